"""A stage kind kept outside the package, for the tests: it must run by name in simulate, campaign and run.

``controller.kind: vesselbot_test_plugin:IntegralController`` (with ``test/plugins``
on ``PYTHONPATH``).  The law carries state from tick to tick (an integral of
the position error), so a runner that rebuilt it, skipped a tick or called it
twice would change the numbers, and the tests compare them bit for bit.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.backstepping import ControlCommand


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
