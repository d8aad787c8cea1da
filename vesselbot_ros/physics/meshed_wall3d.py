"""The meshed vessel wall in 3-D: exact signed distance, inward normal and local diameter.

The 3-D counterpart of :mod:`vesselbot_ros.physics.meshed_wall` (read its docstring first): the wall is a
triangulated surface (the lumen's boundary without its inlet/outlet caps) and the plant's queries are exact
over it, computed by an allocation-free compiled query over per-cell candidate triangles.

Wall surface (:func:`wall_surface`): the triangles are oriented consistently (outward: the normal points out
of the lumen; made consistent across shared edges, then the sign chosen so the volume closed by fans to the
cap centres is positive).  The caps are not wall.  Beyond each cap the lumen continues as a straight tube of
the cap's shape: every rim edge (a boundary edge of the wall lying in the cap's plane) is extruded along the
cap's unit outward normal by ``extension_m`` (two triangles per rim edge, oriented with the wall), so beyond
an open end the wall is the rim's prism -- the cylinder of the cap's radius for a round cap, as the vessel it
was cut from would continue.  ``extension_m`` should reach past the candidate grid's edge.

Per triangle the query stores (flat, ``STRIDE`` floats): its corners, its unit face normal, the
pseudonormals of its three edges (the sum of the two faces' normals, normalised) and of its three vertices
(angle-weighted: Baerentzen & Aanaes 2005, "Signed distance computation using the angle weighted
pseudonormal"), three crease-aware corner normals for the smooth normal, and a bounding disc.  Triangles are
grouped in patches (the candidate lists hold patches, each with an oriented bounding box) and, within a
patch, in chunks of at most ``CHUNK`` (halving along the centroids' longest extent), each bounded as a thick
disc (centre, normal, in-plane radius, half thickness), so the query skips a chunk of a fine mesh at once.

Candidate tree (:func:`candidate_tree`): a regular root grid of cubes over the surface's bounding box plus a
margin, each refined as an octree.  Every node stores the triangles whose distance to the node's centre c is at
most d(c) + 2 w (w: the node's half-diagonal; d: the distance to the surface): with T* the triangle nearest a
point q of the node, dist(T*, c) <= dist(T*, q) + w = d(q) + w <= d(c) + 2 w, so that set holds the nearest
triangle of every point of the node (the 2-D rule, unchanged).  A child's set is a subset of its parent's (its
d(c) + 2 w ball lies in the parent's: the child centre is w_child from the parent centre and w_parent =
2 w_child), so children are filtered from their parent's list only.  A node is split while its list is longer
than ``max_leaf`` and it is shallower than ``max_depth``; only leaves keep their list (CSR), sorted by the
triangles' distance to the leaf centre, so the query meets the nearest first and rejects most of the others by
their bounds.  (A uniform grid fine enough for short lists near the wall would not fit in memory:
deep in a round lumen the d(c) + 2 w band holds a ring of triangles whose area grows as w d, and on the axis
of a cylinder every triangle of a ring is equally far, so no rule can make those lists short; the octree
refines only where it pays.)  The exact signed distance of a node's centre (from its seed) bounds its points'
within +-w, which the optional rules use: a node within ``near_m`` of the wall is split as above, one deeper
or farther only while larger than ``deep_leaf_m`` (its list stays a ring's whatever its size; 8^k more
leaves would hold k-fold shorter copies of it), and one wholly outside the lumen by more than ``far_out_m``
is sealed: no list, the query answering from its seed and signing it outside.  The lists are filtered with
the patches' boxes as lower bounds (a patch whose box lies beyond the limit is never measured), in parallel.
:func:`pruned_arrays` keeps a tree's lists only in the leaves a caller needs (its other leaves emptied, their
subtrees collapsed, only the triangles those lists name kept, int32 indices): bit for bit the same answers
there; :func:`split_leaves` splits chosen leaves further.

Exact query (:func:`nearest_wall3d`, compiled, allocation-free): the leaf of the point, then the nearest
candidate triangle by Ericson's closest-point method (Real-Time Collision Detection, 5.1.5), which also says
which feature holds the foot: the face, an edge or a vertex.  Ties (equal squared distance) go to the lowest
triangle index, so the answer is the same over any candidate set holding the nearest triangle, bit for bit.
Sign: the side of the foot's feature pseudonormal N (face normal, edge or angle-weighted vertex pseudonormal):
inside iff (q - foot) . N < 0.  Baerentzen & Aanaes prove that rule exact at faces, edges and vertices of a
closed manifold mesh (shared features carry one pseudonormal, stored identically in every triangle, so it does
not matter which of the tied triangles wins).  The inward normal is ``(q - foot) / |q - foot|`` inside and its
opposite outside; on the wall itself the triangle's inward face normal.

Smooth normal (:func:`smooth_wall3d`): a flat facet's normal is off the smooth wall's by up to h / (2 R)
(1.9 deg at h = 0.1 mm on R = 1.5 mm), and ``(q - foot)`` inherits it.  The smooth query keeps the exact
distance and replaces the normal by that of the normal field interpolated linearly over the nearest triangle
from its corner normals (angle-weighted vertex normals, averaged only over the triangles within
``crease_deg`` of the corner's own, so a junction's crease stays sharp): it solves for the offset t at which q
lies in the triangle offset along its corner normals, q = P(u, v) + t N(u, v) (a cubic in t, 2-4 Newton steps
from the flat distance), and returns -N(u, v) / |N(u, v)| (barycentrics clamped to the triangle).  On a
cylinder with radial corner normals the line P + t N passes through the axis, so the normal is exactly radial
whatever the facet.  Measured (tools/validate_wall3d.py, h = 0.1 mm, within 1 mm of the wall): max 0.64 /
1.05 / 2.19 deg (cylinder / torus / Y; 99th percentile 0.41 / 0.42 / 0.55) against 1.78 / 3.27 / 4.72 deg for
the facets; the Y's 2.19 is a point 0.27 mm off a daughter's axis (ill-conditioned there), 1 in 10^5.  Exact
CAD vertex normals (``vertex_normals``) change these by < 0.2 deg: the rest comes from barycentrics clamped
where q's normal line leaves the flat-nearest triangle (not yet followed into the neighbour).

Speed (bench/bench_wall3d.py): 1.3-2.9 us per query against 0.05-0.11 us for the 2-D one (18-31 x) with 0.1 mm
triangles: most of it is testing the bounds of the ~50-100 triangles of the opened patches.  On the 3-D plant's
walls (0.5 um sag: 40-60 um triangles, ~40 per patch) at the points the shipped scenarios' beads ask it (a
junction's medial surface, about 1 mm deep): 1.4 us (III-C) to 2.5 us (synthetic tree), of which ~55 list
boxes, ~50 chunk discs, ~140 triangle discs and ~25 exact closest points.

Local diameter (:func:`local_diameter3d`): the 2-D definition carried to 3-D: the diameter of the largest ball
inscribed in the lumen that touches the wall at the point's nearest wall point F (along the inward normal n
there), found per grid node (no splat) by growing and shrinking the ball: the ball of radius r centred at
c = F + r n fits (within ``tol``) while s(c) >= r - tol; radii double from 2 s until one does not fit, then each
failure shrinks r to the largest radius the wall point W nearest c allows, the root of |F + r n - W| = r - tol:
r' = (|W - F|^2 - tol^2) / (2 (n . (W - F) - tol)) (the "shrinking ball" of Ma, Bai & Bhatt 2012, medial axis
points from nearest neighbours, with the fit tolerance); the first r' that fits is the largest (bisection of
the bracket where W says nothing).  One step on a straight tube (W is the opposite wall point: r' = R + tol / 2,
bisection's limit), a few in a junction, where bisection took about 20 exact queries.  2 R in a straight
branch of radius R; in a junction it follows the nearest wall: the parent's width beside the parent's wall, a
daughter's beside the daughter's, and near the crease (the apex) the ball that fits between the crease's two
walls along the crease's normal (the junction's inscribed ball at its middle).  Outside the lumen a node takes
the value of the nearest lumen node, as in 2-D.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.blas_free import dot3

__all__ = ["STRIDE", "CHUNK", "Cap", "WallSurface", "CandidateTree", "wall_surface", "candidate_tree", "centre_distances",
           "leaves3d", "node_boxes", "pruned_arrays", "split_leaves",
           "nearest_wall3d", "smooth_wall3d", "query_points3d", "brute_force3d", "ball_diameters3d", "local_diameter3d",
           "Wall3D",
           "gmsh_wall", "cylinder_wall", "bent_tube_wall", "y_wall", "y_solids"]

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


@dataclasses.dataclass(frozen=True)
class CandidateTree:
    """Per-cell candidate triangles: a root grid of cubes, each an octree (see the module docstring).

    Attributes:
        grid: (7,) root grid ``(x0, y0, z0, a, nx, ny, nz)``: origin (m), cube side (m), cubes per axis.
        nodes: (k, 4) int64 per node ``(first child or -1, list start, list end, seed)`` (seed: the triangle
            nearest the node's centre, where the query starts); roots first, ``(iz ny + iy)
            nx + ix``; the 8 children of a node are consecutive, octant ``ox + 2 oy + 4 oz``.
        index: (total,) int64 leaves' candidate patches (CSR through ``nodes``).
        depth: (k,) int8 depth of each node (0: root).
    """

    grid: Array
    nodes: IArray
    index: IArray
    depth: npt.NDArray[np.int8]

    def stats(self) -> dict[str, float]:
        """Table sizes: nodes, leaves, candidate entries, memory (MB), mean and max list length, max depth."""
        leaf = self.nodes[:, 0] < 0
        n = self.nodes[leaf, 2] - self.nodes[leaf, 1]
        mb = (self.nodes.nbytes + self.index.nbytes) / 1e6
        return {"roots": float(np.prod(self.grid[4:7])), "nodes": float(len(self.nodes)), "leaves": float(leaf.sum()),
                "entries": float(self.index.size), "MB": mb, "mean_list": float(n.mean()), "max_list": float(n.max()),
                "max_depth": float(self.depth.max())}


# ---------------------------------------------------------------------------------------------------------
# surface preparation


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


# ---------------------------------------------------------------------------------------------------------
# compiled query


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
    """Inward unit normal of the corner-normal field of triangle ``t`` seen from the point (module docstring)."""
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

    The normal of the corner-normal field of the nearest triangle (module docstring): within a fraction of
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


# ---------------------------------------------------------------------------------------------------------
# candidate tree


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
def _patch_dist2(px, py, pz, d, pstart, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(squared distance m^2, triangle): the nearest triangle of patch ``p`` to a point (disc bounds prune)."""
    best = np.inf
    tb = pstart[p]
    t0 = pstart[p]
    while t0 < pstart[p + 1]:
        L = int(d[48 * t0 + 7])
        if L >= 2 and _chunk_far(px, py, pz, d, 48 * t0, best):
            t0 += L
            continue
        for t in range(t0, t0 + L):
            b = 48 * t
            if _triangle_far(px, py, pz, d, b, best):
                continue
            d2, _x, _y, _z, _f = _closest(px, py, pz, d, b + 8)
            if d2 < best:
                best = d2
                tb = t
        t0 += L
    return best, tb


@numba.njit(cache=True)
def _select(cx, cy, cz, w, lo, hi, pidx, d, pstart, pbox, slack, out, o):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The patches of ``pidx[lo:hi]`` within d(c) + 2 w of the centre c, nearest first, written to ``out[o:]``
    if ``out`` is long enough; returns (count, seed triangle).  Box lower bounds spare most exact distances."""
    m = hi - lo
    lb = np.empty(m)
    ex = np.full(m, np.inf)
    e0 = 0
    for e in range(m):
        lb[e] = math.sqrt(_box_dist2(cx, cy, cz, pbox, pidx[lo + e]))
        if lb[e] < lb[e0]:
            e0 = e
    d2, seed = _patch_dist2(cx, cy, cz, d, pstart, pidx[lo + e0])
    ex[e0] = math.sqrt(d2)
    dmin = ex[e0]
    for e in range(m):
        if e != e0 and lb[e] < dmin:
            d2, t = _patch_dist2(cx, cy, cz, d, pstart, pidx[lo + e])
            ex[e] = math.sqrt(d2)
            if ex[e] < dmin:
                dmin = ex[e]
                seed = t
    lim = dmin + 2.0 * w + slack
    cnt = 0
    for e in range(m):
        if lb[e] <= lim:
            if ex[e] == np.inf and e != e0:
                d2, _t = _patch_dist2(cx, cy, cz, d, pstart, pidx[lo + e])
                ex[e] = math.sqrt(d2)
            if ex[e] <= lim:
                cnt += 1
    if out.size >= o + cnt and cnt > 0:
        sel = np.empty(cnt, dtype=np.int64)
        k = 0
        for e in range(m):
            if lb[e] <= lim and ex[e] <= lim:
                sel[k] = e
                k += 1
        order = np.argsort(ex[sel], kind="mergesort")
        for k in range(cnt):
            out[o + k] = pidx[lo + sel[order[k]]]
    return cnt, seed


@numba.njit(cache=True, parallel=True)
def _filter(d, pstart, pbox, centres, w, poff, pidx, parent, slack):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """CSR lists of the cells (centres (k, 3), half-diagonals w): the parent's patches within d(c) + 2 w.

    A patch's distance is its nearest triangle's; its oriented box's distance bounds it from below, so a patch
    whose box is beyond the limit (or, while d(c) is sought, beyond the nearest so far) is never measured.
    Two passes (count, then fill: the distances are computed twice, memory stays the lists' own), each in
    parallel over the cells.  Each list is sorted by the patches' distance to the cell centre.
    """
    n = centres.shape[0]
    cnt = np.zeros(n, dtype=np.int64)
    seed = np.zeros(n, dtype=np.int64)
    none = np.empty(0, dtype=np.int64)
    for i in numba.prange(n):
        p = parent[i]
        cnt[i], seed[i] = _select(centres[i, 0], centres[i, 1], centres[i, 2], w[i], poff[p], poff[p + 1], pidx, d,
                                  pstart, pbox, slack, none, 0)
    off = np.zeros(n + 1, dtype=np.int64)
    for i in range(n):
        off[i + 1] = off[i] + cnt[i]
    out = np.empty(off[n], dtype=np.int64)
    for i in numba.prange(n):
        p = parent[i]
        _select(centres[i, 0], centres[i, 1], centres[i, 2], w[i], poff[p], poff[p + 1], pidx, d, pstart, pbox, slack,
                out, off[i])
    return off, out, seed


@numba.njit(cache=True, parallel=True)
def centre_distances(d, centres, seed):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(k,) signed distances (m, > 0 in the lumen) of points (k, 3) (m) from their seeds (k,) (a point's nearest
    triangle: exact, else the distance to that triangle, signed by its feature's pseudonormal)."""
    out = np.empty(centres.shape[0])
    for i in numba.prange(centres.shape[0]):
        t = seed[i]
        best, fx, fy, fz, feat = _closest(centres[i, 0], centres[i, 1], centres[i, 2], d, 48 * t + 8)
        out[i] = _signed(centres[i, 0], centres[i, 1], centres[i, 2], d, best, fx, fy, fz, feat, t)[0]
    return out


def candidate_tree(surface: WallSurface, margin_m: float, root_m: float = 0.8e-3, max_leaf: int = 8,
                   max_depth: int = 2, min_depth: int = 1, near_m: float = math.inf, deep_leaf_m: float = 0.0,
                   far_out_m: float = math.inf) -> CandidateTree:
    """The candidate octree of ``surface`` over its bounding box plus ``margin_m`` (see the module docstring).

    Each node's centre distance s_c (signed, from its seed) bounds its points' s within +-w (w: half-diagonal):
    a node within ``near_m`` of the wall (|s_c| - w <= near_m) is split while its list is longer than
    ``max_leaf`` (and at least ``min_depth`` times) down to ``max_depth``; a node farther in or out only while
    its cube is larger than ``deep_leaf_m`` (its list is long whatever the size: a ring of the lumen); a node
    wholly outside the lumen by more than ``far_out_m`` (s_c + w < -far_out_m) is a sealed leaf: no list, and
    the query answers from its seed, signed outside (see :func:`nearest_wall3d`).

    Args:
        surface: The wall.  Its extensions beyond the caps count for the bounding box only within the margin.
        margin_m: Margin (m) around the wall's (not the extensions') bounding box.
        root_m: Root cube side (m).
        max_leaf: A node with a longer candidate list is split (until ``max_depth``).
        max_depth: Deepest level (the finest cube is ``root_m / 2**max_depth``).
        min_depth: Every root within ``near_m`` is split at least this many times.
        near_m, deep_leaf_m, far_out_m: The rules above (m); the defaults split everywhere and seal nothing.

    Returns:
        The :class:`CandidateTree`.
    """
    wall_v = surface.wall_vertices()
    lo = wall_v.min(axis=0) - margin_m
    hi = wall_v.max(axis=0) + margin_m
    n = np.maximum(1, np.ceil((hi - lo) / root_m).astype(np.int64))
    d = surface.data
    m = surface.patch_start.size - 1
    kk, jj, ii = np.meshgrid(np.arange(n[2]), np.arange(n[1]), np.arange(n[0]), indexing="ij")
    centres = np.ascontiguousarray(lo + (np.column_stack([ii.ravel(), jj.ravel(), kk.ravel()]) + 0.5) * root_m)
    half = 0.5 * root_m
    slack = 1e-9 * max(1.0, float(np.abs(hi).max() + np.abs(lo).max()))
    off, idx, seed = _filter(d, surface.patch_start, surface.patch_box, centres, np.full(len(centres), half * math.sqrt(3.0)),
                             np.array([0, m], dtype=np.int64), np.arange(m, dtype=np.int64), np.zeros(len(centres), dtype=np.int64),
                             slack)
    octs = np.array([[(o & 1) * 2 - 1, ((o >> 1) & 1) * 2 - 1, ((o >> 2) & 1) * 2 - 1] for o in range(8)], dtype=np.float64)
    # per level: child pointers (relative to the next level), leaf lists (CSR over the level's nodes), seeds
    level_child: list[IArray] = []
    level_off: list[IArray] = []
    level_idx: list[IArray] = []
    level_seed: list[IArray] = []
    level_sealed: list[npt.NDArray[np.bool_]] = []
    for depth in range(0, max_depth + 1):
        w = half * math.sqrt(3.0)
        sc = centre_distances(d, centres, seed)
        cnt = np.diff(off)
        sealed = sc + w < -far_out_m
        near = np.abs(sc) - w <= near_m
        split = ~sealed & (depth < max_depth) & np.where(near, (cnt > max_leaf) | (depth < min_depth),
                                                         (cnt > max_leaf) & (2.0 * half > deep_leaf_m))
        child = np.full(len(cnt), -1, dtype=np.int64)
        sp = np.nonzero(split)[0]
        child[sp] = 8 * np.arange(sp.size)
        leaf = ~split & ~sealed
        keep = np.repeat(leaf, cnt)
        lcnt = np.where(leaf, cnt, 0)
        level_child.append(child)
        level_off.append(np.concatenate([[0], np.cumsum(lcnt)]).astype(np.int64))
        level_idx.append(idx[keep])
        level_seed.append(seed)
        level_sealed.append(sealed)
        if sp.size == 0:
            break
        half *= 0.5
        cc = np.ascontiguousarray((centres[sp][:, None, :] + half * octs[None, :, :]).reshape(-1, 3))
        off, idx, seed = _filter(d, surface.patch_start, surface.patch_box, cc, np.full(len(cc), half * math.sqrt(3.0)),
                                 off, idx, np.repeat(sp, 8), slack)
        centres = cc
    starts = np.cumsum([0] + [len(c) for c in level_child])
    nodes_l = []
    index_l = []
    depth_l = []
    pos = 0
    for lev, (child, loff, lidx, sd, sealed) in enumerate(zip(level_child, level_off, level_idx, level_seed, level_sealed)):
        nd = np.empty((len(child), 4), dtype=np.int64)
        nd[:, 3] = sd
        nd[:, 0] = np.where(child < 0, -1, child + starts[min(lev + 1, len(starts) - 1)])
        nd[:, 1] = pos + loff[:-1]
        nd[:, 2] = pos + loff[1:]
        nd[sealed, 1:3] = -1
        pos += int(loff[-1])
        index_l.append(lidx)
        nodes_l.append(nd)
        depth_l.append(np.full(len(child), lev, dtype=np.int8))
    grid = np.array([lo[0], lo[1], lo[2], root_m, n[0], n[1], n[2]], dtype=np.float64)
    return CandidateTree(grid, np.ascontiguousarray(np.concatenate(nodes_l)),
                         np.ascontiguousarray(np.concatenate(index_l)), np.concatenate(depth_l))


@numba.njit(cache=True)
def leaves3d(pts, grid, nodes):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(m,) the leaf of the candidate tree holding each point (m, 3) (m) (outside its grid: the nearest edge leaf)."""
    out = np.empty(pts.shape[0], dtype=np.int64)
    for k in range(pts.shape[0]):
        out[k] = _leaf(pts[k, 0], pts[k, 1], pts[k, 2], grid, nodes)
    return out


def node_boxes(tree: CandidateTree) -> tuple[Array, Array]:
    """(centres (k, 3) m, half sides (k,) m) of the tree's nodes."""
    g = tree.grid
    nx, ny, nz = int(g[4]), int(g[5]), int(g[6])
    k = len(tree.nodes)
    centre = np.zeros((k, 3))
    half = np.zeros(k)
    r = np.arange(nx * ny * nz)
    centre[r] = g[0:3] + (np.column_stack([r % nx, (r // nx) % ny, r // (nx * ny)]) + 0.5) * g[3]
    half[r] = 0.5 * g[3]
    octs = np.array([[(o & 1) * 2 - 1, ((o >> 1) & 1) * 2 - 1, ((o >> 2) & 1) * 2 - 1] for o in range(8)], dtype=np.float64)
    for lev in range(int(tree.depth.max())):
        par = np.nonzero((tree.depth == lev) & (tree.nodes[:, 0] >= 0))[0]
        ch = tree.nodes[par, 0][:, None] + np.arange(8)[None, :]
        half[ch] = 0.5 * half[par][:, None]
        centre[ch] = centre[par][:, None, :] + half[ch][:, :, None] * octs[None, :, :]
    return centre, half


def _ranges(starts: IArray, lengths: IArray) -> IArray:
    """The concatenated ranges ``starts[i] : starts[i] + lengths[i]``."""
    lengths = np.asarray(lengths, dtype=np.int64)
    prev = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    return np.repeat(np.asarray(starts, dtype=np.int64) - prev, lengths) + np.arange(int(lengths.sum()), dtype=np.int64)


def pruned_arrays(surface: WallSurface, tree: CandidateTree, needed: npt.NDArray[np.bool_],
                  seal: npt.NDArray[np.bool_] | None = None
                  ) -> tuple[Array, Array, IArray, Array, npt.NDArray[np.int32], npt.NDArray[np.int32]]:
    """The exact query's arrays ``(d, pbox, pstart, grid, nodes, index)`` answering only in the ``needed`` leaves.

    A needed leaf keeps its list and seed (a sealed one stays sealed); every other leaf is emptied and a
    subtree with no needed leaf collapses into one empty leaf, so the query is bit-identical to the full tree's
    at every point of a needed leaf and meaningless elsewhere.  Only the patches the kept lists and seeds name
    are kept, renumbered in order (so ties still go to the same triangle); ``nodes`` and ``index`` are int32.

    Args:
        surface, tree: The wall and its candidate tree.
        needed: (k,) per node of ``tree``: the leaves the query must answer in (internal nodes ignored).
        seal: (k,) needed leaves to seal instead (their list dropped, their seed's answer signed outside: only
            for leaves wholly outside the lumen).
    """
    nodes = tree.nodes.copy()
    if seal is not None:
        nodes[np.asarray(seal, dtype=bool) & (nodes[:, 0] < 0), 1:3] = -1
    leaf = nodes[:, 0] < 0
    need = np.asarray(needed, dtype=bool) & leaf
    # a node is kept whole when a needed leaf lies beneath it: mark upwards, level by level
    keep = need.copy()
    for lev in range(int(tree.depth.max()) - 1, -1, -1):
        par = np.nonzero((tree.depth == lev) & ~leaf)[0]
        keep[par] = keep[nodes[par, 0][:, None] + np.arange(8)[None, :]].any(axis=1)
    roots = int(np.prod(tree.grid[4:7]))
    # new numbering, level order: roots, then the children blocks of the kept internal nodes in order
    order = [np.arange(roots)]
    front = order[0]
    while True:
        inner = front[~leaf[front] & keep[front]]
        if inner.size == 0:
            break
        front = (nodes[inner, 0][:, None] + np.arange(8)[None, :]).ravel()
        order.append(front)
    old = np.concatenate(order)
    new_of = np.full(len(nodes), -1, dtype=np.int64)
    new_of[old] = np.arange(len(old))
    listed = need & (nodes[:, 1] >= 0)
    # patches named by the kept lists and seeds
    ent = _ranges(nodes[listed, 1], nodes[listed, 2] - nodes[listed, 1])
    tri_patch = np.repeat(np.arange(surface.patch_start.size - 1), np.diff(surface.patch_start))
    used = np.zeros(surface.patch_start.size - 1, dtype=bool)
    used[tree.index[ent]] = True
    used[tri_patch[nodes[need, 3]]] = True
    pk = np.nonzero(used)[0]
    pnew = np.full(used.size, -1, dtype=np.int64)
    pnew[pk] = np.arange(pk.size)
    cnt = np.diff(surface.patch_start)[pk]
    pstart = np.concatenate([[0], np.cumsum(cnt)]).astype(np.int64)
    tk = _ranges(surface.patch_start[pk], cnt)
    tnew = np.full(len(tri_patch), -1, dtype=np.int64)
    tnew[tk] = np.arange(tk.size)
    d = np.ascontiguousarray(surface.data.reshape(-1, STRIDE)[tk].ravel())
    pbox = np.ascontiguousarray(surface.patch_box.reshape(-1, 15)[pk].ravel())
    # nodes and lists in the new order
    on = nodes[old]
    out = np.zeros((len(old), 4), dtype=np.int64)
    internal = (on[:, 0] >= 0) & keep[old]
    out[:, 0] = -1
    out[internal, 0] = new_of[on[internal, 0]]
    ol = listed[old]
    ln = np.where(ol, on[:, 2] - on[:, 1], 0)
    st = np.concatenate([[0], np.cumsum(ln)[:-1]])
    out[:, 1] = np.where(ol, st, 0)
    out[:, 2] = np.where(ol, st + ln, 0)
    sealed = need[old] & (on[:, 1] < 0)
    out[sealed, 1:3] = -1
    out[:, 3] = np.where(need[old], tnew[on[:, 3]], 0)
    src = _ranges(on[ol, 1], ln[ol])
    index = pnew[tree.index[src]]
    if (index < 0).any() or (out[need[old], 3] < 0).any():
        raise AssertionError("pruned_arrays: a kept list names a dropped patch")
    return (d, pbox, pstart, tree.grid.copy(), np.ascontiguousarray(out.astype(np.int32)),
            np.ascontiguousarray(index.astype(np.int32)))


def split_leaves(surface: WallSurface, tree: CandidateTree, which: npt.NDArray[np.bool_], max_leaf: int,
                 max_depth: int) -> CandidateTree:
    """``tree`` with the leaves ``which`` (a mask over its nodes; sealed ones excepted) split further by the rule of
    :func:`candidate_tree` (while the list is longer than ``max_leaf``, down to ``max_depth``).  The new nodes
    are appended (children blocks stay consecutive); a split leaf's old list is left unreferenced."""
    nodes = tree.nodes.copy()
    depth = tree.depth.copy()
    index = tree.index
    centre, half = node_boxes(tree)
    g = tree.grid
    slack = 1e-9 * max(1.0, float(np.abs(g[0:3] + g[3] * g[4:7]).max() + np.abs(g[0:3]).max()))
    octs = np.array([[(o & 1) * 2 - 1, ((o >> 1) & 1) * 2 - 1, ((o >> 2) & 1) * 2 - 1] for o in range(8)], dtype=np.float64)
    cur = np.nonzero(np.asarray(which, dtype=bool) & (nodes[:, 0] < 0) & (nodes[:, 1] >= 0)
                     & (nodes[:, 2] - nodes[:, 1] > max_leaf) & (depth < max_depth))[0]
    cur_c, cur_h = centre[cur], half[cur]
    while cur.size:
        lens = nodes[cur, 2] - nodes[cur, 1]
        pidx = np.ascontiguousarray(index[_ranges(nodes[cur, 1], lens)])
        poff = np.concatenate([[0], np.cumsum(lens)]).astype(np.int64)
        h2 = 0.5 * cur_h
        cc = np.ascontiguousarray((cur_c[:, None, :] + h2[:, None, None] * octs[None, :, :]).reshape(-1, 3))
        hc = np.repeat(h2, 8)
        off, idx, seed = _filter(surface.data, surface.patch_start, surface.patch_box, cc, hc * math.sqrt(3.0), poff,
                                 pidx, np.repeat(np.arange(cur.size, dtype=np.int64), 8), slack)
        new_ids = len(nodes) + np.arange(cc.shape[0])
        nodes[cur, 0] = new_ids[::8]
        nodes[cur, 1:3] = 0
        block = np.column_stack([np.full(cc.shape[0], -1, dtype=np.int64), index.size + off[:-1], index.size + off[1:], seed])
        bdepth = np.repeat(depth[cur] + 1, 8).astype(np.int8)
        nxt = np.nonzero((np.diff(off) > max_leaf) & (bdepth < max_depth))[0]
        nodes = np.concatenate([nodes, block])
        depth = np.concatenate([depth, bdepth])
        index = np.concatenate([index, idx])
        cur, cur_c, cur_h = new_ids[nxt], cc[nxt], hc[nxt]
    return CandidateTree(g.copy(), np.ascontiguousarray(nodes), np.ascontiguousarray(index), depth)


# ---------------------------------------------------------------------------------------------------------
# local diameter


@numba.njit(cache=True)
def _ball_diameters(pts, q, d, pbox, pstart, grid, nodes, index, rmax, tol, r0, grow):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    out = np.zeros(pts.shape[0])
    for k in range(pts.shape[0]):
        s = q[k, 0]
        if s <= 0.0:
            continue
        nx = q[k, 1]
        ny = q[k, 2]
        nz = q[k, 3]
        fx = pts[k, 0] - s * nx  # the nearest wall point (along the normal the query gives)
        fy = pts[k, 1] - s * ny
        fz = pts[k, 2] - s * nz
        lo = s  # the ball of radius s round the point fits
        hi = np.inf  # the least radius known not to fit
        rn = np.inf  # the largest radius W (the wall point nearest the last centre that did not fit) allows
        r = max(r0[k] if r0.size else 2.0 * s, s + tol)
        for _it in range(200):
            cx = fx + r * nx
            cy = fy + r * ny
            cz = fz + r * nz
            sc, ex, ey, ez = nearest_wall3d(cx, cy, cz, d, pbox, pstart, grid, nodes, index)
            if sc >= r - tol:  # fits
                lo = r
                if r >= rn or r >= rmax:
                    break  # W's limit itself fits: the largest
            else:
                hi = r
                # W within r - tol of the centre: a ball through F fits W only up to the root of
                # |F + r n - W| = r - tol
                wx = cx - sc * ex - fx
                wy = cy - sc * ey - fy
                wz = cz - sc * ez - fz
                a = wx * nx + wy * ny + wz * nz
                rn = (wx * wx + wy * wy + wz * wz - tol * tol) / (2.0 * (a - tol)) if a > tol else np.inf
            if hi - lo <= 0.05 * tol:
                break
            if hi == np.inf:
                r = grow * r  # grow until a ball does not fit
            elif lo < rn < hi:
                r = rn
            else:
                r = 0.5 * (lo + hi)  # W says nothing (F off the wall by rounding): bisect
        out[k] = 2.0 * lo
    return out


#: The per-point inscribed-ball diameters (compiled; :func:`local_diameter3d` without the grid and the fill):
#: ``ball_diameters3d(pts (m, 3) m, q (m, 4) their smooth query rows, d, pbox, pstart, grid, nodes, index,
#: rmax m, tol m, r0 (m,) first radii to try (m; empty: 2 s), grow)`` -> (m,) diameters (m), 0 where ``q``'s
#: distance is <= 0 (outside the lumen); radii grow by ``grow`` until one does not fit.
ball_diameters3d = _ball_diameters


def local_diameter3d(surface: WallSurface, tree: CandidateTree, origin_m: npt.ArrayLike, h: float,
                     shape: tuple[int, int, int], tol_m: float = 2e-6) -> Array:
    """(nz, ny, nx) local diameter (m) on the grid of nodes ``origin + h (i, j, k)`` (module docstring).

    A lumen node's diameter is that of the largest ball inscribed in the lumen touching the wall at the
    node's nearest wall point F, centred on the (smooth) inward normal there: the largest r with
    s(F + r n) >= r - ``tol_m``, by doubling then shrinking through the nearest wall point (module docstring);
    so a straight branch of radius R reads 2 R to the facets' sag.  Nodes outside the lumen take the value of the nearest lumen node.

    Args:
        surface: The wall.  tree: Its candidate tree (covering the grid).
        origin_m: (3,) grid origin (m).  h: Node spacing (m).  shape: ``(nz, ny, nx)`` nodes.
        tol_m: Fit tolerance (m) of a ball (the facets are off the smooth wall by ~1 um).

    Raises:
        ValueError: No node lies in the lumen.
    """
    from scipy.ndimage import distance_transform_edt  # deferred: scipy.ndimage is heavy, needed only to sample

    nz, ny, nx = shape
    o = np.asarray(origin_m, dtype=np.float64)
    Z, Y, X = np.meshgrid(o[2] + h * np.arange(nz), o[1] + h * np.arange(ny), o[0] + h * np.arange(nx), indexing="ij")
    pts = np.ascontiguousarray(np.column_stack([X.ravel(), Y.ravel(), Z.ravel()]))
    args = (surface.data, surface.patch_box, surface.patch_start, tree.grid, tree.nodes, tree.index)
    q = query_points3d(pts, *args, True)
    span = float(np.ptp(surface.wall_vertices(), axis=0).max())
    diam = _ball_diameters(pts, q, *args, 2.0 * span, tol_m, np.zeros(0), 2.0)
    out = diam.reshape(nz, ny, nx)
    empty = out <= 0.0
    if empty.all():
        raise ValueError("local_diameter3d: no grid node lies in the lumen")
    if empty.any():
        _dist, ind = distance_transform_edt(empty, return_indices=True)
        out = out[tuple(ind)]
    return out


# ---------------------------------------------------------------------------------------------------------
# numpy API


class Wall3D:
    """A 3-D meshed wall with its candidate tree (numpy API over the compiled queries).

    Args:
        vertices, triangles, caps, crease_deg, vertex_normals: As :func:`wall_surface`.
        margin_m: Margin (m) of the candidate tree around the wall; the extensions reach 2 (R + margin) past
            each cap (R: the largest cap radius).
        root_m, max_leaf, max_depth, near_m, deep_leaf_m, far_out_m: As :func:`candidate_tree`.
        patch_m: As :func:`wall_surface`.
    """

    def __init__(self, vertices: npt.ArrayLike, triangles: npt.ArrayLike, caps: Sequence[Cap], margin_m: float = 1.2e-3,
                 crease_deg: float = 30.0, vertex_normals: npt.ArrayLike | None = None, root_m: float = 0.8e-3,
                 max_leaf: int = 8, max_depth: int = 2, patch_m: float = 0.25e-3, near_m: float = math.inf,
                 deep_leaf_m: float = 0.0, far_out_m: float = math.inf) -> None:
        rmax = max(float(c[2]) for c in caps)
        #: The oriented wall and its extensions.
        self.surface = wall_surface(vertices, triangles, caps, 2.0 * (rmax + margin_m) + root_m, crease_deg,
                                    vertex_normals, patch_m)
        #: Its candidate tree.
        self.tree = candidate_tree(self.surface, margin_m, root_m, max_leaf, max_depth, near_m=near_m,
                                   deep_leaf_m=deep_leaf_m, far_out_m=far_out_m)
        self._args = (self.surface.data, self.surface.patch_box, self.surface.patch_start, self.tree.grid,
                      self.tree.nodes, self.tree.index)

    def query(self, points_m: npt.ArrayLike, smooth: bool = True) -> dict[str, Array]:
        """``sdist`` (m,) m (> 0 inside) and ``normal`` (m, 3) unit inward normal at points (m, 3) (m).

        ``smooth``: the smooth normal (:func:`smooth_wall3d`); else the exact ``(q - foot)`` one.
        """
        q = np.ascontiguousarray(np.atleast_2d(np.asarray(points_m, dtype=np.float64)))
        r = query_points3d(q, *self._args, bool(smooth))
        return {"sdist": r[:, 0], "normal": r[:, 1:4]}

    def brute_force(self, points_m: npt.ArrayLike, smooth: bool = True) -> dict[str, Array]:
        """:meth:`query` over every triangle (the candidate tree's reference)."""
        q = np.ascontiguousarray(np.atleast_2d(np.asarray(points_m, dtype=np.float64)))
        r = brute_force3d(q, self.surface.data, bool(smooth))
        return {"sdist": r[:, 0], "normal": r[:, 1:4]}

    def local_diameter(self, origin_m: npt.ArrayLike, h: float, shape: tuple[int, int, int]) -> Array:
        """(nz, ny, nx) local diameter (m) on a grid (:func:`local_diameter3d`)."""
        return local_diameter3d(self.surface, self.tree, origin_m, h, shape)


# ---------------------------------------------------------------------------------------------------------
# reference surfaces (gmsh, OpenCASCADE), for validation


def gmsh_wall(build: Callable[[Any], None], h_m: float, unit_m: float = 1e-3) -> tuple[Array, IArray, Array]:
    """The wall of a solid built with gmsh's OpenCASCADE kernel: a surface mesh, planar faces (caps) left out.

    Args:
        build: Called with ``gmsh.model.occ``; builds the solid (in ``unit_m``, e.g. millimetres).
        h_m: Triangle size (m).
        unit_m: The length unit ``build`` works in (m).

    Returns:
        ``(vertices (n, 3) m, triangles (t, 3), normals (n, 3))`` of every non-planar face; normals: the CAD
        surface's unit normal at each vertex (sign as the CAD has it; at a vertex shared by faces, one face's).
    """
    import gmsh  # deferred: heavy, and its wheel needs libGLU & co (tools/bootstrap.sh checks); only meshing needs it

    gmsh.initialize(interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add("wall3d")
        build(gmsh.model.occ)
        gmsh.model.occ.synchronize()
        h = h_m / unit_m
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.MeshSizeMin", h)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
        gmsh.option.setNumber("Mesh.Algorithm", 6)
        gmsh.model.mesh.generate(2)
        node_tags, coords, _ = gmsh.model.mesh.getNodes()
        tris = []
        normals: dict[int, Array] = {}
        for _dim, tag in gmsh.model.getEntities(2):
            if gmsh.model.getType(2, tag) == "Plane":
                continue
            ntags, _xyz, par = gmsh.model.mesh.getNodes(2, tag, includeBoundary=True, returnParametricCoord=True)
            nrm = np.asarray(gmsh.model.getNormal(tag, par), dtype=np.float64).reshape(-1, 3)
            normals.update(zip(np.asarray(ntags, dtype=np.int64).tolist(), nrm))
            types, _et, enodes = gmsh.model.mesh.getElements(2, tag)
            for ty, en in zip(types, enodes):
                if ty == 2:
                    tris.append(np.asarray(en, dtype=np.int64).reshape(-1, 3))
    finally:
        gmsh.finalize()
    tags = np.asarray(node_tags, dtype=np.int64)
    xyz = np.asarray(coords, dtype=np.float64).reshape(-1, 3) * unit_m
    lookup = np.full(tags.max() + 1, -1, dtype=np.int64)
    lookup[tags] = np.arange(len(tags))
    tri = lookup[np.concatenate(tris)]
    used = np.unique(tri)
    remap = np.full(len(tags), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    nv = np.array([normals[int(g)] for g in tags[used]])
    return np.ascontiguousarray(xyz[used]), np.ascontiguousarray(remap[tri]), nv


def cylinder_wall(radius_m: float = 1.5e-3, length_m: float = 8e-3, h_m: float = 0.1e-3
                  ) -> tuple[Array, IArray, list[Cap], Array]:
    """A straight cylinder along +x from the origin: (vertices, triangles, caps, CAD vertex normals)."""
    r, L = radius_m * 1e3, length_m * 1e3

    def build(occ: Any) -> None:
        occ.addCylinder(0, 0, 0, L, 0, 0, r)

    v, t, nv = gmsh_wall(build, h_m)
    caps: list[Cap] = [(np.zeros(3), np.array([-1.0, 0, 0]), radius_m),
                       (np.array([length_m, 0, 0]), np.array([1.0, 0, 0]), radius_m)]
    return v, t, caps, nv


def bent_tube_wall(radius_m: float = 1.5e-3, bend_m: float = 6e-3, angle_rad: float = 0.5 * math.pi,
                   h_m: float = 0.1e-3) -> tuple[Array, IArray, list[Cap], Array]:
    """A torus section: tube radius ``radius_m`` round a centreline circle of radius ``bend_m`` about +z
    through the origin, from azimuth 0 to ``angle_rad``: (vertices, triangles, caps, CAD vertex normals)."""
    r, rb = radius_m * 1e3, bend_m * 1e3

    def build(occ: Any) -> None:
        occ.addTorus(0, 0, 0, rb, r, -1, angle_rad)

    v, t, nv = gmsh_wall(build, h_m)
    caps: list[Cap] = [(np.array([bend_m, 0, 0]), np.array([0, -1.0, 0]), radius_m),
                       (bend_m * np.array([math.cos(angle_rad), math.sin(angle_rad), 0]),
                        np.array([-math.sin(angle_rad), math.cos(angle_rad), 0]), radius_m)]
    return v, t, caps, nv


#: The Y's branches: (start (3,) m, unit direction, length m, radius m): a parent along +x ending at the
#: origin and two daughters leaving it at +-35 deg in the xy plane.
Y_BRANCHES = (
    (np.array([-6e-3, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]), 6e-3, 1.5e-3),
    (np.zeros(3), np.array([math.cos(math.radians(35)), math.sin(math.radians(35)), 0.0]), 6e-3, 1.2e-3),
    (np.zeros(3), np.array([math.cos(math.radians(35)), -math.sin(math.radians(35)), 0.0]), 6e-3, 1.2e-3),
)


def y_wall(h_m: float = 0.1e-3) -> tuple[Array, IArray, list[Cap], Array]:
    """A Y: :data:`Y_BRANCHES`' cylinders and a ball of the parent's radius at the node, fused:
    (vertices, triangles, caps, CAD vertex normals)."""

    def build(occ: Any) -> None:
        vols = []
        for s, u, L, r in Y_BRANCHES:
            vols.append((3, occ.addCylinder(*(s * 1e3), *(u * L * 1e3), r * 1e3)))
        vols.append((3, occ.addSphere(0, 0, 0, Y_BRANCHES[0][3] * 1e3)))
        occ.fuse(vols[:1], vols[1:])

    v, t, nv = gmsh_wall(build, h_m)
    caps: list[Cap] = [(Y_BRANCHES[0][0], -Y_BRANCHES[0][1], Y_BRANCHES[0][3])]
    caps += [(s + L * u, u, r) for s, u, L, r in Y_BRANCHES[1:]]
    return v, t, caps, nv


def y_solids(q: Array, cap_margin_m: float = 5e-5) -> tuple[npt.NDArray[np.bool_], Array, npt.NDArray[np.bool_]]:
    """The analytic Y of :func:`y_wall` at points ``q`` (n, 3) (m): ``(inside, near, beyond)``: inside the union of
    :data:`Y_BRANCHES`' cylinders and the node's ball, the least |signed distance| to any of those solids (m), and
    beyond a cap by more than ``-cap_margin_m`` along its branch (where the meshed lumen continues as a tube and the
    union ends)."""
    inside = np.linalg.norm(q, axis=1) < Y_BRANCHES[0][3]
    near = np.abs(np.linalg.norm(q, axis=1) - Y_BRANCHES[0][3])
    beyond = np.zeros(len(q), dtype=bool)
    for s, u, length, r in Y_BRANCHES:
        rel = q - s
        t = (rel[:, 0] * u[0] + rel[:, 1] * u[1]) + rel[:, 2] * u[2]
        rho = np.linalg.norm(q - s - t[:, None] * u, axis=1)
        dx, dy = rho - r, np.abs(t - 0.5 * length) - 0.5 * length
        sdf = np.minimum(np.maximum(dx, dy), 0.0) + np.hypot(np.maximum(dx, 0.0), np.maximum(dy, 0.0))
        inside |= sdf < 0
        near = np.minimum(near, np.abs(sdf))
        beyond |= (t > length - cap_margin_m) if s[0] >= 0 else (t < cap_margin_m)
    return inside, near, beyond
