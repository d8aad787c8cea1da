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
from vesselbot_ros.control.compiled_stage import CompiledController, lazy_step
from vesselbot_ros.physics.kernel import accel_no_motive


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
def _pd(prm, model_p, free, t, x0, x1, z0, z1, pr0, pr1, vr0, vr1, ar0, ar1, out):  # type: ignore[no-untyped-def]  # numba kernel
    """U = a_ref + kd (v_ref - z) + kp (p_ref - x) - F(x, z); G = B^-1 U (prm: kp, kd, B^-1 row-major)."""
    f0, f1 = accel_no_motive(t, x0, x1, z0, z1, free, model_p)
    u0 = ar0 + prm[1] * (vr0 - z0) + prm[0] * (pr0 - x0) - f0
    u1 = ar1 + prm[1] * (vr1 - z1) + prm[0] * (pr1 - x1) - f1
    out[0] = prm[2] * u0 + prm[3] * u1
    out[1] = prm[4] * u0 + prm[5] * u1
    out[2] = u0
    out[3] = u1
    out[4] = 1.0
    out[5] = 1.0
    return 0


def _pd_step(prm, state, model_p, work, fbuf, t, x0, x1, z0, z1, age, flow_scale,  # type: ignore[no-untyped-def]  # numba kernel
            pr0, pr1, vr0, vr1, ar0, ar1, out):
    """The compiled loop's form of :class:`CompiledPD` (the same function as its Python ``command``)."""
    return _pd(prm, model_p, state, t, x0, x1, z0, z1, pr0, pr1, vr0, vr1, ar0, ar1, out)


pd_step = lazy_step(_pd_step)  # the numba cfunc, made on first use


class CompiledPD:
    """PD with the model's forces fed forward, in the compiled loop too (it has ``compiled()``)."""

    ROLE = "controller"
    Params = CompiledPDParams

    def __init__(self, params: CompiledPDParams, context: Any) -> None:
        b_inv = np.linalg.inv(context.model.input_matrix)
        self.prm = np.array([params.kp_per_s2, params.kd_per_s, *b_inv.ravel()])
        self.model_p = context.model.p
        self.state = np.zeros(4)  # the memoryless contact state of F
        self.out = np.zeros(6)

    def command(self, t_s: float, estimate: Any, ref: Any) -> ControlCommand:
        x, z = estimate.x_hat, estimate.z_hat
        _pd(self.prm, self.model_p, self.state, t_s, x[0], x[1], z[0], z[1], ref.p[0], ref.p[1], ref.v[0], ref.v[1],
            ref.a[0], ref.a[1], self.out)
        return ControlCommand(self.out[0:2].copy(), self.out[2:4].copy(), "ok")

    def compiled(self) -> CompiledController:
        return CompiledController(pd_step(), self.prm, self.state, 0)
