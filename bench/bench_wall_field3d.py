#!/usr/bin/env python3
"""The sampled 3-D wall's lookup against the 2-D one, measured side by side in one run.

Comparable geometries (as bench/bench_wall3d.py): the straight vessel (2-D ``straight_table3`` against the
3-D cylinder, R = 1.5 mm, 8 mm) and a bifurcation (2-D ``paper_iiic_artery`` against the 3-D Y).  Query
points: uniform in each geometry's lumen, and within 0.3 mm of the wall inside it, the same count in 2-D and
3-D.  Per call (compiled loop, best of 5), ns:

* 2-D wall: :func:`vesselbot_ros.geometry.polyline_wall.nearest_wall` (s, normal);
* 2-D geometry: :func:`vesselbot_ros.physics.kernel.network_geometry` (s, normal, D, viscosity, velocity:
  the planar force kernel's whole lookup);
* 3-D field: :func:`vesselbot_ros.geometry.field_lookup.wall_field3d` (s, normal, D; exact in flagged cells);
* 3-D exact: :func:`vesselbot_ros.geometry.surface_query.smooth_wall3d` (s, smooth normal), for reference;

and the ratios 3-D field / 2-D (target <= 2).  Also the fraction of the points answered exactly.

Usage: ``.venv/bin/python bench/bench_wall_field3d.py [--h-mm 0.1] [--refine 1]``
"""

from __future__ import annotations

import argparse

import numba
import numpy as np

# the 2-D loop, the exact 3-D loop, the timer and the sampler of the exact-query bench (bench/ is on the path of a
# script run from it)
from bench_wall3d import N, _loop2d, _loop3d, _sample, best

from vesselbot_ros.geometry.field_build import WallField3D, build_wall_field3d
from vesselbot_ros.geometry.field_lookup import wall_field3d
from vesselbot_ros.geometry.fixtures import cylinder_wall, y_wall
from vesselbot_ros.geometry.surface_wall import Wall3D
from vesselbot_ros.physics.kernel import network_geometry
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios
from vesselbot_ros.vessels.cfd import network_wall, packed_params
from vesselbot_ros.vessels.network import load_network


@numba.njit(cache=False)
def _loop2d_geometry(q, p):  # type: ignore[no-untyped-def]
    acc = 0.0
    for k in range(q.shape[0]):
        acc += network_geometry(0.0, q[k, 0], q[k, 1], p)[0]
    return acc


@numba.njit(cache=False)
def _loop3d_field(q, head, field, fine, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]
    acc = 0.0
    for k in range(q.shape[0]):
        acc += wall_field3d(q[k, 0], q[k, 1], q[k, 2], head, field, fine, d, pbox, pstart, grid, nodes, index)[0]
    return acc


def _exact(field: WallField3D, q: np.ndarray) -> float:
    """Fraction of the points the lookup answers by the exact query."""
    return float(field.exact_mask(q).mean())


def main() -> None:
    """Print the side-by-side table."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--h-mm", type=float, default=0.1, help="3-D grid spacing (mm)")
    ap.add_argument("--refine", type=int, default=1, help="sub-cells per axis in flagged cells (1: none)")
    a = ap.parse_args()
    h3 = a.h_mm * 1e-3
    rng = np.random.default_rng(0)
    rows = []
    scen = shipped_scenarios()
    for name2, sets, make3 in (("straight_table3", ["physics.vessel.network=straight_table3"], lambda: cylinder_wall(length_m=8e-3)),
                               ("paper_iiic_artery", ["physics.vessel.network=paper_iiic_artery"], y_wall)):
        w2 = network_wall(load_network(name2))
        a2 = (w2._segs, w2._off, w2._idx, *w2._grid)
        p2 = packed_params(load_scenario(scen["sound_small_artery"], sets=sets).physics)
        x0, z0, h, nx, nz = w2._grid
        lo2, hi2 = np.array([x0, z0]), np.array([x0 + h * (nx - 1), z0 + h * (nz - 1)])
        v, t, caps, _n = make3()
        w3 = Wall3D(v, t, caps, margin_m=1.05e-3 + 3 * h3)
        f3 = build_wall_field3d(w3, h_m=h3, refine=a.refine)
        wv = w3.surface.wall_vertices()
        lo3, hi3 = wv.min(axis=0), wv.max(axis=0)
        for band in (None, 0.3e-3):
            q2 = _sample(lambda q, w=w2: w.query(q)["sdist"], lo2, hi2, band, rng)
            q3 = _sample(lambda q, w=w3: w.query(q, smooth=False)["sdist"], lo3, hi3, band, rng)
            _loop2d(q2[:10], *a2)
            _loop2d_geometry(q2[:10], p2)
            _loop3d_field(q3[:10], *f3.args)
            _loop3d(q3[:10], *w3._args, True)
            t2 = best(lambda q=q2, a=a2: _loop2d(q, *a)) / N * 1e9
            t2g = best(lambda q=q2, p=p2: _loop2d_geometry(q, p)) / N * 1e9
            t3 = best(lambda q=q3, f=f3: _loop3d_field(q, *f.args)) / N * 1e9
            t3x = best(lambda q=q3, w=w3: _loop3d(q, *w._args, True)) / N * 1e9
            rows.append((name2, "lumen" if band is None else "wall<0.3mm", t2, t2g, t3, t3x, _exact(f3, q3)))
        st = f3.stats
        print(f"{name2}: 3-D field {int(st['nodes'])} nodes ({f3.shape}), h = {a.h_mm} mm, {st['MB']:.1f} MB, "
              f"{100 * st['flagged_fraction']:.2f} % cells flagged, {100 * st['exact_fraction']:.2f} % of the volume exact, "
              f"built in {st['build_s']:.1f} s")
    print(f"{'geometry':18s} {'points':11s} {'2-D wall':>9s} {'2-D geom':>9s} {'3-D field':>9s} {'3-D exact':>9s} "
          f"{'field/wall':>10s} {'field/geom':>10s} {'exact':>8s}")
    for name, where, t2, t2g, t3, t3x, fl in rows:
        print(f"{name:18s} {where:11s} {t2:9.0f} {t2g:9.0f} {t3:9.0f} {t3x:9.0f} {t3 / t2:10.2f} {t3 / t2g:10.2f} "
              f"{100 * fl:7.2f}%")
    print("ns per call; target: 3-D / 2-D <= 2")


if __name__ == "__main__":
    main()
