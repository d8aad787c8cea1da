#!/usr/bin/env python3
"""The 3-D meshed wall's query against the 2-D one, measured side by side in one run.

Comparable geometries: the straight vessel (2-D ``straight_table3``'s meshed wall against the 3-D cylinder,
R = 1.5 mm) and a bifurcation (2-D ``paper_iiic_artery`` against the 3-D Y).  Query points: uniform in each
geometry's lumen, and within 0.3 mm of the wall (where contact is decided), the same count in 2-D and 3-D.
Prints ns per call (compiled loop, best of 5), the ratio 3-D / 2-D (the issue's target: <= 2) and the tables.

Usage: .venv/bin/python bench/bench_wall3d.py
"""

from __future__ import annotations

import time

import numba
import numpy as np

from vesselbot_ros.geometry.fixtures import cylinder_wall, y_wall
from vesselbot_ros.geometry.polyline_wall import nearest_wall
from vesselbot_ros.geometry.surface_query import nearest_wall3d, smooth_wall3d
from vesselbot_ros.geometry.surface_wall import Wall3D
from vesselbot_ros.vessels.cfd import network_wall
from vesselbot_ros.vessels.network import load_network

N = 200_000


@numba.njit(cache=False)
def _loop2d(q, segs, off, idx, x0, z0, h, nx, nz):  # type: ignore[no-untyped-def]
    acc = 0.0
    for k in range(q.shape[0]):
        acc += nearest_wall(q[k, 0], q[k, 1], segs, off, idx, x0, z0, h, nx, nz)[0]
    return acc


@numba.njit(cache=False)
def _loop3d(q, d, pbox, pstart, grid, nodes, index, smooth):  # type: ignore[no-untyped-def]
    acc = 0.0
    for k in range(q.shape[0]):
        if smooth:
            acc += smooth_wall3d(q[k, 0], q[k, 1], q[k, 2], d, pbox, pstart, grid, nodes, index)[1]
        else:
            acc += nearest_wall3d(q[k, 0], q[k, 1], q[k, 2], d, pbox, pstart, grid, nodes, index)[1]
    return acc


def best(f, reps=5):  # type: ignore[no-untyped-def]
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t)
    return min(ts)


def _sample(query, lo, hi, band, rng):  # type: ignore[no-untyped-def]
    """N points uniform in the lumen (band None) or within ``band`` of the wall inside it."""
    out = []
    while sum(len(o) for o in out) < N:
        q = rng.uniform(lo, hi, size=(4 * N, len(lo)))
        s = query(q)
        ok = (s > 0) if band is None else (s > 0) & (s < band)
        out.append(q[ok])
    return np.ascontiguousarray(np.concatenate(out)[:N])


def main() -> None:
    """Print the side-by-side table."""
    rng = np.random.default_rng(0)
    rows = []
    for name2, make3 in (("straight_table3", lambda: cylinder_wall(length_m=8e-3)), ("paper_iiic_artery", y_wall)):
        w2 = network_wall(load_network(name2))
        a2 = (w2._segs, w2._off, w2._idx, *w2._grid)
        x0, z0, h, nx, nz = w2._grid
        lo2, hi2 = np.array([x0, z0]), np.array([x0 + h * (nx - 1), z0 + h * (nz - 1)])
        v, t, caps, _n = make3()
        w3 = Wall3D(v, t, caps)
        a3 = w3._args
        wv = w3.surface.wall_vertices()
        lo3, hi3 = wv.min(axis=0), wv.max(axis=0)
        for band in (None, 0.3e-3):
            q2 = _sample(lambda q, w=w2: w.query(q)["sdist"], lo2, hi2, band, rng)
            q3 = _sample(lambda q, w=w3: w.query(q, smooth=False)["sdist"], lo3, hi3, band, rng)
            _loop2d(q2[:10], *a2)
            _loop3d(q3[:10], *a3, False)
            _loop3d(q3[:10], *a3, True)
            t2 = best(lambda q=q2, a=a2: _loop2d(q, *a)) / N * 1e9
            t3 = best(lambda q=q3, a=a3: _loop3d(q, *a, False)) / N * 1e9
            t3s = best(lambda q=q3, a=a3: _loop3d(q, *a, True)) / N * 1e9
            rows.append((name2, "lumen" if band is None else "wall<0.3mm", t2, t3, t3s))
        st = w3.tree.stats()
        print(f"{name2}: 2-D {len(w2.field.wall_segments)} segments, {w2.field.cell_index.size} candidates; 3-D "
              f"{len(w3.surface.triangles)} triangles in {w3.surface.patch_start.size - 1} patches, "
              f"{int(st['nodes'])} nodes, {int(st['entries'])} entries, {st['MB']:.1f} MB")
    print(f"{'geometry':20s} {'points':11s} {'2-D ns':>8s} {'3-D ns':>8s} {'3-D smooth':>10s} {'ratio':>6s} {'smooth':>7s}")
    for name, where, t2, t3, t3s in rows:
        print(f"{name:20s} {where:11s} {t2:8.0f} {t3:8.0f} {t3s:10.0f} {t3 / t2:6.1f} {t3s / t2:7.1f}")
    print("target: 3-D / 2-D <= 2")


if __name__ == "__main__":
    main()
