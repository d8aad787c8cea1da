#!/usr/bin/env python3
"""The best loop in vessel trees: what it costs beside the paper's loop, and where its time goes.

Prints, measured side by side in one run (best of a few repeats; ratios, not absolute times, are the result):

1. per route, the compiled loop's wall time per simulated second: the paper's loop (observer (25), law (24)) and the
   extended Kalman filter with law (24) on the same reference (the tree scenario with the EKF's overrides), and
   the ratio (the navigation target: <= 3); then (1b) the same two loops on the planned routes of the
   ``<tree>_ekf`` scenarios;
2. the EKF loop in the 3-D III-C tree against the same route in the plane, per simulated second (target <= 1.5);
3. where one EKF tick's time goes, in compiled loops at a state on the route: one force evaluation of the model
   (the flow and wall look-ups included), the covariance's prediction (2 d + 2 force evaluations for the
   forward-difference Jacobian and the matrix products), and what copying a network's packed parameters with
   their CFD block cost per force evaluation before ``flow_scaled_into`` kept the block in place.

Usage: .venv/bin/python bench/bench_tree_loops.py
"""

from __future__ import annotations

import time

import numba
import numpy as np

from vesselbot_ros.control.ekf_observer import _f, _predict_cov
from vesselbot_ros.sim.closed_loop import build_stages, run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios

EKF = ["observer.kind=ekf", "observer.ekf={measurement_sigma_m: 1.0e-4, accel_noise_m_per_s2_sqrt_s: 0.01, "
       "flow_scale_noise_per_sqrt_s: 0.02, flow_scale_sigma0: 0.1}", "controller.gains={k1: 150.0, k2: 150.0}",
       "controller.flow_compensation=estimate"]
#: The paper's loop on a best-loop scenario: observer (25) and law (24) with Table III's gains, no compensation.
PAPER = ["observer.kind=high_gain", "controller.gains={k1: 5.0, k2: 10.0}", "controller.flow_compensation=none"]
ROUTES = ("paper_iiic_network_upper", "paper_iiic_network_lower", "small_artery_4gen_udu", "paper_iiic_network_upper_3d",
          "carotid_bifurcation_3d_eca", "synthetic_tree_3d_deep")


def best(f, reps: int = 3) -> float:  # type: ignore[no-untyped-def]
    out = []
    for _ in range(reps):
        t = time.perf_counter()
        f()
        out.append(time.perf_counter() - t)
    return min(out)


def per_sim_s(name: str, sets: list[str]) -> float:
    """Compiled loop wall time (s) per simulated second, seed 0."""
    sc = load_scenario(shipped_scenarios()[name], sets=sets)
    run_closed_loop(sc, 0)  # compile, build the vessel
    return best(lambda: run_closed_loop(sc, 0)) / sc.sim.duration_s


@numba.njit(cache=False)
def _many_f(n, t, y, u, free, geom, p_s, out, fbuf, sc, tc, g0):  # type: ignore[no-untyped-def]
    acc = 0.0
    for k in range(n):
        tc[0] = np.nan  # no memo: each evaluation looks everything up
        _f(t + 1e-9 * k, y, u, free, geom, p_s, out, fbuf, sc, tc, g0, False)
        acc += out[-2]
    return acc


@numba.njit(cache=False)
def _many_cov(n, t, y, P0, P, u, free, geom, p_s, f0, f1, yp, A, Phi, T, fbuf, sc, tc, g0):  # type: ignore[no-untyped-def]
    acc = 0.0
    for _ in range(n):
        P[:, :] = P0
        _predict_cov(t, 1e-3, y, P, u, 1e-4, 4e-4, free, geom, p_s, f0, f1, yp, A, Phi, T, fbuf, sc, tc, g0, False)
        acc += P[0, 0]
    return acc


@numba.njit(cache=False)
def _many_copy(n, p, p_s):  # type: ignore[no-untyped-def]
    for _ in range(n):
        for i in range(p.shape[0]):
            p_s[i] = p[i]
    return p_s[0]


