"""The sampled 3-D wall, built: the exact query sampled on a regular grid, cells flagged, refined and listed.

:func:`build_wall_field3d` samples a :class:`~vesselbot_ros.geometry.surface_wall.Wall3D` at the grid's nodes
(distance, smooth normal, ball diameter), flags the cells interpolation cannot answer to the standard, fits
model cells, refines, prunes the exact query to where the lookup asks it and stores the list cells' short
triangle lists: a :class:`WallField3D`.  The rules and measurements: docs/vessels.md, "The wall geometry", `field_build`.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.geometry.candidate_tree import (
    CandidateTree,
    centre_distances,
    leaves3d,
    node_boxes,
    pruned_arrays,
    split_leaves,
)
from vesselbot_ros.geometry.field_lookup import (
    _LIST_BASE,
    MODEL_REC,
    MODELS,
    NODE_STRIDE,
    _interp,
    _scan_list,
    _sub_list_lengths,
    field_points3d,
)
from vesselbot_ros.geometry.field_models import _beyond, _model_cells
from vesselbot_ros.geometry.surface_query import _closest, _leaf, _scan, smooth_wall3d
from vesselbot_ros.geometry.surface_wall import Wall3D, ball_diameters3d
from vesselbot_ros.progress import ProgressFn

__all__ = ["WallField3D", "grid_box", "build_wall_field3d"]

#: Every point of a cell of side h lies within this many h of one of its corners (half its diagonal).
_HALF_DIAGONAL = 0.5 * math.sqrt(3.0)

Array = npt.NDArray[np.float64]


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _nearest_triangle(px, py, pz, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The triangle the exact query finds nearest (px, py, pz) (-1: none, a sealed leaf)."""
    leaf = _leaf(px, py, pz, grid, nodes)
    return _scan(px, py, pz, d, pbox, pstart, index, nodes[leaf, 1], nodes[leaf, 2], nodes[leaf, 3])[5]


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _cube_centre(x0, y0, z0, a, n, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The centre of cube ``p`` (x fastest) of the ``n``^3 cubes of the cube of side ``a`` (m) with lowest corner
    (x0, y0, z0)."""
    return x0 + a * (p % n + 0.5) / n, y0 + a * ((p // n) % n + 0.5) / n, z0 + a * (p // (n * n) + 0.5) / n


@numba.njit(cache=True)
def _list_agrees(x0, y0, z0, a, n, lst, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Whether the scan over ``lst`` answers as the exact query, bit for bit, at the centres of the ``n``^3 cubes
    of the cube of side ``a`` (m) with lowest corner (x0, y0, z0)."""
    for p in range(n * n * n):
        px, py, pz = _cube_centre(x0, y0, z0, a, n, p)
        r1 = _scan_list(px, py, pz, d, lst, 0, lst.size)
        r2 = smooth_wall3d(px, py, pz, d, pbox, pstart, grid, nodes, index)
        if r1[0] != r2[0] or r1[1] != r2[1] or r1[2] != r2[2] or r1[3] != r2[3]:
            return False
    return True


@numba.njit(cache=True)
def _sub_lists(ts, x0, y0, z0, h, lat, sub, halo, nver, naug, maxlen, out, ln, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Fill ``out`` (sub^3, maxlen) and ``ln`` (sub^3,) with the lists of the ``sub``^3 sub-cubes of the cell with
    lowest corner (x0, y0, z0) and side h, from the nearest triangles ``ts`` at its ``lat``^3 lattice points
    (:func:`_list_cells`)."""
    step = (lat - 1) // sub
    a = h / sub
    buf = np.empty(lat * lat * lat + 9 * naug * naug * naug, dtype=np.int64)
    for c in range(sub * sub * sub):
        ci = c % sub
        cj = (c // sub) % sub
        ck = c // (sub * sub)
        sx = x0 + ci * a
        sy = y0 + cj * a
        sz = z0 + ck * a
        cnt = 0
        for attempt in range(halo + 3):
            if attempt <= halo:  # the lattice points in the sub-cube, then within ``attempt`` spacings of it
                cnt = 0
                for kz in range(max(ck * step - attempt, 0), min((ck + 1) * step + attempt, lat - 1) + 1):
                    for ky in range(max(cj * step - attempt, 0), min((cj + 1) * step + attempt, lat - 1) + 1):
                        for kx in range(max(ci * step - attempt, 0), min((ci + 1) * step + attempt, lat - 1) + 1):
                            buf[cnt] = ts[(kz * lat + ky) * lat + kx]
                            cnt += 1
            else:  # and the triangles nearest the centres of the sub-cube's naug^3, then (2 naug)^3 cubes
                na = naug * (attempt - halo)
                for p in range(na * na * na):
                    px, py, pz = _cube_centre(sx, sy, sz, a, na, p)
                    buf[cnt] = _nearest_triangle(px, py, pz, d, pbox, pstart, grid, nodes, index)
                    cnt += 1
            u = np.unique(buf[:cnt])
            if u.size > maxlen or u[0] < 0:
                break
            dc = np.empty(u.size)
            for t in range(u.size):
                dc[t] = _closest(sx + 0.5 * a, sy + 0.5 * a, sz + 0.5 * a, d, 48 * u[t] + 8)[0]
            lst = u[np.argsort(dc, kind="mergesort")]
            if _list_agrees(sx, sy, sz, a, nver, lst, d, pbox, pstart, grid, nodes, index):
                out[c, :lst.size] = lst
                ln[c] = lst.size
                break


@numba.njit(cache=True, parallel=True)
def _list_cells(head, cells, lat, sub, split_len, maxlen, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Per cell of ``cells`` (m, 3) ``(i, j, k)`` and per sub-cube of its ``sub``^3 (side h / ``sub``, x fastest):
    the fewest triangles, nearest the sub-cube's centre first, whose scan (:func:`_scan_list`) answers as the
    exact query, bit for bit, at the centres of the sub-cube's 3^3 cubes, tried in turn: those the exact query
    finds nearest at the cell's ``lat``^3 lattice points in the sub-cube, then within one lattice spacing of it,
    then with those nearest the centres of its 6^3 and 12^3 cubes added (a sliver's small region of nearest
    points that the lattice missed); none if more than ``maxlen``.  Where those lists average more than
    ``split_len`` triangles, the same for the cell's (2 ``sub``)^3 sub-cubes, checked at 2^3 points each.
    Returns (lists (m, sub^3, maxlen) int32, lengths (m, sub^3) int64: 0 none; the finer ones, (m, 8 sub^3,
    maxlen) and (m, 8 sub^3): all 0 where not tried)."""
    h = head[3]
    m = cells.shape[0]
    ns = sub * sub * sub
    out = np.zeros((m, ns, maxlen), dtype=np.int32)
    ln = np.zeros((m, ns), dtype=np.int64)
    out2 = np.zeros((m, 8 * ns, maxlen), dtype=np.int32)
    ln2 = np.zeros((m, 8 * ns), dtype=np.int64)
    for e in numba.prange(m):
        x0 = head[0] + cells[e, 0] * h
        y0 = head[1] + cells[e, 1] * h
        z0 = head[2] + cells[e, 2] * h
        ts = np.empty(lat * lat * lat, dtype=np.int64)
        for p in range(lat * lat * lat):
            ts[p] = _nearest_triangle(x0 + h * (p % lat) / (lat - 1), y0 + h * ((p // lat) % lat) / (lat - 1),
                                      z0 + h * (p // (lat * lat)) / (lat - 1), d, pbox, pstart, grid, nodes, index)
        _sub_lists(ts, x0, y0, z0, h, lat, sub, 1, 3, 6, maxlen, out[e], ln[e], d, pbox, pstart, grid, nodes, index)
        used = 0
        for c in range(ns):
            used += ln[e, c] > 0
        if ln[e].sum() > split_len * max(used, 1) and (lat - 1) % (2 * sub) == 0:
            _sub_lists(ts, x0, y0, z0, h, lat, 2 * sub, 1, 2, 6, maxlen, out2[e], ln2[e], d, pbox, pstart, grid, nodes, index)
    return out, ln, out2, ln2


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


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _s_at(x, y, z, head, field):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The sampled distance (m) interpolated at (x, y, z) (m), flags ignored (clamped to the grid)."""
    h = head[3]
    nx = int(head[4])
    ny = int(head[5])
    nz = int(head[6])
    fx = (x - head[0]) / h
    fy = (y - head[1]) / h
    fz = (z - head[2]) / h
    i = min(max(int(math.floor(fx)), 0), nx - 2)
    j = min(max(int(math.floor(fy)), 0), ny - 2)
    k = min(max(int(math.floor(fz)), 0), nz - 2)
    base = ((k * ny + j) * nx + i) * NODE_STRIDE
    return _interp(field, base, NODE_STRIDE * nx, NODE_STRIDE * nx * ny, min(1.0, max(0.0, fx - i)),
                   min(1.0, max(0.0, fy - j)), min(1.0, max(0.0, fz - k)), h)[0]


@numba.njit(cache=True, parallel=True)
def _diameters(pts, q, head, field, d, pbox, pstart, grid, nodes, index, rmax, tol, chunk):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`~vesselbot_ros.geometry.surface_wall.ball_diameters3d` in parallel chunks, each ball first sized on the
    sampled distances (its largest radius by bisection on the interpolated s, a few um off near the medial
    surface where the ball's centre lies), so the exact queries start 2 % above it and grow by 5 %: most
    balls take two (one that does not fit and the shrink through its nearest wall point), against about six
    from 2 s."""
    n = pts.shape[0]
    r0 = np.zeros(n)
    for k in numba.prange(n):
        s = q[k, 0]
        if s <= 0.0:
            continue
        fx = pts[k, 0] - s * q[k, 1]
        fy = pts[k, 1] - s * q[k, 2]
        fz = pts[k, 2] - s * q[k, 3]
        lo = s
        hi = 2.0 * s
        while hi < rmax and _s_at(fx + hi * q[k, 1], fy + hi * q[k, 2], fz + hi * q[k, 3], head, field) >= hi - tol:
            lo = hi
            hi *= 2.0
        for _it in range(40):
            if hi - lo <= tol:
                break
            r = 0.5 * (lo + hi)
            if _s_at(fx + r * q[k, 1], fy + r * q[k, 2], fz + r * q[k, 3], head, field) >= r - tol:
                lo = r
            else:
                hi = r
        r0[k] = 1.02 * hi
    out = np.zeros(n)
    nch = (n + chunk - 1) // chunk
    for c in numba.prange(nch):
        a = c * chunk
        b = min(n, a + chunk)
        out[a:b] = ball_diameters3d(pts[a:b], q[a:b], d, pbox, pstart, grid, nodes, index, rmax, tol, r0[a:b], 1.05)
    return out


@numba.njit(cache=True, parallel=True)
def _sub_lattice(head, field, m0, m1, band, out_band, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Exact (s, n) on the planes m0..m1 of the lattice of spacing h / 2 (plane m at z0 + m h / 2).

    (m1 - m0 + 1, 2 ny - 1, 2 nx - 1, 4); NaN at the nodes themselves and where every node of the
    point's cell(s) lies beyond the band by more than 2 h (:func:`_beyond`: no test there).
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
            far = True
            for c in range(8):
                a = ii // 2 + ((c & 1) if ii % 2 else 0)
                bj = jj // 2 + (((c >> 1) & 1) if jj % 2 else 0)
                bk = m // 2 + ((c >> 2) if m % 2 else 0)
                far = far and _beyond(float(field[((bk * ny + bj) * nx + a) * NODE_STRIDE]), band, out_band, 2.0 * h)
            if far:
                continue
            s, gx, gy, gz = smooth_wall3d(head[0] + 0.5 * ii * h, head[1] + 0.5 * jj * h, head[2] + 0.5 * m * h, d, pbox,
                                          pstart, grid, nodes, index)
            out[pm, jj, ii, 0] = s
            out[pm, jj, ii, 1] = gx
            out[pm, jj, ii, 2] = gy
            out[pm, jj, ii, 3] = gz
    return out


@numba.njit(cache=True, parallel=True)
def _flag_layers(head, field, planes, m0, k0, k1, band, out_band, tol_s, cos_tol, cos_spread):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
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
            deep = True
            for a in range(8):
                deep = deep and _beyond(float(field[base + (a & 1) * NODE_STRIDE + ((a >> 1) & 1) * sy + (a >> 2) * sz]),
                                        band, out_band, _HALF_DIAGONAL * h)
            if deep:
                continue  # every point of the cell is beyond the band (s is 1-Lipschitz): interpolated
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
                if e[0] != e[0] or _beyond(e[0], band, out_band, h):  # NaN: no test point there
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
def _refine(head, field, cells, r, band, out_band, tol_s, cos_tol, cos_spread, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
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
                    deep = True
                    for p in range(8):
                        deep = deep and _beyond(out[fb + (p & 1) * NODE_STRIDE + ((p >> 1) & 1) * fy + (p >> 2) * fz], band,
                                                out_band, _HALF_DIAGONAL * hr)
                    if deep:
                        good[e] += 1  # beyond the band (as a coarse cell)
                        continue
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
                            if _beyond(es, band, out_band, h):
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


def _lumen_diameters(head: Array, field: npt.NDArray[Any], q: Array, wargs: tuple[npt.NDArray[Any], ...], rmax: float,
                     tol: float) -> tuple[Array, int]:
    """(nodes,) the lumen nodes' ball diameters (m; 0 outside), and how many balls were sized exactly.

    Coarse to fine with the error checked: the nodes of even (i, j, k) and the centres of the cubes of 2 h they
    span are sized exactly; a cube whose eight corners are lumen nodes and whose trilinear interpolant is
    within ``tol`` of the exact diameter at its centre (a straight or evenly tapering stretch) fills its
    other nodes by interpolation; every other lumen node is sized exactly.
    """
    h = float(head[3])
    nx, ny, nz = int(head[4]), int(head[5]), int(head[6])
    lumen = (q[:, 0] > 0.0).reshape(nz, ny, nx)
    diam = np.zeros((nz, ny, nx))
    done = np.zeros_like(lumen)

    def size(mask: npt.NDArray[np.bool_]) -> int:
        flat = np.nonzero(mask.ravel())[0]
        kk, rem = np.divmod(flat, nx * ny)
        jj, ii = np.divmod(rem, nx)
        pts = np.ascontiguousarray(head[:3] + h * np.column_stack([ii, jj, kk]))
        diam.ravel()[flat] = _diameters(pts, np.ascontiguousarray(q[flat]), head, field, *wargs, rmax, tol,  # type: ignore[call-arg]  # numba dispatcher: mypy sees the wrapper's signature
                                        256)
        done.ravel()[flat] = True
        return int(flat.size)

    # cubes (a, b, c): corners at even indices 2a .. 2a + 2 (z, y, x), centre at 2a + 1
    cz, cy, cx = (nz - 1) // 2, (ny - 1) // 2, (nx - 1) // 2
    first = np.zeros_like(lumen)
    first[::2, ::2, ::2] = lumen[::2, ::2, ::2]
    first[1:2 * cz:2, 1:2 * cy:2, 1:2 * cx:2] = lumen[1:2 * cz:2, 1:2 * cy:2, 1:2 * cx:2]
    n = size(first)
    ev = diam[0:2 * cz + 1:2, 0:2 * cy + 1:2, 0:2 * cx + 1:2]
    evl = lumen[0:2 * cz + 1:2, 0:2 * cy + 1:2, 0:2 * cx + 1:2]
    corners_in = np.ones((cz, cy, cx), dtype=bool)
    mean = np.zeros((cz, cy, cx))
    for c in range(8):
        sl = (slice(c >> 2, cz + (c >> 2)), slice((c >> 1) & 1, cy + ((c >> 1) & 1)), slice(c & 1, cx + (c & 1)))
        corners_in &= evl[sl]
        mean += 0.125 * ev[sl]
    centre = diam[1:2 * cz:2, 1:2 * cy:2, 1:2 * cx:2]
    good = corners_in & lumen[1:2 * cz:2, 1:2 * cy:2, 1:2 * cx:2] & (np.abs(mean - centre) <= tol)
    kk, jj, ii = np.nonzero(lumen & ~done)
    a, b, c0 = kk // 2, jj // 2, ii // 2
    inside = (a < cz) & (b < cy) & (c0 < cx)
    ok = np.zeros(len(kk), dtype=bool)
    ok[inside] = good[a[inside], b[inside], c0[inside]]
    k2, j2, i2 = kk[ok], jj[ok], ii[ok]
    tz, ty, tx = (k2 % 2) * 0.5, (j2 % 2) * 0.5, (i2 % 2) * 0.5
    val = np.zeros(len(k2))
    for c in range(8):
        w = (tx if c & 1 else 1.0 - tx) * (ty if (c >> 1) & 1 else 1.0 - ty) * (tz if c >> 2 else 1.0 - tz)
        val += w * diam[2 * (k2 // 2 + (c >> 2)), 2 * (j2 // 2 + ((c >> 1) & 1)), 2 * (i2 // 2 + (c & 1))]
    diam[k2, j2, i2] = val
    rest = np.zeros_like(lumen)
    rest[kk[~ok], jj[~ok], ii[~ok]] = True
    n += size(rest)
    return diam.ravel(), n


def grid_box(lo_m: npt.ArrayLike, hi_m: npt.ArrayLike, h_m: float, margin_m: float) -> tuple[Array, tuple[int, int, int]]:
    """(origin (3,) m, (nx, ny, nz)): nodes on multiples of ``h_m`` covering the box plus ``margin_m``.

    The rule of :func:`vesselbot_ros.vessels.tree_cfd.sample_grid`, so the wall and the flow can share nodes.
    """
    lo = np.asarray(lo_m, dtype=np.float64) - margin_m
    hi = np.asarray(hi_m, dtype=np.float64) + margin_m
    origin = np.floor(lo / h_m) * h_m
    n = np.ceil((hi - origin) / h_m).astype(np.int64) + 1
    return origin, (int(n[0]), int(n[1]), int(n[2]))


class WallField3D:
    """A wall sampled on a regular grid, with its exact query for the flagged cells (see docs/vessels.md).

    Build with :func:`build_wall_field3d`.

    Attributes:
        wall: The exact wall (:class:`~vesselbot_ros.geometry.surface_wall.Wall3D`).
        head: (8,) ``(x0, y0, z0, h, nx, ny, nz, r)``: origin (m), spacing (m), nodes per axis, refinement.
        field: (nx ny nz NODE_STRIDE,) node records, x fastest (float32 or float64); slot 5 of a cell's lowest
            corner: 0 interpolate, -1 exact, b > 0 refined in block b of ``fine``, -2 - m model cell m (its
            ``MODEL_REC`` floats at ``fine[head[8] + m MODEL_REC]``).
        fine: Refined blocks, (r + 1)^3 records each (sub-nodes of spacing h / r, x fastest); slot 5 of a
            sub-cell's lowest sub-node: 0 interpolate, -1 exact; then the model cells' records, then the list
            cells' triangle indices.
        stats: Build figures: cells, flagged cells (by spread, by test point), refined blocks, sub-cells left
            exact, tested cells, seconds per stage, megabytes.
    """

    def __init__(self, wall: Wall3D, head: Array, field: npt.NDArray[Any], fine: npt.NDArray[Any],
                 stats: dict[str, float], exact: tuple[npt.NDArray[Any], ...] | None = None) -> None:
        self.wall = wall
        self.head = head
        self.field = field
        self.fine = fine
        self.stats = stats
        #: The compiled lookup's array arguments after the point: ``wall_field3d(x, y, z, *args)`` (the exact
        #: query's arrays pruned to where the lookup asks it, or the wall's own).
        self.args = (head, field, fine, *(exact if exact is not None else wall._args))

    @property
    def shape(self) -> tuple[int, int, int]:
        """(nx, ny, nz) nodes."""
        return int(self.head[4]), int(self.head[5]), int(self.head[6])

    def flags(self) -> npt.NDArray[np.float64]:
        """(nz - 1, ny - 1, nx - 1) the cells' flags: 0 interpolated, -1 exact, b > 0 refined (block b), <= -2 model
        cell."""
        nx, ny, nz = self.shape
        f = self.field.reshape(nz, ny, nx, NODE_STRIDE)[:, :, :, 5]
        return np.asarray(f[:-1, :-1, :-1], dtype=np.float64)

    def exact_mask(self, points_m: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """(m,) whether the lookup answers each point (m, 3) (m) by the exact query (outside the grid included; not
        a list cell's scan)."""
        q = np.atleast_2d(np.asarray(points_m, dtype=np.float64))
        return np.asarray(self.exact_mask_raw(q) & ~self._listed(q))

    def list_mask(self, points_m: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """(m,) whether the lookup answers each point (m, 3) (m) by a list cell's short scan."""
        q = np.atleast_2d(np.asarray(points_m, dtype=np.float64))
        return np.asarray(self.exact_mask_raw(q) & self._listed(q))

    def _listed(self, q: Array) -> npt.NDArray[np.bool_]:
        """(m,) whether each point lies in a list cell's sub-cube that has a list (in the grid)."""
        n = np.array(self.shape)
        f = (q - self.head[:3]) / self.head[3]
        ijk = np.floor(f).astype(np.int64)
        inside = ((ijk >= 0) & (ijk < n - 1)).all(axis=1)
        ijk = np.clip(ijk, 0, n - 2)
        t = np.ascontiguousarray(np.clip(f - ijk, 0.0, 1.0))
        rec = self.field.reshape(n[2], n[1], n[0], NODE_STRIDE)[ijk[:, 2], ijk[:, 1], ijk[:, 0]]
        listed = inside & (rec[:, 7] > 0)
        listed[listed] = _sub_list_lengths(t[listed], self.fine, rec[listed, 6].astype(np.int64),
                                           rec[listed, 7].astype(np.int64)) > 0
        return np.asarray(listed)

    def exact_mask_raw(self, points_m: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """(m,) whether each point (m, 3) (m) lies off the grid or in an exact cell or sub-cell (list cells included)."""
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
        return np.asarray(~inside | (flag == -1.0) | ((flag > 0) & sub_exact))

    def query(self, points_m: npt.ArrayLike) -> dict[str, Array]:
        """``sdist`` (m,) m (> 0 inside), ``normal`` (m, 3) unit inward and ``diameter`` (m,) m at points (m, 3) (m)."""
        q = np.ascontiguousarray(np.atleast_2d(np.asarray(points_m, dtype=np.float64)))
        r = field_points3d(q, *self.args)
        return {"sdist": r[:, 0], "normal": r[:, 1:4], "diameter": r[:, 4]}


def _pruned(wall: Wall3D, head: Array, cells: npt.NDArray[np.int64], max_leaf: int,
            max_depth: int) -> tuple[npt.NDArray[Any], ...]:
    """The wall's exact-query arrays kept only in the leaves holding a point of ``cells`` (flat indices of their
    lowest node) or a point outside the grid's cells, those leaves split down to ``max_depth`` (short lists
    where the lookup asks) (:func:`~vesselbot_ros.geometry.candidate_tree.split_leaves`,
    :func:`~vesselbot_ros.geometry.candidate_tree.pruned_arrays`).  Beyond the grid a leaf wholly outside the
    lumen is sealed: only a bead far outside it goes there."""
    tree = wall.tree
    need, seal, at_cells = _needed(tree, wall, head, cells)
    tree = split_leaves(wall.surface, tree, at_cells, max_leaf, max_depth)
    need, seal, _at = _needed(tree, wall, head, cells)
    return pruned_arrays(wall.surface, tree, need, seal)


def _needed(tree: CandidateTree, wall: Wall3D, head: Array, cells: npt.NDArray[np.int64]
            ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    """(needed, sealed, at the cells) leaves of ``tree`` for :func:`_pruned`."""
    h = head[3]
    nx, ny, nz = int(head[4]), int(head[5]), int(head[6])
    centre, half = node_boxes(tree)
    leaf = tree.nodes[:, 0] < 0
    lo = head[:3]
    hi = head[:3] + h * (np.array([nx, ny, nz]) - 1)
    need = leaf & ((centre - half[:, None] < lo).any(axis=1) | (centre + half[:, None] >= hi).any(axis=1))
    sc = centre_distances(wall.surface.data, centre, tree.nodes[:, 3])
    seal = need & (sc + math.sqrt(3.0) * half < 0.0)
    # a point beyond the tree's box falls in an edge leaf (its answer approximate: the lists hold for points in
    # the leaf): none within two root cubes of a cap's axis beyond it is sealed, for a bead gone down an outlet
    g = tree.grid
    edge = ((centre - half[:, None] <= g[0:3] + 1e-12) | (centre + half[:, None] >= g[0:3] + g[3] * g[4:7] - 1e-12)).any(axis=1)
    for c, n, r in wall.surface.caps:
        rel = centre - c
        t = np.maximum((rel[:, 0] * n[0] + rel[:, 1] * n[1]) + rel[:, 2] * n[2], 0.0)  # not rel @ n: a BLAS gemv
        seal &= ~(edge & (np.linalg.norm(rel - t[:, None] * n, axis=1) <= r + 2.0 * g[3]))
    m = int(math.ceil(h / (2.0 * float(half[leaf].min())) - 1e-9)) + 1  # points per axis: leaves no finer
    u = np.linspace(0.0, 1.0, m)
    off = np.stack(np.meshgrid(u, u, u, indexing="ij"), axis=-1).reshape(-1, 3) * h
    kk, rem = np.divmod(cells, nx * ny)
    jj, ii = np.divmod(rem, nx)
    base = lo + h * np.column_stack([ii, jj, kk]).astype(np.float64)
    at_cells = np.zeros_like(need)
    if cells.size:
        for o in off:
            at_cells[leaves3d(np.ascontiguousarray(base + o), tree.grid, tree.nodes)] = True
    return need | at_cells, seal & ~at_cells, at_cells


def _store_lists(head: Array, rec: npt.NDArray[Any], fine: npt.NDArray[Any], lcells: npt.NDArray[np.int64],
                 lat: int, sub: int, split_len: float, maxlen: int, exact: tuple[npt.NDArray[Any], ...], dtype: type
                 ) -> tuple[npt.NDArray[Any], dict[str, float]]:
    """Give the cells ``lcells`` (flat indices) whose sub-cubes have lists their directories and lists in ``fine``.

    Each cell is divided in ``sub``^3 sub-cubes, or in (2 ``sub``)^3 where the lists of those are longer than
    ``split_len`` on average (near a vessel's axis: a ring of triangles nearly as near) and the finer ones
    leave no more of it to the exact query.  A list cell's lowest node's slot 6 holds its directory's offset in
    ``fine``, slot 7 its division n; the directory is ``(hi, lo, start_0 .. start_{n^3})``: sub-cube c's
    triangles are ``fine[base + start_c:base + start_{c+1}]`` with ``base = hi _LIST_BASE + lo`` (none: the
    exact query).  The directories come first, so their offsets stay exact in float32.  Returns (fine, stats).
    """
    stats = {"list_cells": 0.0, "list_cells_fine": 0.0, "list_sub_cells": 0.0, "list_mean_len": 0.0}
    if lcells.size == 0:
        return fine, stats
    nx, ny = int(head[4]), int(head[5])
    kk, rem = np.divmod(lcells, nx * ny)
    jj, ii = np.divmod(rem, nx)
    ijk = np.column_stack([ii, jj, kk])
    ns = sub ** 3
    subs = [sub] * len(lcells)
    per: list[npt.NDArray[np.int64]] = []
    rows: list[npt.NDArray[np.int32]] = []
    chunk = max(1, (1 << 27) // (9 * ns * maxlen * 4))  # a chunk's lists, the finer included: at most 128 MB
    for c0 in range(0, len(ijk), chunk):
        lists, ln, lists2, ln2 = _list_cells(head, np.ascontiguousarray(ijk[c0:c0 + chunk]), lat, sub, split_len, maxlen,
                                             *exact)
        for e in range(len(ln)):
            finer = ln2[e].any() and (ln2[e] > 0).sum() >= 8 * (ln[e] > 0).sum()  # leaving no more to the exact query
            lst, n = (lists2[e], ln2[e]) if finer else (lists[e], ln[e])
            subs[c0 + e] = 2 * sub if finer else sub
            per.append(n)
            rows.append(lst[np.arange(maxlen)[None, :] < n[:, None]])  # per sub-cube, its list
    has = np.array([ln.sum() > 0 for ln in per])
    size = np.array([n ** 3 + 3 for n in subs])
    limit = 2 ** 24 if np.dtype(dtype) == np.float32 else 2 ** 52
    has &= fine.size + np.cumsum(np.where(has, size, 0)) < limit  # the directory's end exact
    cells = np.nonzero(has)[0]
    dir_off = fine.size + np.concatenate([[0], np.cumsum(size[cells])[:-1]])
    total = np.array([int(per[c].sum()) for c in cells])
    base = fine.size + int(size[cells].sum()) + np.concatenate([[0], np.cumsum(total)[:-1]])
    dirs = [np.concatenate([np.divmod(b, _LIST_BASE), [0], np.cumsum(per[c])]) for b, c in zip(base, cells, strict=True)]
    rec[lcells[cells], 6] = dir_off
    rec[lcells[cells], 7] = np.array(subs)[cells]
    parts = [np.zeros(0)] + dirs + [rows[c] for c in cells]
    fine = np.ascontiguousarray(np.concatenate([fine] + [p_.astype(dtype) for p_ in parts]))
    n_sub = sum(int((per[c] > 0).sum()) for c in cells)
    stats.update(list_cells=float(cells.size), list_cells_fine=float(sum(subs[c] > sub for c in cells)),
                 list_sub_cells=float(n_sub), list_mean_len=float(total.sum()) / max(n_sub, 1))
    return fine, stats


def build_wall_field3d(wall: Wall3D, h_m: float = 0.1e-3, margin_m: float = 1.05e-3, band_m: float = 1.0e-3,
                       tol_dist_m: float = 2e-6, tol_normal_deg: float = 1.0, spread_deg: float = 60.0,
                       refine: int = 1, dtype: type = np.float32, origin_m: npt.ArrayLike | None = None,
                       shape: tuple[int, int, int] | None = None, layers_per_chunk: int = 4,
                       prune: bool = True, out_band_m: float | None = None, exact_max_leaf: int = 8,
                       exact_max_depth: int = 0, tube: bool = False, axis_m: float = 5e-6 / math.tan(math.radians(2.0)),
                       models: int = MODELS, list_max: int = 0, list_lattice: int = 17, list_sub: int = 4,
                       list_split: float = 12.0, progress: ProgressFn | None = None) -> WallField3D:
    """Sample ``wall`` on a regular grid and flag the cells interpolation cannot answer (docs/vessels.md).

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
        out_band_m: The band outside the lumen (m) where the standard is kept (default ``band_m``); beyond
            it, as beyond ``band_m`` inside, cells are interpolated whatever the error.
        prune: Keep the exact query's lists only in the leaves the lookup can ask (:func:`_pruned`); else the
            lookup carries the wall's whole candidate tree.
        tube: A flagged cell wholly in the lumen whose least of up to ``models`` smooth models (docs/vessels.md)
            meets the tolerances at its lattice of 125 points is answered by them (for fine walls: on 0.1 mm
            facets the exact normal's facet-scale wiggle between the test points can take a model cell's error
            past 2 deg).
        axis_m: ... the normal not tested within this (m) of the attaining model's axis (the exact normal turns
            by more than 2 deg within 5 um there).
        models: The most models per model cell (1: one straight round tube per cell).
        list_max: An exact cell (or one with exact sub-cells) wholly in the lumen is divided in ``list_sub``^3
            sub-cubes; one whose nearest triangles at the cell's ``list_lattice``^3 lattice points in it and next
            to it are at most this many, and whose scan over them answers as the exact query at the centres of its
            27 cubes, is answered by that scan (docs/vessels.md).  0: none.
        list_split: ... a cell whose sub-cubes' lists are longer on average is divided in (2 ``list_sub``)^3 instead
            (their lists checked at 8 points each).
        exact_max_leaf, exact_max_depth: The kept leaves are split while their list is longer than
            ``exact_max_leaf``, down to ``exact_max_depth`` (0: the wall tree's depth).
        progress: Called as ``progress(done, total)`` after each stage of the build (the sampling, the
            diameters, each chunk of flagged layers, the model cells, the refinement, the pruning, the lists);
            ``done == total`` at the end.

    Returns:
        The :class:`WallField3D`.

    Raises:
        ValueError: The grid leaves the wall's candidate tree, or no node lies in the lumen.
    """
    from scipy.ndimage import distance_transform_edt  # deferred: scipy.ndimage is heavy, needed only to build

    if list_max > 0 and (list_sub < 1 or (list_lattice - 1) % list_sub):
        raise ValueError(f"list_lattice - 1 = {list_lattice - 1} is not a multiple of list_sub = {list_sub}")
    t0 = time.perf_counter()
    out_band = band_m if out_band_m is None else float(out_band_m)
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
    head = np.array([origin[0], origin[1], origin[2], h_m, nx, ny, nz, max(1, int(refine)), 0.0], dtype=np.float64)
    chunks = range(0, nz - 1, layers_per_chunk)
    steps = len(chunks) + 6  # sampling, diameters, the chunks, model cells, refinement, pruning, lists
    done = 0

    def stage() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, steps)

    if progress is not None:
        progress(0, steps)
    field: npt.NDArray[Any] = np.zeros(nx * ny * nz * NODE_STRIDE, dtype=dtype)
    wargs = wall._args
    q = _sample_nodes(head, field, *wargs)
    stage()
    t1 = time.perf_counter()
    # local diameter: lumen nodes by the ball rule (:func:`_lumen_diameters`), the others from the nearest lumen node
    if not (q[:, 0] > 0.0).any():
        raise ValueError("build_wall_field3d: no grid node lies in the lumen")
    span = float(np.ptp(wall.surface.wall_vertices(), axis=0).max())
    diam, n_balls = _lumen_diameters(head, field, q, wargs, 2.0 * span, 2e-6)
    del q
    diam3 = diam.reshape(nz, ny, nx)
    empty = diam3 <= 0.0
    if empty.any():
        _dist, ind = distance_transform_edt(empty, return_indices=True)
        diam3 = diam3[tuple(ind)]
    field.reshape(-1, NODE_STRIDE)[:, 4] = diam3.ravel()
    stage()
    t2 = time.perf_counter()
    # flags, a few cell layers at a time
    counts = np.zeros(3, dtype=np.int64)
    cos_tol = math.cos(math.radians(tol_normal_deg))
    cos_spread = math.cos(math.radians(spread_deg))
    for k0 in chunks:
        k1 = min(nz - 1, k0 + layers_per_chunk)
        planes = _sub_lattice(head, field, 2 * k0, 2 * k1, band_m, out_band, *wargs)
        counts += _flag_layers(head, field, planes, 2 * k0, k0, k1, band_m, out_band, tol_dist_m, cos_tol,
                               cos_spread).sum(axis=0)
        stage()
    t3 = time.perf_counter()
    # one level of refinement in the flagged cells that reach into the lumen (a bead's centre is never
    # outside); blocks with no good sub-cell are dropped (exact)
    rec = field.reshape(-1, NODE_STRIDE)
    s3 = rec[:, 0].reshape(nz, ny, nx)
    reach = np.zeros((nz - 1, ny - 1, nx - 1), dtype=bool)
    for c in range(8):
        reach |= s3[c >> 2:nz - 1 + (c >> 2), (c >> 1) & 1:ny - 1 + ((c >> 1) & 1), c & 1:nx - 1 + (c & 1)] > 0.0
    cell_of = np.zeros((nz, ny, nx), dtype=bool)
    cell_of[:-1, :-1, :-1] = reach
    # first the flagged cells wholly in the lumen that the least of a few smooth models answers (docs/vessels.md)
    inner = np.ones((nz - 1, ny - 1, nx - 1), dtype=bool)
    for c in range(8):
        inner &= s3[c >> 2:nz - 1 + (c >> 2), (c >> 1) & 1:ny - 1 + ((c >> 1) & 1), c & 1:nx - 1 + (c & 1)] > 0.0
    cell_in = np.zeros((nz, ny, nx), dtype=bool)
    cell_in[:-1, :-1, :-1] = inner
    cand = np.nonzero((rec[:, 5] != 0) & cell_in.ravel())[0]
    mrec = np.zeros((0, MODEL_REC))
    n_used = np.zeros(MODELS + 1, dtype=np.int64)
    if tube and cand.size:
        kk, rem = np.divmod(cand, nx * ny)
        jj, ii = np.divmod(rem, nx)
        allrec, used = _model_cells(head, np.ascontiguousarray(np.column_stack([ii, jj, kk])), min(max(1, int(models)), MODELS),
                                    5, 9, band_m, out_band, tol_dist_m, cos_tol, math.cos(math.radians(1.5)), axis_m,
                                    np.dtype(dtype) == np.float32, *wargs)
        passed = used > 0
        mrec = allrec[passed]
        n_used = np.bincount(used, minlength=MODELS + 1)
        rec[cand[passed], 5] = -2.0 - np.arange(mrec.shape[0])
    stage()
    t3b = time.perf_counter()
    flagged = np.nonzero((rec[:, 5] > -2.0) & (rec[:, 5] != 0) & cell_of.ravel())[0]
    kk, rem = np.divmod(flagged, nx * ny)
    jj, ii = np.divmod(rem, nx)
    r = int(head[7])
    fine: npt.NDArray[Any] = np.zeros(0, dtype=dtype)
    sub_exact = 0
    n_blocks = 0
    exact_blocks = np.zeros(0, dtype=np.int64)
    if r > 1 and flagged.size:
        blocks, good = _refine(head, field, np.ascontiguousarray(np.column_stack([ii, jj, kk])), r, band_m, out_band, tol_dist_m, cos_tol,
                               cos_spread, *wargs)
        per = (r + 1) ** 3 * NODE_STRIDE
        keep = np.nonzero(good > 0)[0]
        n_blocks = int(keep.size)
        fine = np.ascontiguousarray(blocks.reshape(-1, per)[keep].ravel().astype(dtype))
        rec[flagged[keep], 5] = np.arange(1, keep.size + 1)
        sub_exact = int(keep.size * r ** 3 - good[keep].sum())
        exact_blocks = flagged[keep[good[keep] < r ** 3]]
    head[8] = fine.size
    fine = np.ascontiguousarray(np.concatenate([fine, mrec.ravel().astype(dtype)]))
    stage()
    t4 = time.perf_counter()
    # the exact query's arrays, pruned to the leaves the lookup can ask: those of the cells it answers
    # exactly and those reaching outside the grid
    exact: tuple[npt.NDArray[Any], ...] = wall._args
    exact_max_depth = exact_max_depth or int(wall.tree.depth.max())
    if prune:
        exact = _pruned(wall, head, np.concatenate([np.nonzero(rec[:, 5] == -1.0)[0], exact_blocks]), exact_max_leaf,
                        exact_max_depth)
    stage()
    t5 = time.perf_counter()
    # list cells: the exact cells and those with exact sub-cells, wholly in the lumen, whose few nearest triangles
    # a short scan answers as the exact query
    lcells = np.zeros(0, dtype=np.int64)
    if list_max > 0:
        lcells = np.concatenate([np.nonzero((rec[:, 5] == -1.0) & cell_in.ravel())[0], exact_blocks[cell_in.ravel()[exact_blocks]]])
    fine, list_stats = _store_lists(head, rec, fine, lcells, int(list_lattice), int(list_sub), float(list_split),
                                    int(list_max), exact, dtype)
    stage()
    t6 = time.perf_counter()
    cells = (nx - 1) * (ny - 1) * (nz - 1)
    n_exact = int((rec[:, 5] == -1.0).sum())
    stats = {"nodes": float(nx * ny * nz), "cells": float(cells), "flagged_spread": float(counts[0]),
             "flagged_test": float(counts[1]), "tested_cells": float(counts[2]),
             "flagged_fraction": float(counts[0] + counts[1]) / cells, "refined_blocks": float(n_blocks),
             "exact_cells": float(n_exact), "exact_subcells": float(sub_exact),
             "exact_fraction": (n_exact + sub_exact / max(r, 1) ** 3) / cells, "lumen_nodes": float((diam > 0).sum()),
             "exact_balls": float(n_balls),
             "tube_cells": float(mrec.shape[0]), "model_cells_1": float(n_used[1]), "model_cells_2": float(n_used[2]),
             "model_cells_3": float(n_used[3]), "MB": (field.nbytes + fine.nbytes) / 1e6, "fine_MB": fine.nbytes / 1e6,
             "exact_MB": sum(a.nbytes for a in exact) / 1e6, "exact_index": float(exact[5].size),
             "exact_nodes": float(len(exact[4])), "exact_triangles": float(exact[0].size // 48),
             **list_stats,
             "sample_s": t1 - t0, "diameter_s": t2 - t1, "flag_s": t3 - t2, "tube_s": t3b - t3, "refine_s": t4 - t3b, "prune_s": t5 - t4,
             "list_s": t6 - t5, "build_s": t6 - t0}
    return WallField3D(wall, head, field, fine, stats, exact)
