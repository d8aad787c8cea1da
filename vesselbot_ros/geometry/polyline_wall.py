"""The planar meshed wall: exact signed distance, inward normal and local diameter over a 2-D mesh's boundary.

The wall polyline of the gmsh triangulation (caps left out, each wall end continued beyond its cap), the
grid cells' candidate segments, the compiled nearest-wall query (the kernel inlines it) with the clearance,
and the local diameter (the largest inscribed disc touching the nearest wall point).  Rules, proofs and
measurements: docs/vessels.md, "The wall geometry", `polyline_wall`.
"""
from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

__all__ = ["wall_segments", "cell_candidates", "grid_cell", "nearest_wall", "nearest_segment", "query_points", "local_diameter",
           "WallQuery"]


def wall_segments(points: npt.NDArray[np.float64], triangles: npt.NDArray[np.int64],
                  caps: dict[str, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], float]],
                  extension_m: float) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The wall polyline of a triangulation, oriented, caps left out and continued beyond them.

    Args:
        points: (n, 2) mesh vertices (m).
        triangles: (t, 3) vertex indices (either orientation).
        caps: ``name -> (centre (2,) m, unit outward normal (2,), radius m)`` of the open ends.
        extension_m: Length (m) of the straight continuation of each wall end beyond its cap.

    Returns:
        ``(segments, caps_segments)``: (k, 4) rows ``(ax, az, bx, bz)`` (m) with the lumen on the left of
        a -> b (mesh wall edges, then the continuations), and the (c, 4) cap edges (open ends, same form).
    """
    tri = np.array(triangles, dtype=np.int64)
    pa, pb, pc = points[tri[:, 0]], points[tri[:, 1]], points[tri[:, 2]]
    neg = (pb[:, 0] - pa[:, 0]) * (pc[:, 1] - pa[:, 1]) - (pb[:, 1] - pa[:, 1]) * (pc[:, 0] - pa[:, 0]) < 0
    tri[neg] = tri[neg][:, [0, 2, 1]]  # counter-clockwise, whatever order the mesh library keeps
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])  # directed, lumen on the left
    key = np.sort(e, axis=1)
    _u, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    bnd = e[cnt[inv.ravel()] == 1]
    a, b = points[bnd[:, 0]], points[bnd[:, 1]]
    mid = 0.5 * (a + b)
    on_cap = np.zeros(len(bnd), dtype=bool)
    ext = []
    for centre, n_out, r in caps.values():
        along = (mid[:, 0] - centre[0]) * n_out[0] + (mid[:, 1] - centre[1]) * n_out[1]
        across = np.abs(-(mid[:, 0] - centre[0]) * n_out[1] + (mid[:, 1] - centre[1]) * n_out[0])
        on = (np.abs(along) < 1e-3 * r) & (across <= r * (1 + 1e-6)) & ~on_cap
        on_cap |= on
        # the cap's two corners: vertices of its edges farthest from the centre across the vessel
        vs = np.unique(bnd[on].ravel())
        off = -(points[vs, 0] - centre[0]) * n_out[1] + (points[vs, 1] - centre[1]) * n_out[0]
        for corner in (points[vs[int(np.argmax(off))]], points[vs[int(np.argmin(off))]]):
            far = corner + extension_m * np.asarray(n_out)
            d = far - corner
            to_c = np.asarray(centre) - corner
            ext.append(np.concatenate([corner, far]) if d[0] * to_c[1] - d[1] * to_c[0] > 0 else np.concatenate([far, corner]))
    segs = np.concatenate([np.column_stack([a[~on_cap], b[~on_cap]]), np.array(ext).reshape(-1, 4)])
    return np.ascontiguousarray(segs), np.ascontiguousarray(np.column_stack([a[on_cap], b[on_cap]]))


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _seg_dist2(px, pz, segs, m):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(squared distance, foot x, foot z, cross) of point to segment ``m`` of flat ``segs`` (4 per segment)."""
    ax = segs[4 * m]
    az = segs[4 * m + 1]
    dx = segs[4 * m + 2] - ax
    dz = segs[4 * m + 3] - az
    L2 = dx * dx + dz * dz
    t = ((px - ax) * dx + (pz - az) * dz) / L2
    if t <= 0.0:
        fx = ax
        fz = az
    elif t >= 1.0:
        fx = segs[4 * m + 2]  # the endpoint itself: two segments meeting at a vertex give the same foot
        fz = segs[4 * m + 3]
    else:
        fx = ax + t * dx
        fz = az + t * dz
    ex = px - fx
    ez = pz - fz
    return ex * ex + ez * ez, fx, fz, (dx * ez - dz * ex) / math.sqrt(L2)


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def grid_cell(fx, fz, nx, nz):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(i, j)``: the cell of a grid of nx by nz nodes holding the point at grid coordinates (fx, fz) (-).

    Outside the grid: the cell at the nearest grid edge (the plant's field lookup and the wall's candidate
    lists both answer from it).
    """
    i = int(np.floor(fx))
    j = int(np.floor(fz))
    if i < 0:
        i = 0
    elif i > nx - 2:
        i = nx - 2
    if j < 0:
        j = 0
    elif j > nz - 2:
        j = nz - 2
    return i, j


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def nearest_wall(px, pz, segs, offsets, index, x0, z0, h, nx, nz):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(s, nx, nz)``: signed distance (m, > 0 in the lumen) and unit inward normal of the wall at (px, pz) (m).

    ``segs`` flat (4 k,) segments; ``offsets`` ((nx-1)(nz-1)+1,) and ``index`` the cells' candidates
    (floats holding integers); grid origin x0, z0 (m), spacing h (m), nx, nz nodes.  Allocates nothing.
    """
    i, j = grid_cell((px - x0) / h, (pz - z0) / h, nx, nz)
    c = j * (nx - 1) + i
    best = np.inf
    bperp = -1.0
    cross = 1.0
    fx = px
    fz = pz
    mbest = -1
    for k in range(int(offsets[c]), int(offsets[c + 1])):
        m = int(index[k])
        d2, gx, gz, cr = _seg_dist2(px, pz, segs, m)
        perp = abs(cr)
        if d2 < best or (d2 == best and perp > bperp):
            best = d2
            bperp = perp
            cross = cr
            fx = gx
            fz = gz
            mbest = m
    if mbest < 0:
        return -np.inf, 0.0, -1.0
    d = math.sqrt(best)
    sign = 1.0 if cross >= 0.0 else -1.0
    if d > 0.0:
        return sign * d, sign * (px - fx) / d, sign * (pz - fz) / d
    dx = segs[4 * mbest + 2] - segs[4 * mbest]
    dz = segs[4 * mbest + 3] - segs[4 * mbest + 1]
    L = math.sqrt(dx * dx + dz * dz)
    return 0.0, -dz / L, dx / L


