"""The sampled 3-D wall's compiled lookup: distance, inward normal and diameter at a point, allocation-free.

:func:`wall_field3d` interpolates the node records of a
:class:`~vesselbot_ros.geometry.field_build.WallField3D` where its cell is good, else answers from the cell's
smooth models, its sub-cube's triangle list or the exact query; the record layout (``NODE_STRIDE``,
``MODEL_REC``) is defined here.  Formulas and measurements: docs/vessels.md, "The wall geometry", `field_lookup`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from vesselbot_ros.geometry.surface_query import _closest, _signed, _smooth_normal, _triangle_far, smooth_wall3d

__all__ = ["NODE_STRIDE", "MODELS", "MODEL_REC", "wall_field3d", "field_points3d", "corner_weight"]

#: Floats per node: s (0), inward normal (1-3), diameter (4), flag of the cell with this lowest corner (5), its
#: triangle list's offset in ``fine`` and length if it is a list cell (6-7; 0: none) (32 bytes in float32: two nodes
#: per cache line).
NODE_STRIDE = 8
#: Models per model cell; floats per model cell's record: ``MODELS`` models of ``NODE_STRIDE`` floats each (axis point, unit axis
#: direction, radius, sign sigma; sigma = 0: a plane, 9: no model).
MODELS = 3
MODEL_REC = MODELS * NODE_STRIDE
_NO_MODEL = 9.0
#: A list cell's lists start at ``fine[hi _LIST_BASE + lo]`` (the first two floats of its directory): each part
#: exact in float32.
_LIST_BASE = 1 << 20


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def corner_weight(c, tx, ty, tz):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(cx, cy, cz, w): corner ``c`` (0-7, x fastest) of a cell as offsets 0/1 per axis and its trilinear weight at
    (tx, ty, tz) in [0, 1]^3."""
    cx = c & 1
    cy = (c >> 1) & 1
    cz = c >> 2
    return cx, cy, cz, (tx if cx else 1.0 - tx) * (ty if cy else 1.0 - ty) * (tz if cz else 1.0 - tz)


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
        cx, cy, cz, w = corner_weight(c, tx, ty, tz)
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
def _diameter(field, base, sy, sz, tx, ty, tz):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """D of :func:`_interp` alone (the same doubles), for the cells whose distance and normal come from elsewhere."""
    dd = 0.0
    for c in range(8):
        cx, cy, cz, w = corner_weight(c, tx, ty, tz)
        dd += w * float(field[base + cx * NODE_STRIDE + cy * sy + cz * sz + 4])
    return dd


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def wall_field3d(px, py, pz, head, field, fine, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(s, nx, ny, nz, D)`` at (px, py, pz) (m): signed distance (m, > 0 in the lumen), unit inward normal and
    local diameter (m).

    ``head`` ``(x0, y0, z0, h, nx, ny, nz, r)``, ``field`` and ``fine`` (flat records of ``NODE_STRIDE``):
    the :class:`WallField3D`; ``d`` ... ``index``: its wall's exact-query arrays
    (:func:`~vesselbot_ros.geometry.surface_query.smooth_wall3d`), which answer in flagged cells and outside
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
    flag = field[base + 5]
    if flag == 0.0 or not inside:
        s, gx, gy, gz, dd = _interp(field, base, sy, sz, tx, ty, tz, h)
        if inside:
            return s, gx, gy, gz, dd
    else:
        dd = _diameter(field, base, sy, sz, tx, ty, tz)
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
    if inside and flag <= -2.0:
        s, gx, gy, gz, _rho = _models(px, py, pz, fine, int(head[8]) + (int(-flag) - 2) * MODEL_REC)
        return s, gx, gy, gz, dd
    if inside and field[base + 7] > 0.0:
        o, n = _sub_list(tx, ty, tz, fine, int(field[base + 6]), int(field[base + 7]))
        if n > 0:
            s, gx, gy, gz = _scan_list(px, py, pz, d, fine, o, n)
            return s, gx, gy, gz, dd
    s, gx, gy, gz = smooth_wall3d(px, py, pz, d, pbox, pstart, grid, nodes, index)
    return s, gx, gy, gz, dd


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _sub_list(tx, ty, tz, fine, o, sub):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(offset in ``fine``, length) of the triangle list of the sub-cube holding (tx, ty, tz) in [0, 1]^3 of the
    list cell whose directory starts at ``fine[o]`` (``sub``^3 sub-cubes; length 0: none, the exact query)."""
    c = (min(int(tz * sub), sub - 1) * sub + min(int(ty * sub), sub - 1)) * sub + min(int(tx * sub), sub - 1)
    a = int(fine[o + 2 + c])
    return int(fine[o]) * _LIST_BASE + int(fine[o + 1]) + a, int(fine[o + 3 + c]) - a


@numba.njit(cache=True)
def _sub_list_lengths(t, fine, o, sub):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(m,) the length of the list :func:`_sub_list` gives each point at ``t`` (m, 3) in its list cell (directory
    ``o``, division ``sub``)."""
    out = np.zeros(t.shape[0], dtype=np.int64)
    for k in range(t.shape[0]):
        out[k] = _sub_list(t[k, 0], t[k, 1], t[k, 2], fine, o[k], sub[k])[1]
    return out


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _model(px, py, pz, rec, o):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(s, inward normal, rho) of the model of record ``rec[o:o + 8]`` (axis point, unit axis direction, radius R,
    sign sigma) at (px, py, pz): ``sigma (rho - R)`` and ``sigma`` times the direction from the axis (rho: the
    distance from it); sigma = 0: the plane through the point with unit normal the direction, ``R + a . (q - p)``
    (rho: infinite)."""
    dx = px - float(rec[o])
    dy = py - float(rec[o + 1])
    dz = pz - float(rec[o + 2])
    ax = float(rec[o + 3])
    ay = float(rec[o + 4])
    az = float(rec[o + 5])
    a = dx * ax + dy * ay + dz * az
    sg = float(rec[o + 7])
    if sg == 0.0:
        return float(rec[o + 6]) + a, ax, ay, az, np.inf
    dx -= a * ax
    dy -= a * ay
    dz -= a * az
    rho = math.sqrt(dx * dx + dy * dy + dz * dz)
    if not (rho > 0.0):
        return -sg * float(rec[o + 6]), 0.0, 0.0, -1.0, 0.0
    return sg * (rho - float(rec[o + 6])), sg * dx / rho, sg * dy / rho, sg * dz / rho, rho


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _models(px, py, pz, rec, o):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(s, inward normal, rho) of the model cell of record ``rec[o:o + MODEL_REC]``: the least of its models' s,
    the normal (and distance from the axis) of the model that attains it (the first of equals)."""
    s, gx, gy, gz, rho = _model(px, py, pz, rec, o)
    for m in range(1, MODELS):
        b = o + m * NODE_STRIDE
        if float(rec[b + 7]) == _NO_MODEL:
            break
        s2, hx, hy, hz, r2 = _model(px, py, pz, rec, b)
        if s2 < s:
            s, gx, gy, gz, rho = s2, hx, hy, hz, r2
    return s, gx, gy, gz, rho


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _scan_list(px, py, pz, d, lst, o, n):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`~vesselbot_ros.geometry.surface_query.smooth_wall3d` over the triangles ``lst[o:o + n]`` (their indices,
    nearest the cell's centre first) of a list cell: the same bounds, closest points and tie rule (the lowest
    index), so bit for bit its answer wherever the list holds the nearest triangle."""
    tbest = int(lst[o])
    best, fx, fy, fz, feat = _closest(px, py, pz, d, 48 * tbest + 8)
    for e in range(o + 1, o + n):
        t = int(lst[e])
        b = 48 * t
        if _triangle_far(px, py, pz, d, b, best):
            continue
        d2, gx, gy, gz, f = _closest(px, py, pz, d, b + 8)
        if d2 < best or (d2 == best and t < tbest):
            best = d2
            fx = gx
            fy = gy
            fz = gz
            feat = f
            tbest = t
    s, nx, ny, nz = _signed(px, py, pz, d, best, fx, fy, fz, feat, tbest)
    gx, gy, gz = _smooth_normal(px, py, pz, d, tbest, s, nx, ny, nz)
    return s, gx, gy, gz


@numba.njit(cache=True)
def field_points3d(pts, head, field, fine, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(m, 5) rows ``(s, nx, ny, nz, D)`` of :func:`wall_field3d` at points (m, 3) (m)."""
    out = np.empty((pts.shape[0], 5))
    for k in range(pts.shape[0]):
        r = wall_field3d(pts[k, 0], pts[k, 1], pts[k, 2], head, field, fine, d, pbox, pstart, grid, nodes, index)
        for c in range(5):
            out[k, c] = r[c]
    return out
