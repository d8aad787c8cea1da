"""Compare observers fed exactly the same frames and gradients ("shadow" observers).

One closed loop runs with the scenario's own observer and controller; every
other observer under test is a *shadow*: at each tick it receives the same
delivered frame and the same applied gradient as the loop's observer, but its
estimate is not used by the controller.  All observers therefore estimate the
same true trajectory from the same data, which is what "fed the same frames"
means; their estimation errors are directly comparable.

A shadow that diverges (non-finite estimate or a failed prediction) is
reported as such, with the time it failed, not hidden.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from vesselbot_ros.control.high_gain_observer import ObserverParams
from vesselbot_ros.control.model import DynamicsModel
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.sim.closed_loop import build_stages
from vesselbot_ros.sim.kinds import make_observer
from vesselbot_ros.sim.scenario import Scenario

__all__ = ["ShadowResult", "compare_observers"]


@dataclasses.dataclass(frozen=True)
class ShadowResult:
    """Estimation error of one observer on one run (after ``metrics_after_s``).

    Attributes:
        rms_m: RMS of ``||X_hat - X||`` (m); inf if the observer diverged.
        max_m: Maximum of ``||X_hat - X||`` (m); inf if diverged.
        diverged_at_s: Time the observer failed (s), or None.
    """

    rms_m: float
    max_m: float
    diverged_at_s: float | None


def compare_observers(scenario: Scenario, seed: int, shadows: Mapping[str, ObserverParams]) -> dict[str, ShadowResult]:
    """Run ``scenario`` once and score its own observer and every shadow on the same frames.

    Args:
        scenario: The loop (its observer and controller close the loop).
        seed: Imager seed.
        shadows: ``{name: observer settings}`` to run alongside.

    Returns:
        ``{"loop": ..., name: ...}``: the loop's observer and every shadow.

    Raises:
        ModelInputError: if the loop itself fails (its own observer diverged).
    """
    st = build_stages(scenario, seed)
    n, dt = scenario.sim.n_ticks, scenario.sim.dt_control_s
    after = scenario.sim.metrics_after_s
    x0 = st.reference.sample(0.0).p
    z0, tick = scenario.initial.z_hat0_m_per_s, scenario.sim.dt_control_s
    def own_model() -> DynamicsModel:  # each observer integrates with its own step-size state and counters
        return DynamicsModel(scenario.model_physics(), scenario.sim.integrator, scenario.model.input_mapping)

    others = {name: make_observer(p, own_model(), x0, z0, tick) for name, p in shadows.items()}
    err: dict[str, list[float]] = {name: [] for name in ("loop", *others)}
    failed: dict[str, float] = {}
    g_prev = np.zeros(2)
    for k in range(n):
        t = k * dt
        truth = st.plant.output()
        meas = st.imager.frame(t, truth.p)
        est = st.observer.update(t, meas, g_prev)
        if t >= after - 1e-12:
            err["loop"].append(math.hypot(est.x_hat[0] - truth.p[0], est.x_hat[1] - truth.p[1]))
        for name, obs in others.items():
            if name in failed:
                continue
            try:
                e = obs.update(t, meas, g_prev)
            except ModelInputError:
                failed[name] = t
                continue
            d = math.hypot(e.x_hat[0] - truth.p[0], e.x_hat[1] - truth.p[1])
            if not math.isfinite(d) or d > 1.0:  # a metre off: gone
                failed[name] = t
            elif t >= after - 1e-12:
                err[name].append(d)
        ref = st.reference.sample(t)
        cmd = st.controller.command(t, est, ref)
        out = st.coil.apply(t, cmd.gradient_T_per_m)
        st.plant.step(out.applied)
        g_prev = out.applied
    res: dict[str, ShadowResult] = {}
    for name, errs in err.items():
        if name in failed:
            res[name] = ShadowResult(math.inf, math.inf, failed[name])
        else:
            a = np.asarray(errs)
            res[name] = ShadowResult(float(np.sqrt(np.mean(a * a))), float(np.max(a)), None)
    return res


def summarise(results: Sequence[Mapping[str, ShadowResult]]) -> dict[str, dict[str, Any]]:
    """Mean / worst over seeds of each observer's RMS and max error; divergences counted."""
    out: dict[str, dict[str, Any]] = {}
    for name in results[0]:
        rms = [r[name].rms_m for r in results]
        mx = [r[name].max_m for r in results]
        out[name] = {"rms_mean_m": float(np.mean(rms)), "rms_worst_m": float(np.max(rms)),
                     "max_mean_m": float(np.mean(mx)), "max_worst_m": float(np.max(mx)),
                     "diverged": sum(r[name].diverged_at_s is not None for r in results)}
    return out
