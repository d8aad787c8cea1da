#!/usr/bin/env python3
"""The closed loop in a 3-D tree against the planar one, measured side by side in one run.

Two figures, each a ratio of two measurements taken here, one after the other:

* run cost per simulated second: ``vesselbot simulate``'s compiled loop (``run_closed_loop``, warm, best of 5) of
  the III-C route in the plane (``paper_iiic_network_upper``) and written as a 3-D tree
  (``paper_iiic_network_upper_3d``), and of the two trees that leave the plane (``carotid_bifurcation_3d_eca``,
  ``synthetic_tree_3d_deep``) against the same planar run (target: 3-D <= 3 x planar);
* the force kernel's lookup (everything the kernel asks of the geometry and the flow at a point: distance, normal,
  diameter, viscosity, blood velocity): :func:`vesselbot_ros.physics.kernel.network_geometry` on the planar III-C
  network at the points its bead visits against :func:`vesselbot_ros.physics.tree_vessel.tree_geometry` on each 3-D tree
  at the points its bead visits (the true positions of the runs above; target: 3-D <= 2 x planar), with the share
  of those points the wall's exact query answers and the size of the tree's wall arrays; and at points uniform in
  the III-C lumen.

Then the run costs side by side with a reference commit's (``--ref``, default the commit issue 40 measured before
one loop served any number of axes; ``--ref ''`` skips it): CPU ms per simulated second of the planar route and the
three trees in both trees of code, taking turns, and the 3-D / planar ratio of the same route in each (issue 40's
target: <= 1.5x).

Usage: ``.venv/bin/python bench/bench_loop3d.py [--ref REV]``
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np
from bench_against import ISSUE_40_BASE, side_by_side  # this folder's: the same timing as bench_against.py

from vesselbot_ros.geometry.field_build import WallField3D
from vesselbot_ros.physics.kernel import network_geometry
from vesselbot_ros.physics.tree_vessel import tree_geometry
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios
from vesselbot_ros.vessels.cfd import packed_params
from vesselbot_ros.vessels.tree_field import packed_tree

PLANAR = "paper_iiic_network_upper"
TREES = ("paper_iiic_network_upper_3d", "carotid_bifurcation_3d_eca", "synthetic_tree_3d_deep")
REPEAT = 5


def per_sim_second(name: str) -> tuple[float, np.ndarray]:
    sc = load_scenario(shipped_scenarios()[name])
    res = run_closed_loop(sc, 0)  # warm: compile, load the samples
    assert res.path == "compiled", res.path
    best = np.inf
    for seed in range(REPEAT):
        t0 = time.perf_counter()
        run_closed_loop(sc, seed)
        best = min(best, time.perf_counter() - t0)
    return best / sc.sim.duration_s, res.timeseries["p_true"]


@numba.njit(cache=False)
def _loop2d(q, p):  # type: ignore[no-untyped-def]
    acc = 0.0
    for k in range(q.shape[0]):
        acc += network_geometry(0.1, q[k, 0], q[k, 1], p)[0]
    return acc


@numba.njit(cache=False)
def _loop3d(q, p, W, F, fh):  # type: ignore[no-untyped-def]
    acc = 0.0
    for k in range(q.shape[0]):
        acc += tree_geometry(0.1, q[k, 0], q[k, 1], q[k, 2], p, W, F, fh)[0]
    return acc


def ns_per_call(fn, q: np.ndarray, *args: object) -> float:  # type: ignore[no-untyped-def]
    fn(q[:10], *args)
    best = np.inf
    for _ in range(REPEAT):
        t0 = time.perf_counter()
        fn(q, *args)
        best = min(best, time.perf_counter() - t0)
    return 1e9 * best / len(q)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref", default=ISSUE_40_BASE, help="the reference commit of the side-by-side section ('' skips)")
    args = ap.parse_args()
    planar_s, p2 = per_sim_second(PLANAR)
    print("run cost per simulated second (compiled loop, best of 5)")
    print(f"  {PLANAR:32s} {1e3 * planar_s:8.2f} ms")
    visited = {}
    for name in TREES:
        s3, p3 = per_sim_second(name)
        visited[name] = p3
        print(f"  {name:32s} {1e3 * s3:8.2f} ms   {s3 / planar_s:5.2f} x planar (target <= 3)")
    p2d = packed_params(load_scenario(shipped_scenarios()[PLANAR]).physics)
    q2 = np.ascontiguousarray(np.repeat(p2, 20, axis=0))
    a2 = ns_per_call(_loop2d, q2, p2d)
    print("force kernel lookup (geometry and flow at a point), ns per call, at the points the bead visits")
    print(f"  {PLANAR:32s} planar {a2:7.1f}")
    for name in TREES:
        k3 = packed_tree(load_scenario(shipped_scenarios()[name]).physics)
        q3 = np.ascontiguousarray(np.repeat(visited[name], 20, axis=0))
        field = WallField3D.__new__(WallField3D)  # the lookup's own mask of exact cells, on the packed arrays
        field.head, field.field, field.fine = k3.W[0], k3.W[1], k3.W[2]
        exact = float(np.mean(field.exact_mask(q3)))
        listed = float(np.mean(field.list_mask(q3)))
        a3 = ns_per_call(_loop3d, q3, k3.p, k3.W, k3.F, k3.fh)
        mb = sum(a.nbytes for a in k3.W) / 1e6
        print(f"  {name:32s} 3-D    {a3:7.1f}   {a3 / a2:5.2f} x (target <= 2); exact share {exact:.1%}; "
              f"list cells {listed:.1%}; wall arrays {mb:.0f} MB")
    k3 = packed_tree(load_scenario(shipped_scenarios()[TREES[0]]).physics)
    rng = np.random.default_rng(0)
    q3 = visited[TREES[0]]
    lo, hi = q3.min(axis=0) - 1e-4, q3.max(axis=0) + 1e-4
    box3 = rng.uniform(lo, hi, size=(200_000, 3))
    box3[:, 1] = rng.uniform(-1.2e-3, 1.2e-3, len(box3))  # across the III-C vessels' width
    box2 = np.ascontiguousarray(box3[:, [0, 2]])
    box3 = np.ascontiguousarray(box3)
    b2, b3 = ns_per_call(_loop2d, box2, p2d), ns_per_call(_loop3d, box3, k3.p, k3.W, k3.F, k3.fh)
    print(f"  box points (III-C)               planar {b2:7.1f}   3-D {b3:7.1f}   {b3 / b2:5.2f} x")
    if args.ref:
        print("run cost per simulated second, ", end="")
        side_by_side(args.ref, [PLANAR, *TREES], ratios=((TREES[0], PLANAR, "3-D tree / planar network, same route "
                                                          "[issue 40 target <= 1.5x]"),))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
