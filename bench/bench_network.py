#!/usr/bin/env python3
"""Vessel networks: force evaluation (network vs straight kernel), CFD solve + sampling, pure loop speed.

Prints side-by-side figures and ratios.  Usage: .venv/bin/python bench/bench_network.py
"""

from __future__ import annotations

import os
import tempfile
import time

import numba
import numpy as np

from vesselbot_ros.physics.kernel import forces_into
from vesselbot_ros.physics.params import BloodParams
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios
from vesselbot_ros.vessels.cfd import packed_params


@numba.njit(cache=False)
def _many(n, p, out):  # type: ignore[no-untyped-def]
    c = np.zeros(4)
    acc = 0.0
    for k in range(n):
        forces_into(0.001 * k, 2e-3 + 1e-6 * k % 8e-3, 0.8e-3, 1e-3, 0.0, 0.01, 0.0, c, p, out)
        acc += out[7, 0]
    return acc


def best(f, reps=5):  # type: ignore[no-untyped-def]
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t)
    return min(ts)


def main() -> None:
    straight = load_scenario(shipped_scenarios()["sound_small_artery"])
    net1 = load_scenario(shipped_scenarios()["sound_small_artery"], sets=["physics.vessel.network=straight_table3"])
    paper = load_scenario(shipped_scenarios()["paper_iiic_network_upper"])
    out = np.empty((8, 2))
    n = 1_000_000
    ps, pn = packed_params(straight.physics), packed_params(paper.physics)
    _many(10, ps, out)
    _many(10, pn, out)
    ts = best(lambda: _many(n, ps, out)) / n
    tn = best(lambda: _many(n, pn, out)) / n
    print(f"force evaluation: straight kernel {ts * 1e9:.0f} ns, network kernel {tn * 1e9:.0f} ns, ratio {tn / ts:.2f} (target <= 2)")
    from vesselbot_ros.vessels.cfd import network_field
    from vesselbot_ros.vessels.network import load_network

    with tempfile.TemporaryDirectory() as d:
        os.environ["VESSELBOT_CFD_CACHE"] = d
        t = time.perf_counter()
        f = network_field(load_network("paper_iiic_artery"), BloodParams(), refresh=True)  # not the shipped field
        tc = time.perf_counter() - t
        os.environ.pop("VESSELBOT_CFD_CACHE")
    print(f"CFD of paper_iiic_artery from scratch: {tc:.1f} s (solve {f.meta['solve_s']:.1f} s, "
          f"{f.meta['n_dofs']} dofs, {f.meta['picard_iterations']} Picard iterations; grid {f.nx} x {f.nz}) (target <= 60 s)")
    for label, sc in (("straight, analytic", straight), ("straight, one-branch CFD", net1), ("III-C network", paper)):
        run_closed_loop(sc, 0)
        w = best(lambda sc=sc: run_closed_loop(sc, 0), reps=3)
        print(f"pure loop {label:26s}: {sc.sim.duration_s:.1f} s simulated in {w:.3f} s -> {sc.sim.duration_s / w:.0f}x real time")


if __name__ == "__main__":
    main()
