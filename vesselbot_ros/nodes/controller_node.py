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

What the controller returns is checked before it is published, by the core's
:func:`~vesselbot_ros.sim.kinds.checked_command`, the very check the ROS-free
runner makes (so a lockstep run stays bit for bit the runner's): a
non-finite gradient, a controller that raised in its step, a return value
that is not a command (``None``, a wrong shape, an unknown status) and a
non-finite estimate (an observer that diverged: the estimate is counted as a
rejected input, ``rejected_reason:non_finite``, yet its tick is answered,
the controller not called) are *rejected commands*: counted
(``status:nonfinite``, ``rejected_commands``, ``command_rejected:<reason>``,
the first one's tick and, for a raise or a malformed value, its text) and
warned (WARN diagnostics, a log line at most once per second).  The node
still publishes the tick's command, as the core hands it over (the
controller's own non-finite values, else NaN): nothing is dropped, so the
bag holds every command the loop ran on and the tick does not wait for the
driver's watchdog; the coil driver rejects it (``command_rejected``) and,
through the same coil stage as the runner, ramps the gradient to zero at the
slew limit, until a valid command comes.  A finite bare array of the right
shape is a command, as in the runner.
"""

from __future__ import annotations

import math
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
from vesselbot_ros.sim.kinds import (
    REJECT_ESTIMATE,
    REJECT_MALFORMED,
    REJECT_NONFINITE,
    REJECT_RAISED,
    checked_command,
)

__all__ = ["ControllerNode", "REJECT_NAMES", "main"]

#: Diagnostic names of the core's rejection codes (``command_rejected:<name>``).
REJECT_NAMES: dict[int, str] = {REJECT_NONFINITE: "nonfinite", REJECT_ESTIMATE: "nonfinite_estimate",
                                REJECT_RAISED: "raised", REJECT_MALFORMED: "malformed"}


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
        self.rejected: Counter[int] = Counter()  # rejected commands by the core's code
        self.first_rejected_tick: int | None = None
        self.reject_details: dict[int, str] = {}  # the first detail of each code

    def _on_estimate(self, msg: Any) -> None:
        """An estimate, in its flat form (``Odometry``: ``pose_pose_position_x`` ...)."""
        x, z, age = cv.estimate_arrays(msg, self.dims)
        flow_scale = cv.estimate_flow_scale(msg)
        px, py, pz = msg.pose_pose_position_x, msg.pose_pose_position_y, msg.pose_pose_position_z
        vy = msg.twist_twist_linear_y
        stamp = cv.stamp_ns(msg)
        state = (px, py, pz, msg.twist_twist_linear_x, vy, msg.twist_twist_linear_z)
        finite = all(map(math.isfinite, state))
        if finite and not self.check("estimate", frame_id=msg.header_frame_id_cdr, stamp_ns=stamp,
                                     values=(*state, age), y_values=(py, vy), z_position=pz, x_position=px,
                                     y_position=py):
            return
        if not finite:
            # the observer diverged: a rejected input (counted, WARN), yet, when it is the estimate of a tick
            # still open, that tick is answered with a rejected command (the runner's REJECT_ESTIMATE: the coil
            # ramps to zero now, instead of the driver's watchdog holding the last gradient first)
            if not self.check("estimate", frame_id=msg.header_frame_id_cdr, stamp_ns=stamp, values=(age,)):
                return
            k_bad, on_grid = cv.tick_of_ns(stamp, self.dt)
            answer = on_grid and (not self.lockstep or self.join.fits("estimate", k_bad))
            self.reject("estimate", "non_finite", f"values {list(state)}"
                        + ("; the tick's command is rejected" if answer else ""))
            if not answer:
                return
        k = self.join.tick_of("estimate", stamp)
        if k is None:
            return
        self.note_input_tick("estimate", k)
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
        self.note_input_tick("reference", k)
        if self.lockstep:
            if self.join.put("reference", k, (p, v, a)):
                self.count_received("reference")
                self._drain()
            return
        self.count_received("reference")
        self._ref_latest = (p, v, a)

    def _command(self, k: int, est: tuple[Any, Any, float, float], ref: tuple[Any, Any, Any]) -> None:
        t = cv.tick_time(k, self.dt)
        # the estimate as the runner hands it, with the observer's blood-velocity scale; the runner's check of
        # what came back (a rejected command comes with the controller's non-finite values, else NaN)
        cmd, why, detail = checked_command(self.controller, t, est[0], est[1], est[2], est[3], *ref, self.dims)
        self.status[cmd.status] += 1
        if why:
            self._count_rejected(k, why, detail)
        self.publish("gradient_command", cv.gradient_flat(t, cmd.gradient_T_per_m, self.dims))
        self.period_done(k)

    def _count_rejected(self, k: int, why: int, detail: str) -> None:
        """Count a rejected command of tick ``k`` (the core's code ``why``) and warn (rate-limited)."""
        self.rejected[why] += 1
        if self.first_rejected_tick is None:
            self.first_rejected_tick = k
        self.reject_details.setdefault(why, detail)
        self.flag_output("gradient_command", REJECT_NAMES.get(why, str(why)),
                         f"tick {k}: {detail}; the coil driver rejects it and ramps to zero")

    def _drain(self) -> None:
        while (inputs := self.join.pop_ready()) is not None:
            self._command(self.join.k - 1, inputs["estimate"], inputs["reference"])
            if self.join.k >= self.n_ticks:
                self.mark_finished()

    def diagnostic_values(self) -> dict[str, str]:
        out = {"tick": str(self.join.k - 1)}
        out.update({f"status:{s}": str(self.status[s]) for s in ("ok", "stale", "nonfinite")})
        out["rejected_commands"] = str(sum(self.rejected.values()))
        out.update({f"command_rejected:{name}": str(self.rejected[code]) for code, name in REJECT_NAMES.items()})
        if self.first_rejected_tick is not None:
            out["first_rejected_command_tick"] = str(self.first_rejected_tick)
        for code, key in ((REJECT_RAISED, "rejected_command_error"), (REJECT_MALFORMED, "rejected_command_malformed")):
            if code in self.reject_details:
                out[key] = self.reject_details[code]
        return out


def main(argv: list[str] | None = None) -> int:
    """Console script ``vesselbot_controller``."""
    return run_node(ControllerNode, argv, exit_process=True)


if __name__ == "__main__":
    sys.exit(main())
