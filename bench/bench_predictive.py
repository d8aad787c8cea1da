"""The predictive controller's cost beside law (24): figures and ratios measured in one run, never pass/fail.

Usage::

    .venv/bin/python bench/bench_predictive.py [--repeats 5] [--config config/plans/clinical_3t.yaml]

1. **Compiled loop, ms per run**: the same planned scenario with law (24) and with the
   predictive controller, interleaved (A B A B ...), median of ``--repeats``; the
   ratio against the target (at most 5x law (24)).
2. **Planning as the controller node does it** (one process, one core): every call of
   the controller on the per-tick loop's inputs (:func:`vesselbot_ros.sim.kinds.call_controller`,
   what the controller node calls) is timed; the calls that plan (the first of a
   propulsion window or on a new frame) are set against two budgets: the control tick
   (1 ms: at real-time factor 1 a tick's work must fit in it) and the dead time before
   the propulsion window (the sequence's natural budget).  Printed: median, p99, max
   and the share of planning calls over each budget, and the same for law (24)'s calls.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

from vesselbot_ros.sim.closed_loop import build_stages, run_closed_loop, run_stages
from vesselbot_ros.sim.scenario import Scenario, load_scenario, scenario_with

ROOT = Path(__file__).resolve().parents[1]


class _Timed:
    """A controller whose every ``command`` is timed (wall s), for the per-tick loop."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.calls: list[tuple[float, float]] = []  # (t_s, seconds)

    def command(self, t_s: float, estimate: Any, ref: Any) -> Any:
        t0 = time.perf_counter()
        out = self.inner.command(t_s, estimate, ref)
        self.calls.append((t_s, time.perf_counter() - t0))
        return out

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


def _per_call(s: Scenario) -> np.ndarray:
    st = build_stages(s, 0)
    timed = _Timed(st.controller)
    run_stages(s, st._replace(controller=timed), 0, path="per_tick")
    return np.array(timed.calls)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default=str(ROOT / "config" / "plans" / "clinical_3t.yaml"))
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    law = load_scenario(args.config)
    carried = getattr(law.controller, "wall_contact", "none")  # a plan on the wall: the predictive kind carries it too
    mpc = scenario_with(law, {"controller.kind": "predictive", "controller.wall_contact": carried})
    for s in (law, mpc):  # compile and warm both
        run_closed_loop(s, 0)
    times: dict[str, list[float]] = {"law24": [], "predictive": []}
    for _ in range(args.repeats):
        for name, s in (("law24", law), ("predictive", mpc)):
            t0 = time.perf_counter()
            run_closed_loop(s, 0)
            times[name].append(time.perf_counter() - t0)
    med = {k: statistics.median(v) for k, v in times.items()}
    ratio = med["predictive"] / med["law24"]
    print(f"compiled loop, {law.name} ({law.sim.duration_s:.2f} s simulated), median of {args.repeats}, interleaved:")
    print(f"  law (24)     {med['law24'] * 1e3:8.1f} ms/run")
    print(f"  predictive   {med['predictive'] * 1e3:8.1f} ms/run   ratio {ratio:.2f}x (target <= 5x: "
          f"{'met' if ratio <= 5.0 else 'MISSED'})")
    seq = law.sequence
    tick = 1.0 / law.sim.control_rate_Hz
    dead = seq.dead_time_s if seq.mode == "multiplexed" else tick
    print(f"controller calls per tick as the controller node makes them (per-tick loop, one core); budgets: "
          f"tick {tick * 1e3:.1f} ms (real-time factor 1), dead time before a window {dead * 1e3:.1f} ms")
    for name, s in (("law24", law), ("predictive", mpc)):
        _per_call(s)  # warm: the per-tick path's first calls compile
        calls = _per_call(s)
        dt = calls[:, 1]
        plan = dt[dt > 5.0 * np.median(dt)] if name == "predictive" else dt
        label = "planning calls" if name == "predictive" else "all calls"
        print(f"  {name:<11} {dt.size} calls, median {np.median(dt) * 1e6:7.0f} us; {label} ({plan.size}): "
              f"p50 {np.median(plan) * 1e6:6.0f} us, p99 {np.percentile(plan, 99) * 1e6:6.0f} us, "
              f"max {plan.max() * 1e6:6.0f} us; over the tick {np.mean(plan > tick):.1%}, "
              f"over the dead time {np.mean(plan > dead):.1%}")


if __name__ == "__main__":
    main()
