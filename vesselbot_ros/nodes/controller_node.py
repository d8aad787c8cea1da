"""Controller node: gradient command from the estimate and the reference.

Thin adapter over the scenario's controller kind (``controller.kind``: the
backstepping law (24) of :class:`vesselbot_ros.control.backstepping.BacksteppingController`
by default, or a user's ``module:Class``), built by
:func:`vesselbot_ros.sim.closed_loop.build_stage` and called through
:func:`vesselbot_ros.sim.kinds.call_controller`, as the ROS-free loop calls it.

Ports (frame ``vessel``):

=================================  ===================================  =========  =================
port                               type                                 rate       units
=================================  ===================================  =========  =================
in  ``/vesselbot/estimate``        nav_msgs/Odometry                    per tick   m, m/s, age s, s_hat
in  ``/vesselbot/reference``       vesselbot_msgs/ReferenceSample       per tick   m, m/s, m/s^2
out ``/vesselbot/gradient_command`` geometry_msgs/Vector3Stamped        per tick   T/m
out ``/diagnostics``               diagnostic_msgs/DiagnosticArray      1 Hz wall  status counts
=================================  ===================================  =========  =================

Lockstep: tick k is computed once ``estimate`` k and ``reference`` k are in;
the command is stamped t_k.  Real-time: every estimate triggers a command with
the latest reference sample (stamp = the estimate's).

Input checks: wrong frame_id, non-finite, non-zero y (planar scenarios), positions outside the
vessel (+ margin), off-grid or stale/future ticks (lockstep) or stamps
(real-time) are rejected (WARN diagnostics).  In lockstep a rejected input
leaves its tick open; the coil driver's watchdog then keeps the loop going.
The core's safe actions (``stale``: estimate too old; ``nonfinite``: the law
diverged) are counted in diagnostics (``status:<name>``).
"""

from __future__ import annotations

import sys
from collections import Counter
from typing import Any

from geometry_msgs.msg import Vector3Stamped
from nav_msgs.msg import Odometry
from vesselbot_msgs.msg import ReferenceSample

from vesselbot_ros.nodes import conversions as cv
from vesselbot_ros.nodes.base import VesselbotNode
from vesselbot_ros.nodes.process import run_node
from vesselbot_ros.nodes.tick_join import TickJoin
from vesselbot_ros.sim.closed_loop import build_stage
from vesselbot_ros.sim.kinds import call_controller

__all__ = ["ControllerNode", "main"]


class ControllerNode(VesselbotNode):
    """The scenario's controller (see module docstring)."""

    ROLE = "controller"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.ROLE, **kwargs)
        self.reset_state()
        self.add_publisher("gradient_command", Vector3Stamped)
        self.add_subscription("estimate", Odometry, self._on_estimate)
        self.add_subscription("reference", ReferenceSample, self._on_reference)
        self.realtime_clock()

    def reset_state(self) -> None:
        """The controller as built from the scenario, at tick 0."""
        self.controller = build_stage(self.scenario, self.stage)
        self.join = TickJoin(self, {"estimate": 0, "reference": 0})
        self._ref_latest: Any = None
        self.status: Counter[str] = Counter()

    def _on_estimate(self, msg: Any) -> None:
        """An estimate, in its flat form (``Odometry``: ``pose_pose_position_x`` ...)."""
        x, z, age = cv.estimate_arrays(msg, self.dims)
        flow_scale = cv.estimate_flow_scale(msg)
        px, py, pz = msg.pose_pose_position_x, msg.pose_pose_position_y, msg.pose_pose_position_z
        vy = msg.twist_twist_linear_y
        stamp = cv.stamp_ns(msg)
        if not self.check("estimate", frame_id=msg.header_frame_id_cdr, stamp_ns=stamp,
                          values=(px, py, pz, msg.twist_twist_linear_x, vy, msg.twist_twist_linear_z, age),
                          y_values=(py, vy), z_position=pz, x_position=px, y_position=py):
            return
        k = self.join.tick_of("estimate", stamp)
        if k is None:
            return
        if self.lockstep:
            if self.join.put("estimate", k, (x, z, age, flow_scale)):
                self.count_received("estimate")
                self._drain()
            return
        self.count_received("estimate")
        if self._ref_latest is not None:
            self._command(k, (x, z, age, flow_scale), self._ref_latest)

    def _on_reference(self, msg: Any) -> None:
        """A reference sample, in its flat form (``ReferenceSample``: ``tick``, ``position_x`` ...)."""
        p, v, a = cv.reference_arrays(msg, self.dims)
        stamp = cv.stamp_ns(msg)
        vals = (msg.position_x, msg.position_y, msg.position_z, msg.velocity_x, msg.velocity_y, msg.velocity_z,
                msg.acceleration_x, msg.acceleration_y, msg.acceleration_z)
        if not self.check("reference", frame_id=msg.header_frame_id_cdr, stamp_ns=stamp, values=vals,
                          y_values=(msg.position_y, msg.velocity_y, msg.acceleration_y), z_position=msg.position_z,
                          x_position=msg.position_x, y_position=msg.position_y):
            return
        k = self.join.tick_of("reference", stamp, int(msg.tick))
        if k is None:
            return
        if self.lockstep:
            if self.join.put("reference", k, (p, v, a)):
                self.count_received("reference")
                self._drain()
            return
        self.count_received("reference")
        self._ref_latest = (p, v, a)

    def _command(self, k: int, est: tuple[Any, Any, float, float], ref: tuple[Any, Any, Any]) -> None:
        t = cv.tick_time(k, self.dt)
        # the estimate as the runner hands it, with the observer's blood-velocity scale
        cmd = call_controller(self.controller, t, est[0], est[1], est[2], est[3], *ref)
        self.status[cmd.status] += 1
        self.publish("gradient_command", cv.gradient_flat(t, cmd.gradient_T_per_m, self.dims))
        self.period_done(k)

    def _drain(self) -> None:
        while (inputs := self.join.pop_ready()) is not None:
            self._command(self.join.k - 1, inputs["estimate"], inputs["reference"])
            if self.join.k >= self.n_ticks:
                self.mark_finished()

    def diagnostic_values(self) -> dict[str, str]:
        out = {"tick": str(self.join.k - 1)}
        out.update({f"status:{s}": str(self.status[s]) for s in ("ok", "stale", "nonfinite")})
        return out


def main(argv: list[str] | None = None) -> int:
    """Console script ``vesselbot_controller``."""
    return run_node(ControllerNode, argv, exit_process=True)


if __name__ == "__main__":
    sys.exit(main())
