"""The 3-D wall surface: the oriented triangles of the lumen's boundary, continued beyond the caps, packed for the query.

:func:`wall_surface` orients the wall's triangles, extrudes each cap's rim into a straight tube, and packs per
triangle its corners, face, edge and vertex pseudonormals, smooth corner normals and bounds (``STRIDE`` floats),
grouped in patches (each with an oriented box) and chunks of at most ``CHUNK``.  The rules: docs/vessels.md, "The wall geometry", `surface`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.blas_free import dot3

__all__ = ["STRIDE", "CHUNK", "Cap", "WallSurface", "wall_surface"]

#: Floats stored per triangle: the bound (centroid 0-2, radius of its disc 3, unit outward face normal 4-6;
#: one cache line), corners A, B, C (8-16), edge pseudonormals AB, BC, CA (17-25), vertex pseudonormals A, B, C
#: (26-34), smooth corner normals A, B, C (35-43); the chunk's (see :func:`wall_surface`): its length at its
#: first triangle (7, else 0), its centre and in-plane radius (44-47 of its first), its normal and half
#: thickness (44-47 of its second) (a multiple of 64 bytes).
STRIDE = 48
#: Triangles per chunk: each patch's triangles are split in compact chunks, each bounded as a thick disc.
CHUNK = 8

#: A cap: (centre (3,) m, unit outward normal (3,), radius m).
Cap = tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], float]

Array = npt.NDArray[np.float64]
IArray = npt.NDArray[np.int64]


@dataclasses.dataclass(frozen=True)
class WallSurface:
    """An oriented wall surface with its per-triangle query data.

    Attributes:
        vertices: (n, 3) vertices (m), the wall's then the extensions' far ends.
        triangles: (t, 3) vertex indices, outward (counter-clockwise seen from outside the lumen).
        is_wall: (t,) the wall's triangles (the others extend it beyond the caps).
        data: (t * STRIDE,) flat per-triangle query data (see ``STRIDE``).
        patch_start: (P + 1,) the triangles are grouped in patches (those whose centroid lies in one cube of
            side ``patch_m``), patch p holding triangles ``patch_start[p]:patch_start[p + 1]``.
        patch_box: (P * 15,) each patch's oriented bounding box: three orthonormal axes (9) and the ranges
            of its vertices' projections on them (lo (3), hi (3)), in the axes' coordinates (m).
        caps: The caps (centre, outward normal, radius).
    """

    vertices: Array
    triangles: IArray
    is_wall: npt.NDArray[np.bool_]
    data: Array
    patch_start: IArray
    patch_box: Array
    caps: tuple[Cap, ...]

    def wall_vertices(self) -> Array:
        """(k, 3) the wall's vertices (m), the extensions' far ends left out."""
        return self.vertices[np.unique(self.triangles[self.is_wall])]


def _orient(tri: IArray) -> IArray:
    """Triangles made consistently oriented across shared edges (breadth first from each component's first)."""
    tri = tri.copy()
    m = len(tri)
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    owner = np.tile(np.arange(m), 3)
    _u, inv, cnt = np.unique(_edge_keys(e), return_inverse=True, return_counts=True)
    inv = inv.ravel()
    if cnt.max() > 2:
        raise ValueError("wall_surface: an edge is shared by more than two triangles (non-manifold surface)")
    order = np.argsort(inv, kind="stable")
    sinv = inv[order]
    pair = np.nonzero(sinv[1:] == sinv[:-1])[0]
    h1, h2 = order[pair], order[pair + 1]
    same = np.all(e[h1] == e[h2], axis=1)  # equally directed half-edges: the two triangles disagree
    flip, ok = _flips(m, owner[h1], owner[h2], same)
    if not ok:
        raise ValueError("wall_surface: the surface is not orientable")
    tri[flip] = tri[flip][:, [0, 2, 1]]
    return tri


@numba.njit(cache=True)
def _flips(m, t1, t2, same):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(flip (m,), orientable): which of m triangles to flip so that every adjacent pair (t1, t2) agrees
    (``same``: their shared edge runs the same way in both, they disagree), breadth first from each
    component's first triangle."""
    deg = np.zeros(m + 1, dtype=np.int64)
    for e in range(t1.size):
        deg[t1[e] + 1] += 1
        deg[t2[e] + 1] += 1
    for i in range(m):
        deg[i + 1] += deg[i]
    fill = deg[:-1].copy()
    nb = np.empty(2 * t1.size, dtype=np.int64)
    sm = np.empty(2 * t1.size, dtype=np.bool_)
    for e in range(t1.size):
        nb[fill[t1[e]]] = t2[e]
        sm[fill[t1[e]]] = same[e]
        fill[t1[e]] += 1
        nb[fill[t2[e]]] = t1[e]
        sm[fill[t2[e]]] = same[e]
        fill[t2[e]] += 1
    flip = np.zeros(m, dtype=np.bool_)
    seen = np.zeros(m, dtype=np.bool_)
    queue = np.empty(m, dtype=np.int64)
    ok = True
    for start in range(m):
        if seen[start]:
            continue
        seen[start] = True
        head = 0
        tail = 1
        queue[0] = start
        while head < tail:
            t = queue[head]
            head += 1
            for e in range(deg[t], deg[t + 1]):
                want = flip[t] ^ sm[e]
                o = nb[e]
                if not seen[o]:
                    seen[o] = True
                    flip[o] = want
                    queue[tail] = o
                    tail += 1
                elif flip[o] != want:
                    ok = False
    return flip, ok


def _boundary_edges(tri: IArray) -> IArray:
    """(b, 2) directed boundary edges (as their triangle runs them)."""
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    _u, inv, cnt = np.unique(_edge_keys(e), return_inverse=True, return_counts=True)
    return e[cnt[inv.ravel()] == 1]


def _edge_keys(e: IArray) -> IArray:
    """One int64 per undirected edge (k, 2) of vertex indices."""
    lo = np.minimum(e[:, 0], e[:, 1]).astype(np.int64)
    hi = np.maximum(e[:, 0], e[:, 1]).astype(np.int64)
    return lo * (int(e.max(initial=0)) + 1) + hi


@numba.njit(cache=True)
def _triangle_data(v, tri, crease_cos, vnormal_override, chunk_len):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    m = tri.shape[0]
    n = v.shape[0]
    out = np.zeros(m * 48)
    fn = np.zeros((m, 3))
    ang = np.zeros((m, 3))
    for t in range(m):
        a = v[tri[t, 0]]
        b = v[tri[t, 1]]
        c = v[tri[t, 2]]
        cr = np.cross(b - a, c - a)
        fn[t] = cr / math.sqrt(dot3(cr, cr))
        for k in range(3):
            p = v[tri[t, k]]
            q1 = v[tri[t, (k + 1) % 3]] - p
            q2 = v[tri[t, (k + 2) % 3]] - p
            x = np.cross(q1, q2)
            ang[t, k] = math.atan2(math.sqrt(dot3(x, x)), dot3(q1, q2))
    # vertex -> incident (triangle, corner) CSR
    cnt = np.zeros(n + 1, dtype=np.int64)
    for t in range(m):
        for k in range(3):
            cnt[tri[t, k] + 1] += 1
    for i in range(n):
        cnt[i + 1] += cnt[i]
    fill = cnt[:-1].copy()
    inc_t = np.empty(3 * m, dtype=np.int64)
    inc_k = np.empty(3 * m, dtype=np.int64)
    for t in range(m):
        for k in range(3):
            i = tri[t, k]
            inc_t[fill[i]] = t
            inc_k[fill[i]] = k
            fill[i] += 1
    vn = np.zeros((n, 3))
    for i in range(n):
        for e in range(cnt[i], cnt[i + 1]):
            vn[i] += ang[inc_t[e], inc_k[e]] * fn[inc_t[e]]
        L = math.sqrt(dot3(vn[i], vn[i]))
        if L > 0:
            vn[i] /= L
    # edge pseudonormals: sum of the (at most two) faces' normals
    for t in range(m):
        for k in range(3):
            i = tri[t, k]
            j = tri[t, (k + 1) % 3]
            en = fn[t].copy()
            for e in range(cnt[i], cnt[i + 1]):
                s = inc_t[e]
                if s == t:
                    continue
                has_j = tri[s, 0] == j or tri[s, 1] == j or tri[s, 2] == j
                if has_j:
                    en += fn[s]
            L = math.sqrt(dot3(en, en))
            for d in range(3):
                out[48 * t + 17 + 3 * k + d] = en[d] / L
    for t in range(m):
        b0 = 48 * t
        for k in range(3):
            i = tri[t, k]
            for d in range(3):
                out[b0 + 8 + 3 * k + d] = v[i, d]
                out[b0 + 26 + 3 * k + d] = vn[i, d]
            cn = np.zeros(3)
            for e in range(cnt[i], cnt[i + 1]):
                s = inc_t[e]
                if dot3(fn[s], fn[t]) >= crease_cos:
                    cn += ang[s, inc_k[e]] * fn[s]
            if vnormal_override.shape[0] == n:
                ov = vnormal_override[i] if dot3(vnormal_override[i], vn[i]) >= 0.0 else -vnormal_override[i]
                if dot3(ov, fn[t]) >= crease_cos:
                    cn = ov.copy()
            L = math.sqrt(dot3(cn, cn))
            for d in range(3):
                out[b0 + 35 + 3 * k + d] = cn[d] / L
        for d in range(3):
            out[b0 + 4 + d] = fn[t, d]
        cen = (v[tri[t, 0]] + v[tri[t, 1]] + v[tri[t, 2]]) / 3.0
        r = 0.0
        for k in range(3):
            dd = v[tri[t, k]] - cen
            r = max(r, math.sqrt(dot3(dd, dd)))
        for d in range(3):
            out[b0 + d] = cen[d]
        out[b0 + 3] = r * (1.0 + 1e-9) + 1e-15  # a little larger: the sphere test never rejects a tie
    # chunks: at a chunk's first triangle its length (7), centre (44-46) and in-plane radius (47); at its second
    # the chunk's unit normal (44-46) and half thickness (47) (both padded: the bound never rejects a tie)
    for t in range(m):
        L = chunk_len[t]
        out[48 * t + 7] = L
        if L < 2:
            continue
        c = np.zeros(3)
        nsum = np.zeros(3)
        for u in range(t, t + L):
            for k in range(3):
                c += v[tri[u, k]] / (3.0 * L)
            nsum += np.cross(v[tri[u, 1]] - v[tri[u, 0]], v[tri[u, 2]] - v[tri[u, 0]])
        nn = nsum / max(math.sqrt(dot3(nsum, nsum)), 1e-300)
        rad = 0.0
        thick = 0.0
        for u in range(t, t + L):
            for k in range(3):
                dv = v[tri[u, k]] - c
                hn = dot3(dv, nn)
                thick = max(thick, abs(hn))
                rad = max(rad, math.sqrt(max(dot3(dv, dv) - hn * hn, 0.0)))
        pad = 1e-9 * math.sqrt(dot3(c, c)) + 1e-15
        for d in range(3):
            out[48 * t + 44 + d] = c[d]
            out[48 * (t + 1) + 44 + d] = nn[d]
        out[48 * t + 47] = rad * (1.0 + 1e-9) + pad
        out[48 * (t + 1) + 47] = thick * (1.0 + 1e-9) + pad
    return out


@numba.njit(cache=True)
def _chunks(cen, pstart, size):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(order, chunk length at each chunk's first position): each patch's triangles (centroids ``cen`` in patch
    order) split in chunks of at most ``size`` by halving along the centroids' longest extent."""
    m = cen.shape[0]
    order = np.arange(m)
    length = np.zeros(m, dtype=np.int64)
    stack = np.empty((64, 2), dtype=np.int64)
    for p in range(pstart.size - 1):
        top = 0
        stack[0, 0] = pstart[p]
        stack[0, 1] = pstart[p + 1]
        top = 1
        while top > 0:
            top -= 1
            lo = stack[top, 0]
            hi = stack[top, 1]
            n = hi - lo
            if n <= size:
                if n > 0:
                    length[lo] = n
                continue
            ext = np.zeros(3)
            for a in range(3):
                mn = np.inf
                mx = -np.inf
                for u in range(lo, hi):
                    mn = min(mn, cen[order[u], a])
                    mx = max(mx, cen[order[u], a])
                ext[a] = mx - mn
            ax = int(np.argmax(ext))
            sub = order[lo:hi].copy()
            keys = np.empty(n)
            for u in range(n):
                keys[u] = cen[sub[u], ax]
            idx = np.argsort(keys, kind="mergesort")
            for u in range(n):
                order[lo + u] = sub[idx[u]]
            mid = lo + ((n + size - 1) // size // 2) * size
            stack[top, 0] = lo
            stack[top, 1] = mid
            stack[top + 1, 0] = mid
            stack[top + 1, 1] = hi
            top += 2
    return order, length


@numba.njit(cache=True)
def _patch_boxes(v, tri, pstart):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    npatch = pstart.size - 1
    out = np.zeros(15 * npatch)
    for p in range(npatch):
        nsum = np.zeros(3)
        for t in range(pstart[p], pstart[p + 1]):
            nsum += np.cross(v[tri[t, 1]] - v[tri[t, 0]], v[tri[t, 2]] - v[tri[t, 0]])
        L = math.sqrt(dot3(nsum, nsum))
        ax = np.eye(3)
        if L > 0.0:
            n = nsum / L
            k = np.argmin(np.abs(n))
            e = np.zeros(3)
            e[k] = 1.0
            t1 = e - dot3(e, n) * n
            t1 /= math.sqrt(dot3(t1, t1))
            t2 = np.cross(n, t1)
            ax[0] = n
            ax[1] = t1
            ax[2] = t2
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for t in range(pstart[p], pstart[p + 1]):
            for c in range(3):
                x = v[tri[t, c]]
                for a in range(3):
                    pr = ax[a, 0] * x[0] + ax[a, 1] * x[1] + ax[a, 2] * x[2]
                    lo[a] = min(lo[a], pr)
                    hi[a] = max(hi[a], pr)
        b = 15 * p
        for a in range(3):
            for c in range(3):
                out[b + 3 * a + c] = ax[a, c]
            pad = 1e-12 + 1e-12 * (abs(lo[a]) + abs(hi[a]))  # rounding: the box never cuts a triangle
            out[b + 9 + a] = lo[a] - pad
            out[b + 12 + a] = hi[a] + pad
    return out


def wall_surface(vertices: npt.ArrayLike, triangles: npt.ArrayLike, caps: Sequence[Cap], extension_m: float,
                 crease_deg: float = 30.0, vertex_normals: npt.ArrayLike | None = None,
                 patch_m: float = 0.25e-3) -> WallSurface:
    """The oriented wall, continued beyond its caps, with its per-triangle query data.

    Args:
        vertices: (n, 3) wall vertices (m).
        triangles: (t, 3) vertex indices of the wall's triangles (caps excluded; any orientation).
        caps: The open ends: (centre (3,) m, unit outward normal (3,), radius m) each.  Every boundary edge of
            the wall must lie on one cap's rim (in its plane, within its radius).
        extension_m: Length (m) of each cap rim's extrusion along the cap's outward normal.
        crease_deg: Corner normals average the faces within this angle (deg) of the corner's face only.
        vertex_normals: Optional (n, 3) exact unit normals (either sign, each) of the smooth wall at the
            vertices (e.g. from the CAD: :func:`gmsh_wall`), used for the smooth normal where within
            ``crease_deg`` of the face (elsewhere, at a crease, the crease-aware mesh normal).
        patch_m: Side (m) of the cubes grouping the triangles in patches (the candidate lists hold patches).

    Returns:
        The :class:`WallSurface` (outward triangles, the wall's first).

    Raises:
        ValueError: A non-manifold or non-orientable surface, or a boundary edge on no cap.
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    tri = _orient(np.asarray(triangles, dtype=np.int64))
    bnd = _boundary_edges(tri)
    # the caps' normals unit by elementwise sums (np.linalg.norm of a vector is a BLAS ddot, its order by CPU)
    caps_t = tuple((np.asarray(c, dtype=np.float64), nn / math.sqrt(dot3(nn, nn)), float(r))
                   for c, nn, r in ((c, np.asarray(nn, dtype=np.float64), r) for c, nn, r in caps))
    which = np.full(len(bnd), -1)
    for k, (c, nn, r) in enumerate(caps_t):
        on = np.ones(len(bnd), dtype=bool)
        for end in (0, 1):
            p = v[bnd[:, end]] - c
            on &= (np.abs((p[:, 0] * nn[0] + p[:, 1] * nn[1]) + p[:, 2] * nn[2]) < 1e-3 * r) & (np.linalg.norm(p, axis=1) <= r * (1 + 1e-3))
        which[on & (which < 0)] = k
    if (which < 0).any():
        raise ValueError(f"wall_surface: {(which < 0).sum()} boundary edges lie on no cap")
    # outward: the volume closed by fans to the cap centres is positive
    vol = np.einsum("ij,ij->i", v[tri[:, 0]], np.cross(v[tri[:, 1]], v[tri[:, 2]])).sum()
    for k, (c, _nn, _r) in enumerate(caps_t):
        e = bnd[which == k]
        vol += np.einsum("ij,ij->i", v[e[:, 1]], np.cross(v[e[:, 0]], np.broadcast_to(c, (len(e), 3)))).sum()
    if vol < 0:
        tri = tri[:, [0, 2, 1]]
        bnd = bnd[:, ::-1]
    n_wall = len(tri)
    # extrusions: rim edge i -> j (as its wall triangle runs it) gets (j, i, i') and (j, i', j')
    far: dict[int, int] = {}
    new_v: list[npt.NDArray[np.float64]] = []
    ext = []
    for (i, j), k in zip(bnd.tolist(), which.tolist()):
        c, nn, _r = caps_t[k]
        ids = []
        for a in (i, j):
            if a not in far:
                far[a] = len(v) + len(new_v)
                new_v.append(v[a] + extension_m * nn)
            ids.append(far[a])
        ext += [(j, i, ids[0]), (j, ids[0], ids[1])]
    v_all = np.ascontiguousarray(np.concatenate([v, np.array(new_v).reshape(-1, 3)]))
    tri_all = np.ascontiguousarray(np.concatenate([tri, np.array(ext, dtype=np.int64).reshape(-1, 3)]))
    over = np.zeros((0, 3))
    if vertex_normals is not None:
        vn = np.asarray(vertex_normals, dtype=np.float64)  # either sign: each made outward like its vertex's faces
        over = np.zeros((len(v_all), 3))
        over[:len(v)] = vn
        over[len(v):] = vn[np.array(list(far.keys()), dtype=np.int64)]
    is_wall = np.arange(len(tri_all)) < n_wall
    # patches: triangles sorted by the cube holding their centroid
    cen = v_all[tri_all].mean(axis=1)
    cube = np.floor((cen - cen.min(axis=0)) / patch_m).astype(np.int64)
    order = np.lexsort((cube[:, 0], cube[:, 1], cube[:, 2]))
    tri_all = np.ascontiguousarray(tri_all[order])
    is_wall = is_wall[order]
    ck = cube[order]
    new = np.concatenate([[True], np.any(ck[1:] != ck[:-1], axis=1)])
    pstart = np.concatenate([np.nonzero(new)[0], [len(tri_all)]]).astype(np.int64)
    corder, clen = _chunks(np.ascontiguousarray(v_all[tri_all].mean(axis=1)), pstart, CHUNK)
    tri_all = np.ascontiguousarray(tri_all[corder])
    is_wall = is_wall[corder]
    data = _triangle_data(v_all, tri_all, math.cos(math.radians(crease_deg)), over, clen)
    return WallSurface(v_all, tri_all, is_wall, data, pstart, _patch_boxes(v_all, tri_all, pstart), caps_t)
