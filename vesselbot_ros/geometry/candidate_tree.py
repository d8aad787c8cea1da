"""The candidate tree of a 3-D wall: per octree leaf, the patches that can hold a point's nearest triangle.

:func:`candidate_tree` builds it (a root grid of cubes, each refined as an octree, lists filtered from the
parent's in parallel); :func:`pruned_arrays` cuts it down to the leaves a caller asks and :func:`split_leaves`
splits chosen leaves further.  The rule and why it holds: docs/vessels.md, "The wall geometry", `candidate_tree`.
"""

from __future__ import annotations

import dataclasses
import math

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.geometry.surface import STRIDE, Array, IArray, WallSurface
from vesselbot_ros.geometry.surface_query import _box_dist2, _chunk_far, _closest, _leaf, _signed, _triangle_far

__all__ = ["CandidateTree", "candidate_tree", "centre_distances", "leaves3d", "node_boxes", "pruned_arrays", "split_leaves"]

@dataclasses.dataclass(frozen=True)
class CandidateTree:
    """Per-cell candidate triangles: a root grid of cubes, each an octree (see docs/vessels.md).

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
def _filter_chunk(d, pstart, pbox, centres, w, poff, pidx, parent, slack, c0, c1, boff, buf, cnt, seed):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The lists of cells ``c0:c1`` into ``buf`` (cell i's at ``boff[i - c0]``, room for its parent's whole list),
    in parallel over the cells; their counts and seeds into ``cnt`` and ``seed``."""
    for i in numba.prange(c0, c1):
        p = parent[i]
        cnt[i], seed[i] = _select(centres[i, 0], centres[i, 1], centres[i, 2], w[i], poff[p], poff[p + 1], pidx, d,
                                  pstart, pbox, slack, buf, boff[i - c0])


#: The most list entries :func:`_filter` holds at once before compacting (int64: 32 MB).
_FILTER_BUFFER = 1 << 22


def _filter(d: Array, pstart: IArray, pbox: Array, centres: Array, w: Array, poff: IArray, pidx: IArray,
            parent: IArray, slack: float) -> tuple[IArray, IArray, IArray]:
    """CSR lists of the cells (centres (k, 3), half-diagonals w): the parent's patches within d(c) + 2 w.

    A patch's distance is its nearest triangle's; its oriented box's distance bounds it from below, so a patch
    whose box is beyond the limit (or, while d(c) is sought, beyond the nearest so far) is never measured.
    One pass over chunks of cells, each in parallel over its cells: a cell's list is written where its parent's
    whole list would fit (a chunk's room is at most :data:`_FILTER_BUFFER` entries, or one cell's), then the
    chunk is compacted.  Each list is sorted by the patches' distance to the cell centre.
    """
    n = centres.shape[0]
    cnt = np.zeros(n, dtype=np.int64)
    seed = np.zeros(n, dtype=np.int64)
    room = (poff[1:] - poff[:-1])[parent]
    ends = np.cumsum(room)
    parts: list[IArray] = []
    c0 = 0
    while c0 < n:
        base = ends[c0 - 1] if c0 else 0
        c1 = max(c0 + 1, int(np.searchsorted(ends, base + _FILTER_BUFFER, side="right")))
        boff = np.concatenate([[0], ends[c0:c1 - 1] - base]).astype(np.int64)
        buf = np.empty(int(ends[c1 - 1] - base), dtype=np.int64)
        _filter_chunk(d, pstart, pbox, centres, w, poff, pidx, parent, slack, c0, c1, boff, buf, cnt, seed)
        keep = np.arange(buf.size) - np.repeat(boff, room[c0:c1]) < np.repeat(cnt[c0:c1], room[c0:c1])
        parts.append(buf[keep])
        c0 = c1
    off = np.concatenate([[0], np.cumsum(cnt)]).astype(np.int64)
    out = np.concatenate(parts) if parts else np.empty(0, dtype=np.int64)
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
                   far_out_m: float = math.inf, box_m: tuple[npt.ArrayLike, npt.ArrayLike] | None = None) -> CandidateTree:
    """The candidate octree of ``surface`` over its bounding box plus ``margin_m`` (see docs/vessels.md).

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
        box_m: (lo, hi) (m): only the roots of that grid that meet this box (each root is refined on its own, from
            the same centres: they are the whole tree's roots there); a query outside them is answered from the
            nearest root's lists, so only for a caller whose queries stay in the box (the cross-kernel build
            test's block, :mod:`vesselbot_ros.analysis.builds_fingerprint`).  None: the whole grid.

    Returns:
        The :class:`CandidateTree`.
    """
    wall_v = surface.wall_vertices()
    lo = wall_v.min(axis=0) - margin_m
    hi = wall_v.max(axis=0) + margin_m
    n = np.maximum(1, np.ceil((hi - lo) / root_m).astype(np.int64))
    first = np.zeros(3, dtype=np.int64)
    if box_m is not None:
        first = np.clip(np.floor((np.asarray(box_m[0], dtype=np.float64) - lo) / root_m).astype(np.int64), 0, n - 1)
        last = np.clip(np.floor((np.asarray(box_m[1], dtype=np.float64) - lo) / root_m).astype(np.int64), first, n - 1)
        n = last - first + 1
    d = surface.data
    m = surface.patch_start.size - 1
    kk, jj, ii = np.meshgrid(np.arange(n[2]), np.arange(n[1]), np.arange(n[0]), indexing="ij")
    # the whole grid's centres (first = 0 without a box: the same floats as ever)
    centres = np.ascontiguousarray(lo + (np.column_stack([ii.ravel(), jj.ravel(), kk.ravel()]) + first + 0.5) * root_m)
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
    x0 = lo + first * root_m if box_m is not None else lo
    grid = np.array([x0[0], x0[1], x0[2], root_m, n[0], n[1], n[2]], dtype=np.float64)
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
