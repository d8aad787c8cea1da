"""What keeping BLAS out of the per-run numerics costs, measured side by side.

Usage: .venv/bin/python bench/bench_blas_free.py

Each line times the BLAS path (what the code did before: numpy ``@`` / ``inv``,
``make_interp_spline``, ``solve_ivp``) and the BLAS-free path that replaced it
(:mod:`vesselbot_ros.blas_free`), interleaved in one process, best of several
repeats, and prints the ratio.  The last lines put the per-tick difference in
proportion to a whole warm run of the sound scenario (2000 ticks).  Absolute
times depend on the machine's load; the ratios and the share of a run are the
result.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import make_interp_spline

from vesselbot_ros.blas_free import interp_spline, interp_spline_fitpack, mat2, mat2_apply, mat2_inverse
from vesselbot_ros.control.bspline_reference import ReferenceParams, ReferenceTrajectory
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios


def best_of(fn: Callable[[], object], number: int, repeat: int = 7) -> float:
    """Best mean time per call (s) over ``repeat`` batches of ``number`` calls."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t0) / number)
    return best


def line(label: str, old: float, new: float) -> None:
    print(f"{label:<44} {old * 1e6:10.2f} us {new * 1e6:10.2f} us   ratio {new / old:5.2f}")


def main() -> None:
    b = np.array([[208.5, 0.0], [0.0, 208.5]])
    u = np.array([1.3, -0.4])
    b_inv_np = np.linalg.inv(b)
    b_inv, bm = mat2_inverse(mat2(b)), mat2(b)
    print(f"{'operation':<44} {'BLAS':>13} {'BLAS-free':>13}")
    t_ctl_old = best_of(lambda: b_inv_np @ u, 20000)
    t_ctl_new = best_of(lambda: np.array(mat2_apply(b_inv, u[0], u[1])), 20000)
    line("controller G = B^-1 U, per tick", t_ctl_old, t_ctl_new)
    t_obs_old = best_of(lambda: b @ u, 20000)
    t_obs_new = best_of(lambda: np.array(mat2_apply(bm, u[0], u[1])), 20000)
    line("observer U = B G, per tick", t_obs_old, t_obs_new)
    line("controller set-up: inverse of B", best_of(lambda: np.linalg.inv(b), 5000),
         best_of(lambda: mat2_inverse(mat2(b)), 5000))

    x = np.cumsum(np.full(8, 1.5e-3))
    y = np.column_stack([x, 1e-3 * np.sin(x * 500.0)])
    line("path spline, 8 anchors (natural C2)", best_of(lambda: make_interp_spline(x, y, k=3, bc_type="natural"), 200),
         best_of(lambda: interp_spline(x, y, 3), 200))
    ts = np.linspace(0.0, 2.0, 1001)
    us = np.sin(ts) + ts
    line("timing spline, 1001 points (not-a-knot)", best_of(lambda: make_interp_spline(ts, us, k=3), 50),
         best_of(lambda: interp_spline_fitpack(ts, us), 50))

    def vf(t: float, p: np.ndarray) -> float:
        return 0.025 * (1.0 + 0.5 * np.sin(2.0 * np.pi * t))

    params = ReferenceParams(timing="flow_synchronised", sync_ratio=0.5)
    ref = ReferenceTrajectory(params, vf)

    def scipy_timing() -> None:  # the previous construction: RK45 through BLAS gemv
        def rhs(t: float, yy: np.ndarray) -> list[float]:
            uu = min(max(float(yy[0]), 0.0), ref.length_m)
            return [0.5 * vf(t, ref._path(uu)) / float(ref._d1(uu)[0])]
        sol = solve_ivp(rhs, (0.0, 2.0), [0.0], t_eval=ts, rtol=1e-9, atol=1e-12, max_step=2.0 / 200)
        make_interp_spline(ts, sol.y[0], k=3)

    line("flow-synchronised timing (ODE + spline)", best_of(scipy_timing, 3, 3),
         best_of(lambda: ReferenceTrajectory(params, vf), 3, 3))

    scenario = load_scenario(shipped_scenarios()["sound_small_artery"])
    run_closed_loop(scenario)  # JIT / cache load
    t_run = best_of(lambda: run_closed_loop(scenario), 1, 3)
    per_tick = (t_ctl_new - t_ctl_old) + (t_obs_new - t_obs_old)
    n = scenario.sim.n_ticks
    print(f"\nsound scenario, one warm run of {n} ticks: {t_run * 1e3:.1f} ms")
    print(f"per-run cost of the BLAS-free 2x2 products: {per_tick * n * 1e3:+.2f} ms "
          f"({100.0 * per_tick * n / t_run:+.2f} % of the run)")


if __name__ == "__main__":
    main()
