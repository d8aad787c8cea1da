"""The 3-D vessel wall sampled on a regular grid: a compiled lookup of distance, normal and diameter.

The exact query of :mod:`vesselbot_ros.physics.meshed_wall3d` costs microseconds (tens of candidate triangles
per point); the plant asks it at every force evaluation.  This module samples it once on a regular 3-D grid
(the plant's grid, the flow's: nodes ``origin + h (i, j, k)``) and answers by interpolation, falling back to
the exact query only in the cells where interpolation cannot meet the standard (within 1 mm of a wall,
distance within 5 um and normal within 2 deg of the true wall).

Samples (per node, ``NODE_STRIDE`` floats, float32 by default): the exact signed distance s (m, > 0 in the
lumen), the smooth unit inward normal n (:func:`~vesselbot_ros.physics.meshed_wall3d.smooth_wall3d`), the
local diameter D (m, :func:`~vesselbot_ros.physics.meshed_wall3d.local_diameter3d`'s ball definition, filled
outside the lumen from the nearest lumen node) and the flag of the cell whose lowest corner the node is.

Lookup (:func:`wall_field3d`, compiled, allocation-free): in the cell holding the point, trilinear weights
w_c of its eight corners c, and

* distance: ``sum_c w_c (s_c + n_c . (q - x_c) / 2)``, the mean of the trilinear interpolant and of the
  blend of the corners' tangent planes.  s's gradient is n, and for a quadratic s the two errors are
  exactly opposite (trilinear: ``+1/2 sum w_c (x_c - q)^T H (x_c - q)``; tangent planes: minus that), so the
  mean reproduces quadratics and its error is third order, ~ h^3 / rho^2 (rho: the radius of curvature of
  the level set), where the trilinear one's is h^2 / (8 rho): 2.5 um at h = 0.1 mm, 0.5 mm off the axis of
  a tube, against 0.01 um;
* normal: ``sum_c w_c n_c``, normalised (error ~ h^2 / (8 rho^2) rad);
* diameter: trilinear.

Flags (computed at build time): interpolation breaks where the nearest wall feature jumps inside a cell
(the medial surface: a tube's axis, the bisector beside a junction's crease, the apex) and, within the
band, where curvature is high.  A cell is flagged when

* its corners' normals span more than ``spread_deg`` (a jump of the nearest feature; anywhere), or
* at one of its 19 test points (the midpoints of its edges and faces and its centre: the lattice of
  spacing h / 2) within ``band_m`` + h of the wall (a cell reaching into the band is tested whole), the
  interpolated distance is more than ``tol_dist_m`` off the exact one or the normal more than
  ``tol_normal_deg``.  A medial surface with a jump of more than twice ``tol_normal_deg`` that crosses an
  edge puts an edge midpoint or a face centre on the wrong side, so it is caught wherever it crosses the
  cell; the interpolation errors of smooth fields peak at those points.

A flagged cell is refined once: ``refine``^3 sub-cells sampled exactly (the diameter interpolated from the
cell's corners), each flagged by the same two rules at spacing h / ``refine``; the lookup interpolates in
a good sub-cell and asks the exact query in a flagged one (and in a flagged cell with no good sub-cell).
Outside the grid the exact query answers (the diameter from the nearest edge cell).

Measured (tools/validate_wall_field3d.py, h = 0.1 mm, float32, no refinement; 2 x 10^5 points within 1 mm
of the wall each): against the exact query, max 0.8 / 0.9 / 1.7 um and 0.9 / 1.0 / 1.4 deg (cylinder / bent
tube / Y, junction included), no sign error; against the analytic wall 0.7 / 1.2 um and 0.58 / 0.64 deg
(cylinder / bent tube: the facets' 0.66 / 1.05 deg are smoothed).  Flagged cells 0.15 / 0.43 / 2.4 %.
With ``refine`` = 2 the Y's worst normal is 2.1 deg (1 point in 2 x 10^5): in a junction's crease wedge
(the foot on a crease edge) the exact smooth normal takes one face's side, jumping at the facets' scale,
which 19 test points per sub-cell do not see; so refinement is off by default.
Speed (bench/bench_wall_field3d.py): cylinder 83 / 42 ns (lumen / within 0.3 mm of the wall) against the
2-D wall's 128 / 73 ns; the Y 795 / 103 ns against 115 / 68 ns (472 / 148 ns with ``refine`` = 2): 4-8 %
of its lumen (the junction's ball and creases) goes to the exact query.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.physics.meshed_wall3d import Wall3D, ball_diameters3d, smooth_wall3d

__all__ = ["NODE_STRIDE", "WallField3D", "grid_box", "wall_field3d", "field_points3d", "build_wall_field3d"]

#: Floats per node: s (0), inward normal (1-3), diameter (4), flag of the cell with this lowest corner (5),
#: 6-7 unused (32 bytes in float32: two nodes per cache line).
NODE_STRIDE = 8

Array = npt.NDArray[np.float64]


# ---------------------------------------------------------------------------------------------------------
# compiled lookup


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _interp(field, base, sy, sz, tx, ty, tz, h):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(s, nx, ny, nz, D) interpolated in the cell whose lowest corner's record starts at ``base``.

    ``sy``, ``sz``: record offsets of the next node along y and z; (tx, ty, tz) in [0, 1]: the point in the
    cell; h: spacing (m).  The distance is the mean of the trilinear and the tangent-plane blends.
    """
    s = 0.0
    gx = 0.0
    gy = 0.0
    gz = 0.0
    dd = 0.0
    for c in range(8):
        cx = c & 1
        cy = (c >> 1) & 1
        cz = c >> 2
        w = (tx if cx else 1.0 - tx) * (ty if cy else 1.0 - ty) * (tz if cz else 1.0 - tz)
        b = base + cx * NODE_STRIDE + cy * sy + cz * sz
        n0 = float(field[b + 1])
        n1 = float(field[b + 2])
        n2 = float(field[b + 3])
        s += w * (float(field[b]) + 0.5 * h * (n0 * (tx - cx) + n1 * (ty - cy) + n2 * (tz - cz)))
        gx += w * n0
        gy += w * n1
        gz += w * n2
        dd += w * float(field[b + 4])
    L = math.sqrt(gx * gx + gy * gy + gz * gz)
    if not (L > 0.0):
        return s, 0.0, 0.0, -1.0, dd
    return s, gx / L, gy / L, gz / L, dd


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def wall_field3d(px, py, pz, head, field, fine, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(s, nx, ny, nz, D)`` at (px, py, pz) (m): signed distance (m, > 0 in the lumen), unit inward normal and
    local diameter (m).

    ``head`` ``(x0, y0, z0, h, nx, ny, nz, r)``, ``field`` and ``fine`` (flat records of ``NODE_STRIDE``):
    the :class:`WallField3D`; ``d`` ... ``index``: its wall's exact-query arrays
    (:func:`~vesselbot_ros.physics.meshed_wall3d.smooth_wall3d`), which answer in flagged cells and outside
    the grid.  Allocates nothing.
    """
    h = head[3]
    nx = int(head[4])
    ny = int(head[5])
    nz = int(head[6])
    fx = (px - head[0]) / h
    fy = (py - head[1]) / h
    fz = (pz - head[2]) / h
    i = int(math.floor(fx))
    j = int(math.floor(fy))
    k = int(math.floor(fz))
    inside = i >= 0 and j >= 0 and k >= 0 and i < nx - 1 and j < ny - 1 and k < nz - 1
    i = min(max(i, 0), nx - 2)
    j = min(max(j, 0), ny - 2)
    k = min(max(k, 0), nz - 2)
    tx = min(1.0, max(0.0, fx - i))
    ty = min(1.0, max(0.0, fy - j))
    tz = min(1.0, max(0.0, fz - k))
    sy = NODE_STRIDE * nx
    sz = sy * ny
    base = ((k * ny + j) * nx + i) * NODE_STRIDE
    s, gx, gy, gz, dd = _interp(field, base, sy, sz, tx, ty, tz, h)
    flag = field[base + 5]
    if inside and flag == 0.0:
        return s, gx, gy, gz, dd
    if inside and flag > 0.0:
        r = int(head[7])
        r1 = r + 1
        ux = tx * r
        uy = ty * r
        uz = tz * r
        a = min(int(ux), r - 1)
        b = min(int(uy), r - 1)
        c = min(int(uz), r - 1)
        fb = ((int(flag) - 1) * r1 * r1 * r1 + (c * r1 + b) * r1 + a) * NODE_STRIDE
        if fine[fb + 5] == 0.0:
            s, gx, gy, gz, _d = _interp(fine, fb, NODE_STRIDE * r1, NODE_STRIDE * r1 * r1, ux - a, uy - b, uz - c, h / r)
            return s, gx, gy, gz, dd
    s, gx, gy, gz = smooth_wall3d(px, py, pz, d, pbox, pstart, grid, nodes, index)
    return s, gx, gy, gz, dd


@numba.njit(cache=True)
def field_points3d(pts, head, field, fine, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(m, 5) rows ``(s, nx, ny, nz, D)`` of :func:`wall_field3d` at points (m, 3) (m)."""
    out = np.empty((pts.shape[0], 5))
    for k in range(pts.shape[0]):
        r = wall_field3d(pts[k, 0], pts[k, 1], pts[k, 2], head, field, fine, d, pbox, pstart, grid, nodes, index)
        for c in range(5):
            out[k, c] = r[c]
    return out


# ---------------------------------------------------------------------------------------------------------
# build


@numba.njit(cache=True, parallel=True)
def _sample_nodes(head, field, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Fill every node's s and normal (exact smooth query); returns them in float64, (N, 4)."""
    h = head[3]
    nx = int(head[4])
    ny = int(head[5])
    nz = int(head[6])
    out = np.empty((nx * ny * nz, 4))
    for row in numba.prange(ny * nz):
        k = row // ny
        j = row - k * ny
        for i in range(nx):
            m = (k * ny + j) * nx + i
            s, gx, gy, gz = smooth_wall3d(head[0] + i * h, head[1] + j * h, head[2] + k * h, d, pbox, pstart, grid, nodes, index)
            out[m, 0] = s
            out[m, 1] = gx
            out[m, 2] = gy
            out[m, 3] = gz
            b = m * NODE_STRIDE
            field[b] = s
            field[b + 1] = gx
            field[b + 2] = gy
            field[b + 3] = gz
    return out


@numba.njit(cache=True, parallel=True)
def _diameters(pts, q, d, pbox, pstart, grid, nodes, index, rmax, tol, chunk):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`~vesselbot_ros.physics.meshed_wall3d.ball_diameters3d` in parallel chunks."""
    n = pts.shape[0]
    out = np.zeros(n)
    nch = (n + chunk - 1) // chunk
    for c in numba.prange(nch):
        a = c * chunk
        b = min(n, a + chunk)
        out[a:b] = ball_diameters3d(pts[a:b], q[a:b], d, pbox, pstart, grid, nodes, index, rmax, tol)
    return out


@numba.njit(cache=True, parallel=True)
def _sub_lattice(head, field, m0, m1, band, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Exact (s, n) on the planes m0..m1 of the lattice of spacing h / 2 (plane m at z0 + m h / 2).

    (m1 - m0 + 1, 2 ny - 1, 2 nx - 1, 4); NaN at the nodes themselves and where every node of the
    point's cell(s) is farther than ``band`` + 2 h from the wall (no test there).
    """
    h = head[3]
    nx = int(head[4])
    ny = int(head[5])
    mx = 2 * nx - 1
    my = 2 * ny - 1
    np_ = m1 - m0 + 1
    out = np.full((np_, my, mx, 4), np.nan)
    for row in numba.prange(np_ * my):
        pm = row // my
        jj = row - pm * my
        m = m0 + pm
        for ii in range(mx):
            if (ii % 2 == 0) and (jj % 2 == 0) and (m % 2 == 0):
                continue
            near = np.inf
            for c in range(8):
                a = ii // 2 + ((c & 1) if ii % 2 else 0)
                bj = jj // 2 + (((c >> 1) & 1) if jj % 2 else 0)
                bk = m // 2 + ((c >> 2) if m % 2 else 0)
                near = min(near, abs(float(field[((bk * ny + bj) * nx + a) * NODE_STRIDE])))
            if near > band + 2.0 * h:
                continue
            s, gx, gy, gz = smooth_wall3d(head[0] + 0.5 * ii * h, head[1] + 0.5 * jj * h, head[2] + 0.5 * m * h, d, pbox,
                                          pstart, grid, nodes, index)
            out[pm, jj, ii, 0] = s
            out[pm, jj, ii, 1] = gx
            out[pm, jj, ii, 2] = gy
            out[pm, jj, ii, 3] = gz
    return out


@numba.njit(cache=True, parallel=True)
def _flag_layers(head, field, planes, m0, k0, k1, band, tol_s, cos_tol, cos_spread):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Flag the cells of layers k0..k1-1 (``planes``: :func:`_sub_lattice` from plane m0 = 2 k0).

    Returns per layer (flagged by the spread, flagged by a test point, cells tested).
    """
    h = head[3]
    nx = int(head[4])
    ny = int(head[5])
    sy = NODE_STRIDE * nx
    sz = sy * ny
    ncell = (nx - 1) * (ny - 1)
    cnt = np.zeros((k1 - k0, ny - 1, 3), dtype=np.int64)
    for row in numba.prange((k1 - k0) * (ny - 1)):
        kk = row // (ny - 1)
        j = row - kk * (ny - 1)
        k = k0 + kk
        for i in range(nx - 1):
            base = ((k * ny + j) * nx + i) * NODE_STRIDE
            spread = False
            for a in range(8):
                ba = base + (a & 1) * NODE_STRIDE + ((a >> 1) & 1) * sy + (a >> 2) * sz
                for b in range(a + 1, 8):
                    bb = base + (b & 1) * NODE_STRIDE + ((b >> 1) & 1) * sy + (b >> 2) * sz
                    dot = (float(field[ba + 1]) * float(field[bb + 1]) + float(field[ba + 2]) * float(field[bb + 2])
                           + float(field[ba + 3]) * float(field[bb + 3]))
                    if dot < cos_spread:
                        spread = True
            if spread:
                field[base + 5] = -1.0
                cnt[kk, j, 0] += 1
                continue
            bad = False
            tested = False
            for t in range(27):
                di = t % 3
                dj = (t // 3) % 3
                dk = t // 9
                if di % 2 == 0 and dj % 2 == 0 and dk % 2 == 0:
                    continue
                e = planes[2 * k + dk - m0, 2 * j + dj, 2 * i + di]
                if not (abs(e[0]) <= band + h):
                    continue
                tested = True
                s, gx, gy, gz, _dd = _interp(field, base, sy, sz, 0.5 * di, 0.5 * dj, 0.5 * dk, h)
                if abs(s - e[0]) > tol_s or gx * e[1] + gy * e[2] + gz * e[3] < cos_tol:
                    bad = True
                    break
            if tested:
                cnt[kk, j, 2] += 1
            if bad:
                field[base + 5] = -1.0
                cnt[kk, j, 1] += 1
    _ = ncell
    out = np.zeros((k1 - k0, 3), dtype=np.int64)
    for kk in range(k1 - k0):
        for j in range(ny - 1):
            for c in range(3):
                out[kk, c] += cnt[kk, j, c]
    return out


@numba.njit(cache=True, parallel=True)
def _refine(head, field, cells, r, band, tol_s, cos_tol, cos_spread, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Blocks of (r + 1)^3 sub-nodes (spacing h / r) in the flagged cells ``cells`` (m, 3) ``(i, j, k)``.

    Sub-nodes: exact s and normal, D trilinear from the cell's corners; each sub-cell flagged (-1 in its
    lowest sub-node's slot 5) by the coarse rules at spacing h / r.  Returns (blocks (m (r+1)^3
    NODE_STRIDE,) float64, good sub-cells per block (m,)).
    """
    h = head[3]
    nx = int(head[4])
    ny = int(head[5])
    sy = NODE_STRIDE * nx
    sz = sy * ny
    r1 = r + 1
    hr = h / r
    per = r1 * r1 * r1 * NODE_STRIDE
    m = cells.shape[0]
    out = np.zeros(m * per)
    good = np.zeros(m, dtype=np.int64)
    for e in numba.prange(m):
        i = cells[e, 0]
        j = cells[e, 1]
        k = cells[e, 2]
        base = ((k * ny + j) * nx + i) * NODE_STRIDE
        x0 = head[0] + i * h
        y0 = head[1] + j * h
        z0 = head[2] + k * h
        ob = e * per
        for c in range(r1):
            for b in range(r1):
                for a in range(r1):
                    s, gx, gy, gz = smooth_wall3d(x0 + a * hr, y0 + b * hr, z0 + c * hr, d, pbox, pstart, grid, nodes, index)
                    _s, _x, _y, _z, dd = _interp(field, base, sy, sz, a / r, b / r, c / r, h)
                    o = ob + ((c * r1 + b) * r1 + a) * NODE_STRIDE
                    out[o] = s
                    out[o + 1] = gx
                    out[o + 2] = gy
                    out[o + 3] = gz
                    out[o + 4] = dd
        fy = NODE_STRIDE * r1
        fz = fy * r1
        for c in range(r):
            for b in range(r):
                for a in range(r):
                    fb = ob + ((c * r1 + b) * r1 + a) * NODE_STRIDE
                    bad = False
                    for p in range(8):
                        bp = fb + (p & 1) * NODE_STRIDE + ((p >> 1) & 1) * fy + (p >> 2) * fz
                        for q in range(p + 1, 8):
                            bq = fb + (q & 1) * NODE_STRIDE + ((q >> 1) & 1) * fy + (q >> 2) * fz
                            if out[bp + 1] * out[bq + 1] + out[bp + 2] * out[bq + 2] + out[bp + 3] * out[bq + 3] < cos_spread:
                                bad = True
                    if not bad:
                        for t in range(27):
                            di = t % 3
                            dj = (t // 3) % 3
                            dk = t // 9
                            if di % 2 == 0 and dj % 2 == 0 and dk % 2 == 0:
                                continue
                            es, ex, ey, ez = smooth_wall3d(x0 + (a + 0.5 * di) * hr, y0 + (b + 0.5 * dj) * hr,
                                                           z0 + (c + 0.5 * dk) * hr, d, pbox, pstart, grid, nodes, index)
                            if not (abs(es) <= band + h):
                                continue
                            s, gx, gy, gz, _dd = _interp(out, fb, fy, fz, 0.5 * di, 0.5 * dj, 0.5 * dk, hr)
                            if abs(s - es) > tol_s or gx * ex + gy * ey + gz * ez < cos_tol:
                                bad = True
                                break
                    if bad:
                        out[fb + 5] = -1.0
                    else:
                        good[e] += 1
    return out, good


def grid_box(lo_m: npt.ArrayLike, hi_m: npt.ArrayLike, h_m: float, margin_m: float) -> tuple[Array, tuple[int, int, int]]:
    """(origin (3,) m, (nx, ny, nz)): nodes on multiples of ``h_m`` covering the box plus ``margin_m``.

    The rule of :func:`vesselbot_ros.vessels.cfd3d.sample_grid`, so the wall and the flow can share nodes.
    """
    lo = np.asarray(lo_m, dtype=np.float64) - margin_m
    hi = np.asarray(hi_m, dtype=np.float64) + margin_m
    origin = np.floor(lo / h_m) * h_m
    n = np.ceil((hi - origin) / h_m).astype(np.int64) + 1
    return origin, (int(n[0]), int(n[1]), int(n[2]))


class WallField3D:
    """A wall sampled on a regular grid, with its exact query for the flagged cells (see the module docstring).

    Build with :func:`build_wall_field3d`.

    Attributes:
        wall: The exact wall (:class:`~vesselbot_ros.physics.meshed_wall3d.Wall3D`).
        head: (8,) ``(x0, y0, z0, h, nx, ny, nz, r)``: origin (m), spacing (m), nodes per axis, refinement.
        field: (nx ny nz NODE_STRIDE,) node records, x fastest (float32 or float64); slot 5 of a cell's lowest
            corner: 0 interpolate, -1 exact, b > 0 refined in block b of ``fine``.
        fine: Refined blocks, (r + 1)^3 records each (sub-nodes of spacing h / r, x fastest); slot 5 of a
            sub-cell's lowest sub-node: 0 interpolate, -1 exact.
        stats: Build figures: cells, flagged cells (by spread, by test point), refined blocks, sub-cells left
            exact, tested cells, seconds per stage, megabytes.
    """

    def __init__(self, wall: Wall3D, head: Array, field: npt.NDArray[Any], fine: npt.NDArray[Any],
                 stats: dict[str, float]) -> None:
        self.wall = wall
        self.head = head
        self.field = field
        self.fine = fine
        self.stats = stats
        #: The compiled lookup's array arguments after the point: ``wall_field3d(x, y, z, *args)``.
        self.args = (head, field, fine, *wall._args)

    @property
    def shape(self) -> tuple[int, int, int]:
        """(nx, ny, nz) nodes."""
        return int(self.head[4]), int(self.head[5]), int(self.head[6])

    def flags(self) -> npt.NDArray[np.float64]:
        """(nz - 1, ny - 1, nx - 1) the cells' flags: 0 interpolated, -1 exact, b > 0 refined (block b)."""
        nx, ny, nz = self.shape
        f = self.field.reshape(nz, ny, nx, NODE_STRIDE)[:, :, :, 5]
        return np.asarray(f[:-1, :-1, :-1], dtype=np.float64)

    def exact_mask(self, points_m: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """(m,) whether the lookup answers each point (m, 3) (m) by the exact query (outside the grid included)."""
        q = np.atleast_2d(np.asarray(points_m, dtype=np.float64))
        h = self.head[3]
        n = np.array(self.shape)
        f = (q - self.head[:3]) / h
        ijk = np.floor(f).astype(np.int64)
        inside = ((ijk >= 0) & (ijk < n - 1)).all(axis=1)
        ijk = np.clip(ijk, 0, n - 2)
        t = np.clip(f - ijk, 0.0, 1.0)
        flag = self.flags()[ijk[:, 2], ijk[:, 1], ijk[:, 0]]
        r = int(self.head[7])
        r1 = r + 1
        abc = np.minimum((t * r).astype(np.int64), r - 1)
        blk = np.maximum(flag, 1).astype(np.int64) - 1
        fb = (blk * r1 ** 3 + (abc[:, 2] * r1 + abc[:, 1]) * r1 + abc[:, 0]) * NODE_STRIDE
        sub_exact = self.fine[np.minimum(fb, max(self.fine.size - NODE_STRIDE, 0)) + 5] != 0 if self.fine.size else np.ones(len(q), bool)
        return np.asarray(~inside | (flag < 0) | ((flag > 0) & sub_exact))

    def query(self, points_m: npt.ArrayLike) -> dict[str, Array]:
        """``sdist`` (m,) m (> 0 inside), ``normal`` (m, 3) unit inward and ``diameter`` (m,) m at points (m, 3) (m)."""
        q = np.ascontiguousarray(np.atleast_2d(np.asarray(points_m, dtype=np.float64)))
        r = field_points3d(q, *self.args)
        return {"sdist": r[:, 0], "normal": r[:, 1:4], "diameter": r[:, 4]}


def build_wall_field3d(wall: Wall3D, h_m: float = 0.1e-3, margin_m: float = 1.05e-3, band_m: float = 1.0e-3,
                       tol_dist_m: float = 2e-6, tol_normal_deg: float = 1.0, spread_deg: float = 60.0,
                       refine: int = 1, dtype: type = np.float32, origin_m: npt.ArrayLike | None = None,
                       shape: tuple[int, int, int] | None = None, layers_per_chunk: int = 4) -> WallField3D:
    """Sample ``wall`` on a regular grid and flag the cells interpolation cannot answer (module docstring).

    Args:
        wall: The exact wall; its candidate tree must cover the grid.
        h_m: Node spacing (m).
        margin_m: Margin (m) of the grid round the wall's bounding box (nodes on multiples of ``h_m``,
            :func:`grid_box`); ignored when ``origin_m`` and ``shape`` are given.
        band_m: Test points within this distance (m) of the wall are checked against ``tol_dist_m`` and
            ``tol_normal_deg`` (the standard holds within 1 mm of a wall).
        tol_dist_m: A cell with a test point whose interpolated distance is further off (m) is flagged.
        tol_normal_deg: ... or whose interpolated normal is further off (deg).
        spread_deg: A cell whose corners' normals span more (deg) is flagged wherever it is.
        refine: Each flagged cell is divided in ``refine``^3 sub-cells (sampled exactly, flagged by the same
            rules at spacing h / ``refine``); only their flagged sub-cells go to the exact query.  1: none.
        dtype: Storage (np.float32 or np.float64).
        origin_m, shape: An explicit grid: origin (3,) m and ``(nx, ny, nz)`` nodes (e.g. the flow's).
        layers_per_chunk: Cell layers whose test points are held at once (memory of the build).

    Returns:
        The :class:`WallField3D`.

    Raises:
        ValueError: The grid leaves the wall's candidate tree, or no node lies in the lumen.
    """
    from scipy.ndimage import distance_transform_edt  # deferred: scipy.ndimage is heavy, needed only to build

    t0 = time.perf_counter()
    if origin_m is not None and shape is not None:
        origin = np.asarray(origin_m, dtype=np.float64)
        nx, ny, nz = (int(v) for v in shape)
    else:
        wv = wall.surface.wall_vertices()
        origin, (nx, ny, nz) = grid_box(wv.min(axis=0), wv.max(axis=0), h_m, margin_m)
    tg = wall.tree.grid
    tlo = tg[0:3]
    thi = tg[0:3] + tg[3] * tg[4:7]
    top = origin + h_m * (np.array([nx, ny, nz]) - 1)
    if (origin < tlo - 1e-12).any() or (top > thi + 1e-12).any():
        raise ValueError(f"build_wall_field3d: the grid {origin} .. {top} leaves the candidate tree's box {tlo} .. {thi}: "
                         "build the Wall3D with a larger margin_m")
    head = np.array([origin[0], origin[1], origin[2], h_m, nx, ny, nz, max(1, int(refine))], dtype=np.float64)
    field: npt.NDArray[Any] = np.zeros(nx * ny * nz * NODE_STRIDE, dtype=dtype)
    wargs = wall._args
    q = _sample_nodes(head, field, *wargs)
    t1 = time.perf_counter()
    # local diameter: lumen nodes by the ball rule, the others from the nearest lumen node
    lumen = np.nonzero(q[:, 0] > 0.0)[0]
    if lumen.size == 0:
        raise ValueError("build_wall_field3d: no grid node lies in the lumen")
    kk, rem = np.divmod(lumen, nx * ny)
    jj, ii = np.divmod(rem, nx)
    pts = np.ascontiguousarray(origin + h_m * np.column_stack([ii, jj, kk]))
    span = float(np.ptp(wall.surface.wall_vertices(), axis=0).max())
    diam_l = _diameters(pts, np.ascontiguousarray(q[lumen]), *wargs, 2.0 * span, 2e-6, 256)
    del q, pts
    diam = np.zeros(nx * ny * nz)
    diam[lumen] = diam_l
    diam3 = diam.reshape(nz, ny, nx)
    empty = diam3 <= 0.0
    if empty.any():
        _dist, ind = distance_transform_edt(empty, return_indices=True)
        diam3 = diam3[tuple(ind)]
    field.reshape(-1, NODE_STRIDE)[:, 4] = diam3.ravel()
    t2 = time.perf_counter()
    # flags, a few cell layers at a time
    counts = np.zeros(3, dtype=np.int64)
    cos_tol = math.cos(math.radians(tol_normal_deg))
    cos_spread = math.cos(math.radians(spread_deg))
    for k0 in range(0, nz - 1, layers_per_chunk):
        k1 = min(nz - 1, k0 + layers_per_chunk)
        planes = _sub_lattice(head, field, 2 * k0, 2 * k1, band_m, *wargs)
        counts += _flag_layers(head, field, planes, 2 * k0, k0, k1, band_m, tol_dist_m, cos_tol, cos_spread).sum(axis=0)
    t3 = time.perf_counter()
    # one level of refinement in the flagged cells; blocks with no good sub-cell are dropped (exact)
    rec = field.reshape(-1, NODE_STRIDE)
    flagged = np.nonzero(rec[:, 5] != 0)[0]
    kk, rem = np.divmod(flagged, nx * ny)
    jj, ii = np.divmod(rem, nx)
    r = int(head[7])
    fine: npt.NDArray[Any] = np.zeros(0, dtype=dtype)
    sub_exact = 0
    n_blocks = 0
    if r > 1 and flagged.size:
        blocks, good = _refine(head, field, np.ascontiguousarray(np.column_stack([ii, jj, kk])), r, band_m, tol_dist_m, cos_tol,
                               cos_spread, *wargs)
        per = (r + 1) ** 3 * NODE_STRIDE
        keep = np.nonzero(good > 0)[0]
        n_blocks = int(keep.size)
        fine = np.ascontiguousarray(blocks.reshape(-1, per)[keep].ravel().astype(dtype))
        rec[flagged[keep], 5] = np.arange(1, keep.size + 1)
        sub_exact = int(keep.size * r ** 3 - good[keep].sum())
    t4 = time.perf_counter()
    cells = (nx - 1) * (ny - 1) * (nz - 1)
    n_exact = int((rec[:, 5] < 0).sum())
    stats = {"nodes": float(nx * ny * nz), "cells": float(cells), "flagged_spread": float(counts[0]),
             "flagged_test": float(counts[1]), "tested_cells": float(counts[2]),
             "flagged_fraction": float(counts[0] + counts[1]) / cells, "refined_blocks": float(n_blocks),
             "exact_cells": float(n_exact), "exact_subcells": float(sub_exact),
             "exact_fraction": (n_exact + sub_exact / max(r, 1) ** 3) / cells, "lumen_nodes": float(lumen.size),
             "MB": (field.nbytes + fine.nbytes) / 1e6, "fine_MB": fine.nbytes / 1e6, "sample_s": t1 - t0,
             "diameter_s": t2 - t1, "flag_s": t3 - t2, "refine_s": t4 - t3, "build_s": t4 - t0}
    return WallField3D(wall, head, field, fine, stats)
