"""Hostile stage kinds kept outside the package, for the tests of rejected commands (issue 38, section 2).

With ``test/plugins`` on ``PYTHONPATH`` a scenario names them as ``controller.kind:
vesselbot_hostile_plugin:NaNFrom`` (and so on):

* :class:`NaNFrom`: the test plug-in's PD law until ``start_s``, then NaN (or ``+inf`` with ``value: inf``)
  gradients; it has a compiled form, so ``simulate`` runs it in the compiled loop, and ``path="per_tick"``
  runs its Python ``command``: the two must give the same bits;
* :class:`Hostile`: the same PD law until ``start_s``, then one kind of bad answer (``mode``): ``raise``,
  ``none``, ``wrong_length``, ``bad_status``, or ``bare_array`` (a bare ndarray of the right shape, from
  the start: a command);
* :class:`BrokenConstructor`: its constructor raises;
* :class:`NaNObserver`: the built-in observer (25), whose estimate turns NaN from ``start_s``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numba
import numpy as np

from vesselbot_ros.control.backstepping import ControlCommand
from vesselbot_ros.control.compiled_stage import CompiledController, lazy_step
from vesselbot_ros.control.high_gain_observer import ObserverParams
from vesselbot_ros.physics.kernel import accel_no_motive


@numba.njit(cache=True, nogil=True)
def _pd_or_bad(prm, model_p, free, t, x0, x1, z0, z1, pr0, pr1, vr0, vr1, ar0, ar1, out):  # type: ignore[no-untyped-def]  # numba kernel
    """PD with the model's forces fed forward, then ``prm[7]`` (NaN or inf) from ``t >= prm[6]``."""
    f0, f1 = accel_no_motive(t, x0, x1, z0, z1, free, model_p)
    u0 = ar0 + prm[1] * (vr0 - z0) + prm[0] * (pr0 - x0) - f0
    u1 = ar1 + prm[1] * (vr1 - z1) + prm[0] * (pr1 - x1) - f1
    out[0] = prm[2] * u0 + prm[3] * u1
    out[1] = prm[4] * u0 + prm[5] * u1
    out[2] = u0
    out[3] = u1
    out[4] = 1.0
    out[5] = 1.0
    if t >= prm[6]:
        out[0] = prm[7]
        out[1] = prm[7]
    return 0


def _nan_step(prm, state, geom, work, fbuf, sc, t, est, pr, vr, ar, out):  # type: ignore[no-untyped-def]  # numba kernel
    return _pd_or_bad(prm, geom, state, t, est[0], est[1], est[2], est[3], pr[0], pr[1], vr[0], vr[1], ar[0], ar[1], out)


nan_step = lazy_step(_nan_step)


@dataclasses.dataclass(frozen=True)
class NaNFromParams:
    """PD gains, the time the commands turn bad, and the bad value (``nan`` or ``inf``)."""

    kind: str = "vesselbot_hostile_plugin:NaNFrom"
    kp_per_s2: float = 600.0
    kd_per_s: float = 50.0
    start_s: float = 0.5
    value: str = "nan"


class NaNFrom:
    """PD law, then NaN (or inf) gradients from ``start_s`` on, in both loops (it has ``compiled()``)."""

    ROLE = "controller"
    Params = NaNFromParams

    def __init__(self, params: NaNFromParams, context: Any) -> None:
        b_inv = np.linalg.inv(context.model.input_matrix)
        bad = math.inf if params.value == "inf" else math.nan
        self.prm = np.array([params.kp_per_s2, params.kd_per_s, *b_inv.ravel(), params.start_s, bad])
        self.model_p = context.model.p
        self.state = np.zeros(4)
        self.out = np.zeros(6)

    def command(self, t_s: float, estimate: Any, ref: Any) -> ControlCommand:
        x, z = estimate.x_hat, estimate.z_hat
        _pd_or_bad(self.prm, self.model_p, self.state, t_s, x[0], x[1], z[0], z[1], ref.p[0], ref.p[1], ref.v[0],
                   ref.v[1], ref.a[0], ref.a[1], self.out)
        return ControlCommand(self.out[0:2].copy(), self.out[2:4].copy(), "ok")

    def compiled(self) -> CompiledController:
        return CompiledController(nan_step, self.prm, self.state, 0)


