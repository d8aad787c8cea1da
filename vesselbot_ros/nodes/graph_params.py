"""How the node graph runs: the ``graph.*`` ROS parameters every node declares (:class:`GraphParams`).

Kept apart from the node base so that the launcher can build and check the
graph settings without loading rclpy's node machinery.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

from vesselbot_ros.config import check_choice, check_nonnegative, check_positive

__all__ = ["GRAPH_PREFIX", "GraphParams"]

#: Prefix of the graph settings among a node's ROS parameters (``graph.mode``, ...).
GRAPH_PREFIX = "graph."


@dataclasses.dataclass(frozen=True)
class GraphParams:
    """How the node graph runs (ROS parameters ``graph.*``, same for every node).

    Attributes:
        mode: ``lockstep`` (deterministic, as fast as the graph allows) or
            ``realtime`` (the plant steps on the wall clock).
        real_time_factor: Sim seconds per wall second in real-time mode.
        autostart: If true the plant starts stepping by itself once its own
            publishers are matched; otherwise it waits for RunControl START.
        diagnostics_period_s: Wall-clock period of ``/diagnostics`` (s).
        stall_timeout_s: Lockstep only: wall time the coil driver waits for the
            command of the current tick before treating it as missing (its
            watchdog then runs, so the loop goes on) (s).
        plant_wait_warn_s: Lockstep only: wall time after which the plant warns
            that it is still waiting for ``coil/applied`` (s).
        input_max_age_s: Real-time only: inputs stamped older than this (sim
            s, on top of the imager latency for measurements) are stale.
        future_tolerance_s: Real-time only: inputs stamped later than now plus
            this (sim s) are rejected as future.
        position_margin_m: Positions farther than this outside the nominal
            vessel walls are rejected (m); generous, so that scheduled imager
            outliers still reach the observer as in the paper.
    """

    mode: Literal["lockstep", "realtime"] = "lockstep"
    real_time_factor: float = 1.0
    autostart: bool = False
    diagnostics_period_s: float = 1.0
    stall_timeout_s: float = 2.0
    plant_wait_warn_s: float = 5.0
    input_max_age_s: float = 0.25
    future_tolerance_s: float = 0.005
    position_margin_m: float = 0.005

    def __post_init__(self) -> None:
        check_choice("mode", self.mode, ("lockstep", "realtime"))
        check_positive("real_time_factor", self.real_time_factor)
        check_positive("diagnostics_period_s", self.diagnostics_period_s)
        check_positive("stall_timeout_s", self.stall_timeout_s)
        check_positive("plant_wait_warn_s", self.plant_wait_warn_s)
        check_positive("input_max_age_s", self.input_max_age_s)
        check_nonnegative("future_tolerance_s", self.future_tolerance_s)
        check_nonnegative("position_margin_m", self.position_margin_m)

