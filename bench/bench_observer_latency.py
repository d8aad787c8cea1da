"""Delay-compensating observer against observer (25), fed the same frames.

Usage: .venv/bin/python bench/bench_observer_latency.py

The loop: ``sound_small_artery_ekf`` with frames at 25 /s delivered 20 ms after
acquisition, closed by the extended Kalman observer with delay compensation
and law (24) with Table III's gains (the loop's k1 + k2 = 300 1/s is too fast
for 40 ms between frames: it hits the wall).  Shadows, fed the same frames and
gradients (:mod:`vesselbot_ros.analysis.observer_comparison`): the same filter
without delay compensation, observer (25) with Table III's gains (unstable
when sampled at 25 /s: spectral radius printed) and (25) with the smallest
high gain we found stable there.  Prints mean / worst over seeds 0-4 and the
ratio of (25)'s estimation error to the delay-compensating filter's.
"""

from __future__ import annotations

import copy
import dataclasses

from vesselbot_ros.analysis.observer_comparison import compare_observers, summarise
from vesselbot_ros.control.high_gain_observer import ObserverParams, sampled_error_radius
from vesselbot_ros.sim.scenario import load_scenario, scenario_from_mapping, shipped_scenarios

FRAME_RATE_HZ = 25.0
LATENCY_S = 0.020


def main() -> None:
    m = copy.deepcopy(load_scenario(shipped_scenarios()["sound_small_artery_ekf"]).to_mapping())
    m["imager"].update(frame_rate_Hz=FRAME_RATE_HZ, latency_s=LATENCY_S)
    m["controller"]["gains"].update(k1=5.0, k2=10.0)
    loop = scenario_from_mapping(m)
    ekf = loop.observer
    t3 = ObserverParams()
    shadows = {
        "EKF, no delay compensation": dataclasses.replace(ekf, ekf=dataclasses.replace(ekf.ekf, delay_compensation=False)),
        "(25) Table III (L = 5)": t3,
        "(25) L = 2": dataclasses.replace(t3, high_gain=2.0),
    }
    period = 1.0 / FRAME_RATE_HZ
    print(f"frames {FRAME_RATE_HZ:g}/s, latency {LATENCY_S * 1e3:g} ms; sampled (25) spectral radius: "
          f"L = 5: {sampled_error_radius(t3, period):.3f}, L = 2: {sampled_error_radius(shadows['(25) L = 2'], period):.3f}")
    results = [compare_observers(loop, seed, shadows) for seed in range(5)]
    summary = summarise(results)
    base = summary["loop"]["rms_mean_m"]
    print(f"{'observer (seeds 0-4, after 0.6 s)':<34} {'rms mean/worst (um)':>22} {'max mean/worst (um)':>22} "
          f"{'diverged':>9} {'rms ratio':>10}")
    for name, s in summary.items():
        label = "EKF, delay compensation (loop)" if name == "loop" else name
        print(f"{label:<34} {s['rms_mean_m'] * 1e6:10.1f} / {s['rms_worst_m'] * 1e6:9.1f} "
              f"{s['max_mean_m'] * 1e6:10.1f} / {s['max_worst_m'] * 1e6:9.1f} {s['diverged']:>9d} "
              f"{s['rms_mean_m'] / base:10.2f}")


if __name__ == "__main__":
    main()