@dataclasses.dataclass(frozen=True)
class HostileParams:
    """PD gains, the time the answers turn bad and how (``mode``)."""

    kind: str = "vesselbot_hostile_plugin:Hostile"
    kp_per_s2: float = 600.0
    kd_per_s: float = 50.0
    start_s: float = 0.5
    mode: str = "raise"


class Hostile:
    """PD law until ``start_s``, then a bad answer of kind ``mode`` (module docstring); Python only."""

    ROLE = "controller"
    Params = HostileParams

    def __init__(self, params: HostileParams, context: Any) -> None:
        b_inv = np.linalg.inv(context.model.input_matrix)
        self.params = params
        self.prm = np.array([params.kp_per_s2, params.kd_per_s, *b_inv.ravel(), math.inf, math.nan])
        self.model_p = context.model.p
        self.state = np.zeros(4)
        self.out = np.zeros(6)

    def command(self, t_s: float, estimate: Any, ref: Any) -> Any:
        x, z = estimate.x_hat, estimate.z_hat
        _pd_or_bad(self.prm, self.model_p, self.state, t_s, x[0], x[1], z[0], z[1], ref.p[0], ref.p[1], ref.v[0],
                   ref.v[1], ref.a[0], ref.a[1], self.out)
        g = self.out[0:2].copy()
        mode = self.params.mode
        if mode == "bare_array":
            return g
        if t_s < self.params.start_s:
            return ControlCommand(g, self.out[2:4].copy(), "ok")
        if mode == "raise":
            raise ZeroDivisionError("the hostile controller divided by zero")
        if mode == "none":
            return None
        if mode == "wrong_length":
            return ControlCommand(np.array([g[0], 0.0, g[1]]), self.out[2:4].copy(), "ok")
        if mode == "bad_status":
            return ControlCommand(g, self.out[2:4].copy(), "fine")
        raise ValueError(f"unknown mode {mode!r}")


@dataclasses.dataclass(frozen=True)
class BrokenParams:
    """Nothing to set."""

    kind: str = "vesselbot_hostile_plugin:BrokenConstructor"


class BrokenConstructor:
    """Its constructor raises."""

    ROLE = "controller"
    Params = BrokenParams

    def __init__(self, params: BrokenParams, context: Any) -> None:
        raise RuntimeError("no calibration file for this coil")

    def command(self, t_s: float, estimate: Any, ref: Any) -> ControlCommand:  # pragma: no cover - never built
        raise AssertionError


@dataclasses.dataclass(frozen=True)
class NaNObserverParams:
    """The time the estimates turn NaN."""

    kind: str = "vesselbot_hostile_plugin:NaNObserver"
    start_s: float = 0.5


class NaNObserver:
    """The built-in observer (25) with default gains; its estimate is NaN from ``start_s``."""

    ROLE = "observer"
    Params = NaNObserverParams

    def __init__(self, params: NaNObserverParams, context: Any) -> None:
        from vesselbot_ros.sim.kinds import make_observer

        s = context.scenario
        self.start_s = params.start_s
        self.inner = make_observer(ObserverParams(), context.model, context.get("reference").sample(0.0).p,
                                   s.initial.z_hat0_m_per_s, context.dt_s)

    def update(self, t_s: float, measurement: Any, g_prev: Any) -> Any:
        est = self.inner.update(t_s, measurement, g_prev)
        if t_s >= self.start_s:
            return est._replace(x_hat=np.full(2, np.nan), z_hat=np.full(2, np.nan))
        return est
