"""Controller kinds that go bad, for the graph's rejected-command tests (``test/plugins`` on ``PYTHONPATH``).

``controller.kind: vesselbot_graph_fault_plugin:FaultAfter`` steers as the test plug-in's
:class:`~vesselbot_test_plugin.IntegralController` until ``after_s``, then returns, by ``mode``:
``nan_gradient`` (a NaN gradient; not ``nan``: a ROS parameter file reads that as a float), ``none`` (None),
``raise`` (raises in its step), ``shape`` (a (5,) array),
``array`` (the same gradient as a bare finite ndarray: a command), ``slow`` (the same commands, but late: it
sleeps ``pause_s`` of wall time at ``after_s``, then ``slow_tick_s`` at each of the next ``slow_ticks`` ticks, as a
heavy law or a loaded machine would).  ``RaisingCtor``'s constructor raises.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np
from vesselbot_test_plugin import IntegralController

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.backstepping import ControlCommand

MODES = ("nan_gradient", "none", "raise", "shape", "array", "slow")


@dataclasses.dataclass(frozen=True)
class FaultParams:
    """When and how the controller goes bad, and its gains while it is good."""

    kind: str = "vesselbot_graph_fault_plugin:FaultAfter"
    after_s: float = 0.5
    mode: str = "nan_gradient"
    kp_per_s2: float = 500.0
    kd_per_s: float = 45.0
    ki_per_s3: float = 800.0
    pause_s: float = 0.0
    slow_tick_s: float = 0.0
    slow_ticks: int = 0

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ConfigError(f"mode must be one of {list(MODES)}, got {self.mode!r}")


class FaultAfter(IntegralController):
    """The integral controller until ``after_s``, then a bad return value of its ``mode``."""

    ROLE = "controller"
    Params = FaultParams

    def command(self, t_s: float, estimate: Any, ref: Any) -> Any:
        cmd = super().command(t_s, estimate, ref)
        mode = self.params.mode
        if t_s < self.params.after_s - 1e-12:
            return cmd.gradient_T_per_m.copy() if mode == "array" else cmd
        if mode == "slow":
            k = round((t_s - self.params.after_s) / 1e-3)  # ticks since after_s (the test's 1 kHz loop)
            if k == 0:
                time.sleep(self.params.pause_s)
            elif k <= self.params.slow_ticks:
                time.sleep(self.params.slow_tick_s)
            return cmd
        if mode == "nan_gradient":
            return ControlCommand(np.full(2, np.nan), cmd.u_m_per_s2, "ok")
        if mode == "none":
            return None
        if mode == "raise":
            raise ZeroDivisionError(f"the law divided by zero at t = {t_s:.3f} s")
        if mode == "shape":
            return np.zeros(5)
        return cmd.gradient_T_per_m.copy()


@dataclasses.dataclass(frozen=True)
class RaisingParams:
    """No parameters: the constructor raises."""

    kind: str = "vesselbot_graph_fault_plugin:RaisingCtor"


class RaisingCtor:
    """A controller whose constructor raises (a licence check, a missing file, ...)."""

    ROLE = "controller"
    Params = RaisingParams

    def __init__(self, params: RaisingParams, context: Any) -> None:
        raise RuntimeError("no licence for this coil")

    def command(self, t_s: float, estimate: Any, ref: Any) -> ControlCommand:  # pragma: no cover - never built
        raise AssertionError("never built")