@numba.njit(cache=True)
def query_points(pts, segs, offsets, index, x0, z0, h, nx, nz):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(m, 3) rows ``(s, nx, nz)`` of :func:`nearest_wall` at points (m, 2) (m)."""
    out = np.empty((pts.shape[0], 3))
    for k in range(pts.shape[0]):
        s, gx, gz = nearest_wall(pts[k, 0], pts[k, 1], segs, offsets, index, x0, z0, h, nx, nz)
        out[k, 0] = s
        out[k, 1] = gx
        out[k, 2] = gz
    return out


@numba.njit(cache=True)
def _candidates(segs, x0, z0, h, nx, nz, slack):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    ncell = (nx - 1) * (nz - 1)
    nseg = segs.size // 4
    w2 = 2.0 * 0.5 * math.sqrt(2.0) * h + slack
    counts = np.zeros(ncell + 1, dtype=np.int64)
    dist = np.empty(nseg)
    for rep in range(2):
        if rep == 1:
            for c in range(ncell):
                counts[c + 1] += counts[c]
            index = np.empty(counts[ncell], dtype=np.int64)
        for j in range(nz - 1):
            for i in range(nx - 1):
                cx = x0 + (i + 0.5) * h
                cz = z0 + (j + 0.5) * h
                dmin = np.inf
                for m in range(nseg):
                    d2, _fx, _fz, _cr = _seg_dist2(cx, cz, segs, m)
                    dist[m] = math.sqrt(d2)
                    dmin = min(dmin, dist[m])
                c = j * (nx - 1) + i
                lim = dmin + w2
                if rep == 0:
                    for m in range(nseg):
                        if dist[m] <= lim:
                            counts[c + 1] += 1
                else:
                    k = counts[c]
                    for m in range(nseg):
                        if dist[m] <= lim:
                            index[k] = m
                            k += 1
    return counts, index


def cell_candidates(segs: npt.NDArray[np.float64], x0: float, z0: float, h: float, nx: int, nz: int
                    ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """CSR candidate lists of the grid's cells (see docs/vessels.md): ``(offsets, index)``.

    Args:
        segs: (k, 4) wall segments (m).  x0, z0, h: grid origin and spacing (m); nx, nz: nodes per axis.

    Returns:
        offsets ((nx-1)(nz-1)+1,) and index (total,) int64: cell ``j (nx-1) + i`` holds
        ``index[offsets[c]:offsets[c+1]]``.
    """
    return _candidates(np.ascontiguousarray(segs, dtype=np.float64).ravel(), x0, z0, h, nx, nz, 1e-9)


@numba.njit(cache=True)
def _disc_diameter(cx, cz, rad, sd, x0, z0, h, tol, tol_on):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    nz, nx = rad.shape
    out = np.zeros((nz, nx))
    for j in range(nz):
        for i in range(nx):
            r = rad[j, i]
            if r <= 0.0:
                continue
            k = int((r + tol) / h) + 2
            i0 = int(np.floor((cx[j, i] - x0) / h))
            j0 = int(np.floor((cz[j, i] - z0) / h))
            rr = (r + tol) * (r + tol)
            for jj in range(max(0, j0 - k), min(nz, j0 + k + 1)):
                for ii in range(max(0, i0 - k), min(nx, i0 + k + 1)):
                    ddx = x0 + ii * h - cx[j, i]
                    ddz = z0 + jj * h - cz[j, i]
                    d2 = ddx * ddx + ddz * ddz
                    # in the disc, and on one of its radii to where it touches the wall (there the node's
                    # distance to the wall is the disc's radius minus the node's distance from its centre)
                    if d2 <= rr and 2.0 * r > out[jj, ii] and sd[jj, ii] <= r - math.sqrt(d2) + tol_on:
                        out[jj, ii] = 2.0 * r
    return out


def local_diameter(query, x0: float, z0: float, h: float, nx: int, nz: int) -> npt.NDArray[np.float64]:  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(nz, nx) local diameter (m) on the grid (origin x0, z0, spacing h (m), nx x nz nodes).

    ``query``: (m, 2) points -> (m, 3) rows (s, nx, nz) of the exact wall query.  A lumen node's
    diameter is that of the largest disc inscribed in the lumen that touches the wall at the node's
    nearest wall point (the node lies on the disc's radius to that point): the vessel whose wall is
    nearest.  Discs: from each lumen node, centred where the distance is largest along its inward
    normal (searched in steps of h / 4 up to 1.5 h, so centres reach the medial axis between nodes);
    a node takes the largest disc it lies within (tolerance h) on a radius of (tolerance h / 4); a
    node with none takes the value of the nearest node with one (outside the lumen too).
    """
    from scipy.ndimage import distance_transform_edt  # deferred: scipy.ndimage is heavy, needed only to sample

    X, Z = np.meshgrid(x0 + h * np.arange(nx), z0 + h * np.arange(nz))
    pts = np.column_stack([X.ravel(), Z.ravel()])
    q0 = query(pts)
    best = q0[:, 0].copy()
    cen = pts.copy()
    for a in np.arange(1, 7) * 0.25 * h:
        c = pts + a * q0[:, 1:3]
        s = query(c)[:, 0]
        better = s > best
        best[better] = s[better]
        cen[better] = c[better]
    best[q0[:, 0] <= 0.0] = 0.0
    d = _disc_diameter(cen[:, 0].reshape(nz, nx).copy(), cen[:, 1].reshape(nz, nx).copy(), best.reshape(nz, nx),
                       q0[:, 0].reshape(nz, nx).copy(), float(x0), float(z0), float(h), float(h), 0.25 * float(h))
    empty = d <= 0.0
    if empty.all():
        raise ValueError("local_diameter: no grid node lies in the lumen")
    if empty.any():
        _dist, (jj, ii) = distance_transform_edt(empty, return_indices=True)
        d = d[jj, ii]
    return d


