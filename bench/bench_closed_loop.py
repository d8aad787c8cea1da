"""Wall time of the 2 s Section III-C closed loop and its accuracy against a tighter reference.

Usage: .venv/bin/python bench/bench_closed_loop.py [config/sound_small_artery.yaml ...]

For each scenario prints: first-run time (includes numba JIT or cache load),
best of 3 warm runs, ratio to real time, and the relative difference of the
key metrics against a reference run with 100x tighter integrator tolerances
(the "half-step" check for an adaptive 5th-order scheme), then the metrics
over seeds 0..4 (mean and worst).
"""

from __future__ import annotations

import dataclasses as dc
import sys
import time
from pathlib import Path

from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
KEYS = ("tracking_error_max_m", "tracking_error_rms_m", "estimation_error_max_m", "estimation_error_rms_m")


def main(paths: list[str]) -> None:
    for path in paths or [str(ROOT / "config" / "sound_small_artery.yaml"), str(ROOT / "config" / "paper_small_artery.yaml")]:
        sc = load_scenario(path)
        t0 = time.perf_counter()
        run_closed_loop(sc)
        first = time.perf_counter() - t0
        best = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            res = run_closed_loop(sc)
            best = min(best, time.perf_counter() - t0)
        ig = sc.sim.integrator
        tight = dc.replace(sc, sim=dc.replace(sc.sim, integrator=dc.replace(
            ig, rtol=ig.rtol / 100, atol_position_m=ig.atol_position_m / 100,
            atol_velocity_m_per_s=ig.atol_velocity_m_per_s / 100)))
        ref = run_closed_loop(tight)
        sim_s = sc.sim.duration_s
        print(f"{sc.name}: first run {first:.3f} s (JIT/cache), warm {best:.3f} s for {sim_s:g} s simulated "
              f"-> {sim_s / best:.1f}x real time; plant rhs evals {res.metrics['plant_rhs_evals']}, "
              f"forced steps {res.metrics['plant_forced_steps']}")
        for k in KEYS:
            a, b = res.metrics[k], ref.metrics[k]
            print(f"  {k:28s} {a * 1e6:10.2f} um  tight-tolerance ref {b * 1e6:10.2f} um  rel diff {abs(a - b) / abs(b):.2e}")
        runs = [run_closed_loop(sc, seed).metrics for seed in range(5)]
        for k in KEYS + ("contact_time_s",):
            vals = [m[k] for m in runs]
            scale, unit = (1.0, "s ") if k.endswith("_s") else (1e6, "um")
            print(f"  seeds 0-4 {k:24s} mean {sum(vals) / len(vals) * scale:9.3f} {unit} worst {max(vals) * scale:9.3f} {unit}"
                  f"  per seed {[round(v * scale, 3) for v in vals]}")


if __name__ == "__main__":
    main(sys.argv[1:])
