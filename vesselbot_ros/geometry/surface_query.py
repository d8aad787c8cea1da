"""The exact 3-D wall query, compiled: signed distance and inward normal at a point, allocation-free.

:func:`nearest_wall3d` walks the candidate tree to the point's leaf and scans its patches (box, chunk and
triangle bounds, Ericson's closest point, the pseudonormal sign); :func:`smooth_wall3d` keeps its distance
and interpolates the normal from the nearest triangle's corner normals.  Rules, proofs and measurements:
docs/vessels.md, "The wall geometry", `surface_query`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["nearest_wall3d", "smooth_wall3d", "query_points3d", "brute_force3d"]

@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _closest(px, py, pz, d, b):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(squared distance, foot x, y, z, feature) of a point to the triangle with corners ``d[b:b + 9]`` (Ericson 5.1.5).

    Feature: 0 face, 1-3 vertex A, B, C, 4-6 edge AB, BC, CA.
    """
    ax = d[b]
    ay = d[b + 1]
    az = d[b + 2]
    abx = d[b + 3] - ax
    aby = d[b + 4] - ay
    abz = d[b + 5] - az
    acx = d[b + 6] - ax
    acy = d[b + 7] - ay
    acz = d[b + 8] - az
    apx = px - ax
    apy = py - ay
    apz = pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return apx * apx + apy * apy + apz * apz, ax, ay, az, 1
    bpx = px - d[b + 3]
    bpy = py - d[b + 4]
    bpz = pz - d[b + 5]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bpx * bpx + bpy * bpy + bpz * bpz, d[b + 3], d[b + 4], d[b + 5], 2
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        fx = ax + t * abx
        fy = ay + t * aby
        fz = az + t * abz
        return (px - fx) ** 2 + (py - fy) ** 2 + (pz - fz) ** 2, fx, fy, fz, 4
    cpx = px - d[b + 6]
    cpy = py - d[b + 7]
    cpz = pz - d[b + 8]
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cpx * cpx + cpy * cpy + cpz * cpz, d[b + 6], d[b + 7], d[b + 8], 3
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        fx = ax + t * acx
        fy = ay + t * acy
        fz = az + t * acz
        return (px - fx) ** 2 + (py - fy) ** 2 + (pz - fz) ** 2, fx, fy, fz, 6
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        fx = d[b + 3] + t * (d[b + 6] - d[b + 3])
        fy = d[b + 4] + t * (d[b + 7] - d[b + 4])
        fz = d[b + 5] + t * (d[b + 8] - d[b + 5])
        return (px - fx) ** 2 + (py - fy) ** 2 + (pz - fz) ** 2, fx, fy, fz, 5
    den = 1.0 / (va + vb + vc)
    v = vb * den
    w = vc * den
    fx = ax + abx * v + acx * w
    fy = ay + aby * v + acy * w
    fz = az + abz * v + acz * w
    return (px - fx) ** 2 + (py - fy) ** 2 + (pz - fz) ** 2, fx, fy, fz, 0


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _leaf(px, py, pz, grid, nodes):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The leaf node holding the point (outside the root grid: the leaf at its nearest edge)."""
    a = grid[3]
    nx = int(grid[4])
    ny = int(grid[5])
    nz = int(grid[6])
    i = min(max(int(np.floor((px - grid[0]) / a)), 0), nx - 1)
    j = min(max(int(np.floor((py - grid[1]) / a)), 0), ny - 1)
    k = min(max(int(np.floor((pz - grid[2]) / a)), 0), nz - 1)
    node = (k * ny + j) * nx + i
    half = 0.5 * a
    cx = grid[0] + (i + 0.5) * a
    cy = grid[1] + (j + 0.5) * a
    cz = grid[2] + (k + 0.5) * a
    while nodes[node, 0] >= 0:
        half *= 0.5
        o = 0
        if px >= cx:
            o += 1
            cx += half
        else:
            cx -= half
        if py >= cy:
            o += 2
            cy += half
        else:
            cy -= half
        if pz >= cz:
            o += 4
            cz += half
        else:
            cz -= half
        node = nodes[node, 0] + o
    return node


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _box_dist2(px, py, pz, pbox, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Squared distance (m^2) of a point to patch ``p``'s oriented box (a lower bound of its triangles')."""
    o = 15 * p
    g2 = 0.0
    for a in range(3):
        pr = pbox[o + 3 * a] * px + pbox[o + 3 * a + 1] * py + pbox[o + 3 * a + 2] * pz
        if pr < pbox[o + 9 + a]:
            g2 += (pbox[o + 9 + a] - pr) ** 2
        elif pr > pbox[o + 12 + a]:
            g2 += (pr - pbox[o + 12 + a]) ** 2
    return g2


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _scan(px, py, pz, d, pbox, pstart, index, lo, hi, seed):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(squared distance, foot x, y, z, feature, triangle) nearest over the patches ``index[lo:hi]``.

    Starts from triangle ``seed`` (the leaf centre's nearest, so the bounds prune from the start); a patch
    whose box is farther than the best so far is skipped, and a triangle whose bounding disc (in its plane)
    is; ties (equal squared distance) go to the lowest triangle index.
    """
    tbest = seed
    best, fx, fy, fz, feat = _closest(px, py, pz, d, 48 * seed + 8)
    for e in range(lo, hi):
        p = index[e]
        if _box_dist2(px, py, pz, pbox, p) > best:
            continue
        t0 = pstart[p]
        t1 = pstart[p + 1]
        while t0 < t1:
            b = 48 * t0
            L = int(d[b + 7])
            if L >= 2 and _chunk_far(px, py, pz, d, b, best):
                t0 += L
                continue
            for t in range(t0, t0 + L):
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
            t0 += L
    return best, fx, fy, fz, feat, tbest


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _triangle_far(px, py, pz, d, b, best):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """True if the triangle of record ``b`` lies farther than sqrt(best) from the point: a lower bound, the triangle
    lying in the disc of radius r round its centroid in its plane."""
    sx = px - d[b]
    sy = py - d[b + 1]
    sz = pz - d[b + 2]
    hn = sx * d[b + 4] + sy * d[b + 5] + sz * d[b + 6]
    h2 = hn * hn
    if h2 > best:
        return True
    rin = math.sqrt(max(sx * sx + sy * sy + sz * sz - h2, 0.0)) - d[b + 3]
    return rin > 0.0 and h2 + rin * rin > best


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _chunk_far(px, py, pz, d, b, best):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """True if the chunk starting at record ``b`` lies farther than sqrt(best) from the point: its triangles lie in
    the slab of its half thickness round its plane, within its in-plane radius of its centre."""
    sx = px - d[b + 44]
    sy = py - d[b + 45]
    sz = pz - d[b + 46]
    hn = abs(sx * d[b + 92] + sy * d[b + 93] + sz * d[b + 94])
    a = max(hn - d[b + 95], 0.0)
    h2 = a * a
    if h2 > best:
        return True
    rin = math.sqrt(max(sx * sx + sy * sy + sz * sz - hn * hn, 0.0)) - d[b + 47]
    return rin > 0.0 and h2 + rin * rin > best


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _signed(px, py, pz, d, best, fx, fy, fz, feat, t):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(s, inward normal x, y, z) from the nearest triangle's foot and feature (pseudonormal sign)."""
    if t < 0:
        return -np.inf, 0.0, 0.0, -1.0
    b = 48 * t
    if feat == 0:
        o = b + 4
    elif feat <= 3:
        o = b + 26 + 3 * (feat - 1)
    else:
        o = b + 17 + 3 * (feat - 4)
    ex = px - fx
    ey = py - fy
    ez = pz - fz
    dist = math.sqrt(best)
    if dist == 0.0:
        return 0.0, -d[b + 4], -d[b + 5], -d[b + 6]
    if ex * d[o] + ey * d[o + 1] + ez * d[o + 2] < 0.0:
        return dist, ex / dist, ey / dist, ez / dist
    return -dist, -ex / dist, -ey / dist, -ez / dist


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def nearest_wall3d(px, py, pz, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(s, nx, ny, nz)``: exact signed distance (m, > 0 in the lumen) and unit inward normal at (px, py, pz) (m).

    ``d``, ``pbox``, ``pstart``: the surface's triangle data, patch boxes and patch starts
    (:class:`WallSurface`); ``grid``, ``nodes``, ``index``: its :class:`CandidateTree`.  The normal is
    ``(q - foot) / |q - foot|`` inside, its opposite outside, the triangle's inward normal on the wall itself.
    Allocates nothing.
    """
    leaf = _leaf(px, py, pz, grid, nodes)
    best, fx, fy, fz, feat, t = _scan(px, py, pz, d, pbox, pstart, index, nodes[leaf, 1], nodes[leaf, 2], nodes[leaf, 3])
    s, nx, ny, nz = _signed(px, py, pz, d, best, fx, fy, fz, feat, t)
    if nodes[leaf, 1] < 0 and s > 0.0:  # a sealed leaf: wholly outside, its seed's answer signed so
        return -s, -nx, -ny, -nz
    return s, nx, ny, nz


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _smooth_normal(px, py, pz, d, t, s, nx, ny, nz):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Inward unit normal of the corner-normal field of triangle ``t`` seen from the point (docs/vessels.md)."""
    b = 48 * t + 8
    ax = d[b]
    ay = d[b + 1]
    az = d[b + 2]
    e1x = d[b + 3] - ax
    e1y = d[b + 4] - ay
    e1z = d[b + 5] - az
    e2x = d[b + 6] - ax
    e2y = d[b + 7] - ay
    e2z = d[b + 8] - az
    nax = d[b + 27]
    nay = d[b + 28]
    naz = d[b + 29]
    g1x = d[b + 30] - nax
    g1y = d[b + 31] - nay
    g1z = d[b + 32] - naz
    g2x = d[b + 33] - nax
    g2y = d[b + 34] - nay
    g2z = d[b + 35] - naz
    wx = px - ax
    wy = py - ay
    wz = pz - az
    tt = -s  # outward offset
    scale = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
    for _it in range(8):
        E1x = e1x + tt * g1x
        E1y = e1y + tt * g1y
        E1z = e1z + tt * g1z
        E2x = e2x + tt * g2x
        E2y = e2y + tt * g2y
        E2z = e2z + tt * g2z
        Wx = wx - tt * nax
        Wy = wy - tt * nay
        Wz = wz - tt * naz
        cx = E1y * E2z - E1z * E2y
        cy = E1z * E2x - E1x * E2z
        cz = E1x * E2y - E1y * E2x
        f = cx * Wx + cy * Wy + cz * Wz
        # d/dt (E1 x E2) = g1 x E2 + E1 x g2
        dcx = g1y * E2z - g1z * E2y + E1y * g2z - E1z * g2y
        dcy = g1z * E2x - g1x * E2z + E1z * g2x - E1x * g2z
        dcz = g1x * E2y - g1y * E2x + E1x * g2y - E1y * g2x
        fp = dcx * Wx + dcy * Wy + dcz * Wz - (cx * nax + cy * nay + cz * naz)
        if fp == 0.0:
            break
        step = f / fp
        tt -= step
        if abs(step) <= 1e-9 * scale:
            break
    E1x = e1x + tt * g1x
    E1y = e1y + tt * g1y
    E1z = e1z + tt * g1z
    E2x = e2x + tt * g2x
    E2y = e2y + tt * g2y
    E2z = e2z + tt * g2z
    Wx = wx - tt * nax
    Wy = wy - tt * nay
    Wz = wz - tt * naz
    cx = E1y * E2z - E1z * E2y
    cy = E1z * E2x - E1x * E2z
    cz = E1x * E2y - E1y * E2x
    nn = cx * cx + cy * cy + cz * cz
    if not (nn > 0.0) or not (abs(tt + s) <= 2.0 * scale + 0.5 * abs(s)):
        return nx, ny, nz  # degenerate offset triangle (near a focal point): keep the exact normal
    # barycentrics of q in the offset triangle: W = u E1 + v E2 (+ normal part)
    u = ((Wy * E2z - Wz * E2y) * cx + (Wz * E2x - Wx * E2z) * cy + (Wx * E2y - Wy * E2x) * cz) / nn
    v = ((E1y * Wz - E1z * Wy) * cx + (E1z * Wx - E1x * Wz) * cy + (E1x * Wy - E1y * Wx) * cz) / nn
    if u < 0.0:
        u = 0.0
    if v < 0.0:
        v = 0.0
    if u + v > 1.0:
        sm = u + v
        u /= sm
        v /= sm
    mx = nax + u * g1x + v * g2x
    my = nay + u * g1y + v * g2y
    mz = naz + u * g1z + v * g2z
    L = math.sqrt(mx * mx + my * my + mz * mz)
    if not (L > 0.0):
        return nx, ny, nz
    return -mx / L, -my / L, -mz / L


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def smooth_wall3d(px, py, pz, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(s, nx, ny, nz)``: :func:`nearest_wall3d`'s exact distance (m) with the smooth inward normal.

    The normal of the corner-normal field of the nearest triangle (docs/vessels.md): within a fraction of
    a degree of the smooth wall's where the facets' is off by h / (2 R).  Allocates nothing.
    """
    leaf = _leaf(px, py, pz, grid, nodes)
    best, fx, fy, fz, feat, t = _scan(px, py, pz, d, pbox, pstart, index, nodes[leaf, 1], nodes[leaf, 2], nodes[leaf, 3])
    s, nx, ny, nz = _signed(px, py, pz, d, best, fx, fy, fz, feat, t)
    if t < 0:
        return s, nx, ny, nz
    if nodes[leaf, 1] < 0:  # a sealed leaf: wholly outside, its seed's answer signed so (exact normal)
        if s > 0.0:
            return -s, -nx, -ny, -nz
        return s, nx, ny, nz
    gx, gy, gz = _smooth_normal(px, py, pz, d, t, s, nx, ny, nz)
    return s, gx, gy, gz


@numba.njit(cache=True)
def query_points3d(pts, d, pbox, pstart, grid, nodes, index, smooth):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(m, 4) rows ``(s, nx, ny, nz)`` at points (m, 3) (m): :func:`smooth_wall3d` if ``smooth`` else
    :func:`nearest_wall3d`."""
    out = np.empty((pts.shape[0], 4))
    for k in range(pts.shape[0]):
        if smooth:
            s, gx, gy, gz = smooth_wall3d(pts[k, 0], pts[k, 1], pts[k, 2], d, pbox, pstart, grid, nodes, index)
        else:
            s, gx, gy, gz = nearest_wall3d(pts[k, 0], pts[k, 1], pts[k, 2], d, pbox, pstart, grid, nodes, index)
        out[k, 0] = s
        out[k, 1] = gx
        out[k, 2] = gy
        out[k, 3] = gz
    return out


@numba.njit(cache=True)
def brute_force3d(pts, d, smooth):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`query_points3d` over every triangle (no candidate tree): the reference of the candidate rule."""
    m = d.size // 48
    out = np.empty((pts.shape[0], 4))
    for k in range(pts.shape[0]):
        px = pts[k, 0]
        py = pts[k, 1]
        pz = pts[k, 2]
        best = np.inf
        fx = px
        fy = py
        fz = pz
        feat = -1
        tb = -1
        for t in range(m):
            d2, gx, gy, gz, f = _closest(px, py, pz, d, 48 * t + 8)
            if d2 < best:  # ascending t: ties keep the lowest index, as _scan
                best = d2
                fx = gx
                fy = gy
                fz = gz
                feat = f
                tb = t
        s, nx, ny, nz = _signed(px, py, pz, d, best, fx, fy, fz, feat, tb)
        if smooth and tb >= 0:
            nx, ny, nz = _smooth_normal(px, py, pz, d, tb, s, nx, ny, nz)
        out[k, 0] = s
        out[k, 1] = nx
        out[k, 2] = ny
        out[k, 3] = nz
    return out