class WallQuery:
    """Exact wall queries of a sampled network field (numpy API over :func:`nearest_wall`).

    Args:
        field: A :class:`vesselbot_ros.vessels.cfd.NetworkField` (its wall segments and candidate lists).
    """

    def __init__(self, field) -> None:  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
        self.field = field
        self._segs = np.ascontiguousarray(field.wall_segments, dtype=np.float64).ravel()
        self._off = np.ascontiguousarray(field.cell_offsets, dtype=np.float64)
        self._idx = np.ascontiguousarray(field.cell_index, dtype=np.float64)
        self._grid = (float(field.x0_m), float(field.z0_m), float(field.h_m), int(field.nx), int(field.nz))
        self._diam = np.ascontiguousarray(field.field("diameter"))
        n_ext = int(field.meta.get("n_wall_extensions", 0))
        #: (k, 4) the meshed wall's segments (m), lumen on the left, without the continuations beyond the caps.
        self.segments = np.asarray(field.wall_segments)[:len(field.wall_segments) - n_ext]

    def query(self, points_m: npt.ArrayLike) -> dict[str, npt.NDArray[np.float64]]:
        """``sdist`` (m,) m (> 0 inside), ``normal`` (m, 2) unit inward normal, ``diameter`` (m,) m at points (m, 2)."""
        q = np.ascontiguousarray(np.atleast_2d(np.asarray(points_m, dtype=np.float64)))
        r = query_points(q, self._segs, self._off, self._idx, *self._grid)
        return {"sdist": r[:, 0], "normal": r[:, 1:3], "diameter": self.diameter(q)}

    def diameter(self, points_m: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """(m,) local diameter (m): the field's, bilinear (as the plant reads it)."""
        q = np.atleast_2d(np.asarray(points_m, dtype=np.float64))
        x0, z0, h, nx, nz = self._grid
        fx = np.clip((q[:, 0] - x0) / h, 0.0, nx - 1.0)
        fz = np.clip((q[:, 1] - z0) / h, 0.0, nz - 1.0)
        i = np.clip(np.floor(fx).astype(np.int64), 0, nx - 2)
        j = np.clip(np.floor(fz).astype(np.int64), 0, nz - 2)
        tx, tz = fx - i, fz - j
        g = self.field.field("diameter")
        return ((1 - tx) * (1 - tz) * g[j, i] + tx * (1 - tz) * g[j, i + 1] + (1 - tx) * tz * g[j + 1, i]
                + tx * tz * g[j + 1, i + 1])

    def clearance(self, x_m: float, z_m: float) -> tuple[float, float]:
        """(signed distance (m, > 0 inside), local diameter (m)) at one point, compiled (a few microseconds)."""
        return _clearance(float(x_m), float(z_m), self._segs, self._off, self._idx, self._diam, *self._grid)


@numba.njit(cache=True, nogil=True)
def _clearance(px, pz, segs, offsets, index, diam, x0, z0, h, nx, nz):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    s, _gx, _gz = nearest_wall(px, pz, segs, offsets, index, x0, z0, h, nx, nz)
    fx = min(max((px - x0) / h, 0.0), nx - 1.0)
    fz = min(max((pz - z0) / h, 0.0), nz - 1.0)
    i = min(int(np.floor(fx)), nx - 2)
    j = min(int(np.floor(fz)), nz - 2)
    tx = fx - i
    tz = fz - j
    d = ((1 - tx) * (1 - tz) * diam[j, i] + tx * (1 - tz) * diam[j, i + 1] + (1 - tx) * tz * diam[j + 1, i]
         + tx * tz * diam[j + 1, i + 1])
    return s, d


@numba.njit(cache=True)
def nearest_segment(pts, segs):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(index (m,), foot (m, 2)) of the segment of (k, 4) ``segs`` nearest each point (m, 2), brute force."""
    flat = segs.ravel()
    idx = np.empty(pts.shape[0], dtype=np.int64)
    foot = np.empty((pts.shape[0], 2))
    for q in range(pts.shape[0]):
        best = np.inf
        for m in range(segs.shape[0]):
            d2, fx, fz, _cr = _seg_dist2(pts[q, 0], pts[q, 1], flat, m)
            if d2 < best:
                best = d2
                idx[q] = m
                foot[q, 0] = fx
                foot[q, 1] = fz
    return idx, foot