def tick_costs(name: str) -> tuple[float, float, float, int]:
    """(one force evaluation, one covariance prediction, one whole-vector copy) in s, and the vector's length."""
    sc = load_scenario(shipped_scenarios()[name], sets=EKF)
    obs = build_stages(sc).observer
    e = obs.ekf
    d = e.dims
    ts = run_closed_loop(sc, 0).timeseries
    k = len(ts["t_s"]) // 2  # a state on the route, mid-run
    y = np.concatenate([ts["p_true"][k], ts["v_true"][k], [1.0]])
    t = float(ts["t_s"][k])
    u, g0, free = np.zeros(d), np.zeros(d), np.zeros(4)
    tc = np.full(e.vec.shape[1], np.nan)
    out = np.zeros(2 * d + 1)
    p = e.geom[0] if isinstance(e.geom, tuple) else e.geom  # a tree: (p, wall, flow, grid)
    p_s = p.copy()
    n = 20000
    _many_f(10, t, y, u, free, e.geom, p_s, out, e.fbuf, e.sc, tc, g0)
    t_f = best(lambda: _many_f(n, t, y, u, free, e.geom, p_s, out, e.fbuf, e.sc, tc, g0)) / n
    P0 = e.P.copy()
    P = P0.copy()
    f0, f1, yp = np.zeros(2 * d + 1), np.zeros(2 * d + 1), np.zeros(2 * d + 1)
    A, Phi, T = (np.zeros((2 * d + 1, 2 * d + 1)) for _ in range(3))
    _many_cov(10, t, y, P0, P, u, free, e.geom, p_s, f0, f1, yp, A, Phi, T, e.fbuf, e.sc, tc, g0)
    t_cov = best(lambda: _many_cov(n // 4, t, y, P0, P, u, free, e.geom, p_s, f0, f1, yp, A, Phi, T, e.fbuf, e.sc,
                                   tc, g0)) / (n // 4)
    m = 200 if p.size > 10_000 else 20000
    _many_copy(2, p, p_s)
    t_copy = best(lambda: _many_copy(m, p, p_s)) / m
    return t_f, t_cov, t_copy, int(p.size)


def main() -> None:
    print("1. compiled loop, wall time per simulated second (seed 0), same route:")
    print(f"   {'route':30s} {'paper loop':>11s} {'EKF loop':>10s} {'ratio':>7s}  (target <= 3)")
    ekf_of = {}
    for name in ROUTES:
        a = per_sim_s(name, [])
        b = per_sim_s(name, EKF)
        ekf_of[name] = b
        print(f"   {name:30s} {a * 1e3:8.2f} ms {b * 1e3:7.2f} ms {b / a:7.2f}")
    print("1b. the same on the planned routes (the best loop's scenarios, <route>_ekf), the paper loop flown on them:")
    for name in ROUTES:
        a = per_sim_s(name + "_ekf", PAPER)
        b = per_sim_s(name + "_ekf", [])
        ekf_of[name + "_ekf"] = b
        print(f"   {name + '_ekf':30s} {a * 1e3:8.2f} ms {b * 1e3:7.2f} ms {b / a:7.2f}")
    for suffix, what in (("", "hand-timed"), ("_ekf", "planned")):
        p2, p3 = ekf_of["paper_iiic_network_upper" + suffix], ekf_of["paper_iiic_network_upper_3d" + suffix]
        print(f"2. EKF loop, III-C upper route ({what}): 3-D tree {p3 * 1e3:.2f} ms / plane {p2 * 1e3:.2f} ms per "
              f"simulated s = {p3 / p2:.2f} (target <= 1.5)")
    print("3. where an EKF tick's time goes (compiled; a state mid-route):")
    for name in ("paper_iiic_network_lower", "paper_iiic_network_upper_3d", "synthetic_tree_3d_deep"):
        t_f, t_cov, t_copy, n_p = tick_costs(name)
        print(f"   {name:30s} force evaluation {t_f * 1e9:7.0f} ns; covariance prediction {t_cov * 1e6:6.2f} us "
              f"({t_cov / t_f:.1f} force evaluations' worth); copying the {n_p}-entry parameter vector "
              f"{t_copy * 1e6:8.1f} us = {t_copy / t_f:.0f} force evaluations (paid per evaluation before the fix)")


if __name__ == "__main__":
    main()
