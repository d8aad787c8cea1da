"""A stage kind kept outside the package, for the tests: it must run by name in simulate, campaign and run.

``controller.kind: vesselbot_test_plugin:IntegralController`` (with ``test/plugins``
on ``PYTHONPATH``).  The law carries state from tick to tick (an integral of
the position error), so a runner that rebuilt it, skipped a tick or called it
twice would change the numbers, and the tests compare them bit for bit.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numba
import numpy as np

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.backstepping import ControlCommand
from vesselbot_ros.control.bspline_reference import CompiledReference, RefSample
from vesselbot_ros.control.compiled_stage import CompiledController, lazy_step, model_f_into


@dataclasses.dataclass(frozen=True)
class IntegralParams:
    """Gains: ``U = a_ref + kd e_v + kp e_p + ki int(e_p) - F``."""

    kind: str = "vesselbot_test_plugin:IntegralController"
    kp_per_s2: float = 500.0
    kd_per_s: float = 45.0
    ki_per_s3: float = 800.0

    def __post_init__(self) -> None:
        if self.kp_per_s2 <= 0.0:
            raise ConfigError(f"kp_per_s2 must be > 0, got {self.kp_per_s2!r}")


class IntegralController:
    """PID on the position error with the model's forces fed forward (the test plug-in)."""

    ROLE = "controller"
    Params = IntegralParams

    def __init__(self, params: IntegralParams, context: Any) -> None:
        self.params = params
        self.model = context.model
        self.dt = context.dt_s
        self.b_inv = np.linalg.inv(self.model.input_matrix)
        self.integral = np.zeros(2)
        self.calls = 0

    def command(self, t_s: float, estimate: Any, ref: Any) -> ControlCommand:
        p = self.params
        e_p = ref.p - estimate.x_hat
        self.integral = self.integral + e_p * self.dt
        f = self.model.F(t_s, estimate.x_hat, estimate.z_hat, estimate.flow_scale)
        u = ref.a + p.kd_per_s * (ref.v - estimate.z_hat) + p.kp_per_s2 * e_p + p.ki_per_s3 * self.integral - f
        self.calls += 1
        return ControlCommand(self.b_inv @ u, u, "ok")


class NotAStage:
    """Has no ROLE: naming it as a kind is refused with one line."""


# ---- a compiled controller kind: one module, its class names its compiled step ------------------------------------
@dataclasses.dataclass(frozen=True)
class CompiledPDParams:
    """Gains of :class:`CompiledPD`."""

    kind: str = "vesselbot_test_plugin:CompiledPD"
    kp_per_s2: float = 600.0
    kd_per_s: float = 50.0


@numba.njit(cache=True, nogil=True)
def _pd(prm, geom, free, work, fbuf, sc, t, est, pr, vr, ar, out):  # type: ignore[no-untyped-def]  # numba kernel
    """U = a_ref + kd (v_ref - z) + kp (p_ref - x) - F(x, z); G = B^-1 U (prm: kp, kd, B^-1 row-major), on the d
    axes of the model ``geom`` (the plane or a 3-D tree: ``model_f_into`` reads either)."""
    d = pr.shape[0]
    f = work[3 * d:4 * d]
    model_f_into(t, est[:d], est[d:2 * d], geom, free, fbuf, sc, work[:2 * d], work[2 * d:3 * d], f)
    for i in range(d):
        out[d + i] = ar[i] + prm[1] * (vr[i] - est[d + i]) + prm[0] * (pr[i] - est[i]) - f[i]
    for i in range(d):
        acc = prm[2 + i * d] * out[d]
        for j in range(1, d):
            acc = acc + prm[2 + i * d + j] * out[d + j]
        out[i] = acc
    out[2 * d] = 1.0
    out[2 * d + 1] = 1.0
    return 0


def _pd_step(prm, state, geom, work, fbuf, sc, t, est, pr, vr, ar, out):  # type: ignore[no-untyped-def]  # numba kernel
    """The compiled loop's form of :class:`CompiledPD` (the same function as its Python ``command``)."""
    return _pd(prm, geom, state, work, fbuf, sc, t, est, pr, vr, ar, out)


pd_step = lazy_step(_pd_step)  # the numba cfunc, made on first use


class CompiledPD:
    """PD with the model's forces fed forward, in the compiled loop too (it has ``compiled()``), in any vessel."""

    ROLE = "controller"
    Params = CompiledPDParams

    def __init__(self, params: CompiledPDParams, context: Any) -> None:
        b_inv = np.linalg.inv(context.model.input_matrix)
        d = b_inv.shape[0]
        self.prm = np.array([params.kp_per_s2, params.kd_per_s, *b_inv.ravel()])
        self.geom = context.model.geom
        self.state = np.zeros(4)  # the memoryless contact state of F
        self.work = np.zeros(4 * d)
        self.fbuf = np.empty((8, d))
        self.sc = np.zeros((4, d))
        self.est = np.zeros(2 * d + 2)
        self.out = np.zeros(2 * d + 2)

    def command(self, t_s: float, estimate: Any, ref: Any) -> ControlCommand:
        d = self.est.shape[0] // 2 - 1
        self.est[:d] = estimate.x_hat
        self.est[d:2 * d] = estimate.z_hat
        _pd(self.prm, self.geom, self.state, self.work, self.fbuf, self.sc, t_s, self.est,
            np.asarray(ref.p, dtype=np.float64), np.asarray(ref.v, dtype=np.float64),
            np.asarray(ref.a, dtype=np.float64), self.out)
        return ControlCommand(self.out[0:d].copy(), self.out[d:2 * d].copy(), "ok")

    def compiled(self) -> CompiledController:
        return CompiledController(pd_step, self.prm, self.state, self.work.shape[0])


# ---- a reference kind with a compiled form: its samples at the tick times -----------------------------------------
@dataclasses.dataclass(frozen=True)
class GlideParams:
    """A straight glide from the start point: ``p(t) = p0 + v t`` (m, m/s), on the scenario's axes."""

    kind: str = "vesselbot_test_plugin:GlideReference"
    speed_m_per_s: float = 2.0e-3


class GlideReference:
    """Glides along x at a constant speed from the scenario's start point (the test plug-in's reference kind)."""

    ROLE = "reference"
    Params = GlideParams

    def __init__(self, params: GlideParams, context: Any) -> None:
        self.p0 = np.asarray(context.scenario.initial.p0_m, dtype=np.float64)
        self.v = np.zeros_like(self.p0)
        self.v[0] = params.speed_m_per_s

    def sample(self, t_s: float) -> RefSample:
        return RefSample(self.p0 + self.v * t_s, self.v.copy(), np.zeros_like(self.v))

    def sample_many(self, ts: np.ndarray) -> tuple[np.ndarray, ...]:
        t = np.asarray(ts, dtype=np.float64)[:, None]
        return self.p0 + self.v * t, np.repeat(self.v[None, :], len(t), axis=0), np.zeros((len(t), len(self.v)))

    def compiled(self) -> CompiledReference:
        return CompiledReference(self.sample_many)
