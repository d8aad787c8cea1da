"""MRI gradient-coil driver node: saturation, slew limit and watchdog on every command.

Thin adapter over :class:`vesselbot_ros.scanner.actuator_limits.CoilLimiter`
(Section III-C: ``U_a = U / k``, ``k = max(1, |U| / U_sat)``, then the slew
limit, lowered by the scenario's ``dbdt:`` limit when that binds), built by
:func:`vesselbot_ros.sim.closed_loop.build_stage`: with a multiplexed
``sequence:`` it is the scanner's
:class:`~vesselbot_ros.scanner.stages.SequencedCoil`, which applies the
command only in propulsion windows (exactly zero in tracking windows and dead
time; saturation, slew and dB/dt hold across window edges), the very stage
the ROS-free runner calls.

Sequence phase: the driver publishes ``scanner/phase``
(vesselbot_msgs/SequencePhase, latched) whenever the phase window of the next
tick differs from the last one published, before that tick's
``coil/applied``; in continuous mode once, at start-up (no per-tick cost).

Ports (frame ``vessel``):

=====================================  ================================  ======================  ==========
port                                   type                              rate                    units
=====================================  ================================  ======================  ==========
in  ``/vesselbot/gradient_command``    geometry_msgs/Vector3Stamped      per tick                T/m
in  ``/vesselbot/coil/stall``          std_msgs/Header                   lockstep: a late tick   s
in  ``/clock``                         rosgraph_msgs/Clock               real time: per tick     s
out ``/vesselbot/coil/applied``        geometry_msgs/Vector3Stamped      per tick (+ watchdog)   T/m
out ``/vesselbot/coil/state``          vesselbot_msgs/CoilState          per tick (+ watchdog)   T/m, T/m/s
out ``/vesselbot/scanner/phase``       vesselbot_msgs/SequencePhase      on phase change         s
out ``/diagnostics``                   diagnostic_msgs/DiagnosticArray   1 Hz wall               counts
=====================================  ================================  ======================  ==========

The output is ALWAYS limited, whatever arrives: every accepted command goes
through ``CoilLimiter.apply``.  A command that is non-finite or malformed
(wrong frame_id, non-zero y in a planar scenario) is *not dropped*: it is passed to the limiter as
non-finite, which rejects it (``command_rejected = true``) and, from that
tick on, ramps the output to zero at the slew limit (the core coil stage's
rule, the very one the ROS-free runner applies: the same ramp as the
watchdog's), where it stays until a valid command comes; it never holds a
stale gradient.  Counted: ``rejected_commands`` (diagnostics) and
``command_rejected`` per tick (``coil/state``, the run's ``cmd_rejected``
series and metrics).  Nothing non-finite is ever published.

Watchdog ("commands stopped"):

* real-time: a sim-time timer at the control rate calls
  ``CoilLimiter.watchdog(now)``, which ramps to zero within the slew limit once
  no command arrived for ``coil.command_timeout_s`` of sim time;
* lockstep: sim time only advances when the driver answers, so silence is
  measured on the wall clock, by the plant, which knows whether a tick is in
  flight or held at its gate (paused, stepping): when ``coil/applied`` of tick
  k has not come within ``graph.stall_timeout_s`` (wall) of announcing k, the
  plant publishes ``coil/stall`` stamped t_k, and the driver answers tick k
  itself with ``CoilLimiter.watchdog(t_k)``: it holds the applied value until
  ``coil.command_timeout_s`` of *sim* time passed without commands, then ramps
  to zero (``watchdog_active = true``).  The loop therefore goes on, and the
  bag shows the ramp (and the requests).  A command arriving later for an
  answered tick is rejected as stale.  Once a tick has been answered by the
  watchdog the commands are *lost*: the plant then waits only
  ``min(graph.stall_timeout_s, LOST_GRACE_S)`` (20 ms wall) per tick, so a dead
  controller costs one stall timeout, not one per tick, and the ramp to zero
  runs at graph speed.  A command that arrives in time for its tick ends the
  lost state.  A controller that is alive but slow (a loaded machine, a heavy
  law) is not locked out by that grace: once the watchdog has answered a tick,
  when a command of any tick came within the last ``graph.stall_timeout_s`` of
  wall time (a request the plant sent early), the driver defers its answer
  to a request by ``graph.stall_timeout_s`` and takes the tick's command if it
  comes meanwhile (counted: ``deferred_stalls``).  A dead or hung controller
  sends nothing, so it is answered at once, as before.  The driver does not
  follow ``/clock`` in lockstep (one delivery and one process wake-up less per
  tick).

``coil/stall`` input checks: a time off the tick grid, a frame other than
``vessel`` or a tick the driver has not reached (``off_tick_stamp``,
``wrong_frame_id``, ``future_tick``) is rejected and moves nothing; a request
for a tick already answered crossed that answer and is ignored.

Real-time ``/clock`` input checks (``VesselbotNode.accept_clock``): an off-grid
time, a time not newer than the last announced tick or a jump far ahead is
rejected (``off_tick_stamp`` / ``stale_stamp`` / ``future_stamp``).
"""

from __future__ import annotations

import math
import sys
import time
from typing import Any

import numpy as np
from geometry_msgs.msg import Vector3Stamped
from std_msgs.msg import Header
from vesselbot_msgs.msg import CoilState, SequencePhase

from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.nodes import conversions as cv
from vesselbot_ros.nodes.base import VesselbotNode
from vesselbot_ros.nodes.process import run_node
from vesselbot_ros.physics.axes import AXES
from vesselbot_ros.scanner.actuator_limits import CoilOutput
from vesselbot_ros.scanner.hardware import dbdt_at
from vesselbot_ros.scanner.sequence import PhaseWindow, duty_cycle, window_at
from vesselbot_ros.sim.closed_loop import build_stage

__all__ = ["CoilDriverNode", "main"]


class CoilDriverNode(VesselbotNode):
    """The gradient-coil driver (see module docstring)."""

    ROLE = "coil_driver"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.ROLE, **kwargs)
        seq = self.scenario.sequence
        self.sequence = seq
        self._multiplexed = seq.mode == "multiplexed"
        self._latency = seq.latency_s if self._multiplexed else self.scenario.imager.latency_s
        self._duty = duty_cycle(seq)
        self._window: PhaseWindow | None = None  # the last phase window published
        self.reset_state()
        self.add_publisher("coil_applied", Vector3Stamped)
        self.add_publisher("coil_state", CoilState)
        self.add_publisher("sequence_phase", SequencePhase)
        self._publish_phase(0)
        self.add_subscription("gradient_command", Vector3Stamped, self._on_command)
        if self.lockstep:  # the plant says when a tick's command is late; real time follows /clock
            self.add_subscription("coil_stall", Header, self._on_stall)
            self._defer_timer = self.create_timer(self.graph.stall_timeout_s, self._deferred_answer, clock=self._wall)
            self._defer_timer.cancel()  # runs while a request waits for a live but slow controller
        self.realtime_clock()

    def reset_state(self) -> None:
        """The coils as built from the scenario (zero output), at tick 0, no command pending.

        After a reset in a multiplexed sequence the phase of tick 0 is published again before its first output.
        """
        self.limiter = build_stage(self.scenario, self.stage)
        self.limits = self.limiter.limits  # in force: the dB/dt limit may have lowered the slew
        dbdt = self.scenario.dbdt
        self._dbdt = ((dbdt_at(dbdt, self.limits.saturation_T_per_m, self.limits.slew_rate_T_per_m_per_s), dbdt.radius_m)
                      if dbdt.mode != "off" else (0.0, 0.0))
        if self._multiplexed and self._window is not None:
            self._window = None
            self._publish_phase(0)
        self.k = 0  # next tick to answer
        self.watchdog_ticks = 0
        self.rejected_commands = 0
        self._t_last = 0.0
        self.commands_lost = False
        self._pending: tuple[int, Any] | None = None  # real time: a command for a tick not yet announced
        self.deferred_stalls = 0
        self._last_command_wall = -math.inf  # lockstep: monotonic time of the last command received (any tick)
        self._deferred: int | None = None  # lockstep: the tick whose watchdog answer waits for a slow controller
        if hasattr(self, "_defer_timer"):
            self._defer_timer.cancel()

    # ------------------------------------------------------------------ inputs
    def _on_stall(self, msg: Header) -> None:
        """Lockstep: the plant waited too long for ``coil/applied`` of the stamped tick: answer it (watchdog)."""
        stamp = cv.ns_of_stamp(msg.stamp)
        k, on_grid = cv.tick_of_ns(stamp, self.dt)
        if not on_grid:
            self.reject("coil_stall", "off_tick_stamp", f"stamp {stamp} ns")
            return
        if not self.check("coil_stall", frame_id=msg.frame_id):
            return
        if k > self.k:
            self.reject("coil_stall", "future_tick", f"tick {k}, driver at {self.k}")
            return
        if k < self.k or self.finished:  # answered already: the request crossed the answer
            return
        if self._deferred == k:  # this tick's answer already waits for a slow controller
            return
        self.count_received("coil_stall")
        if self.watchdog_ticks and time.monotonic() - self._last_command_wall < self.graph.stall_timeout_s:
            # the plant asks early (commands were lost), but the controller is alive, only late: give this tick a
            # full stall timeout before answering it
            self._deferred = k
            self.deferred_stalls += 1
            self._defer_timer.reset()
            return
        self._answer_stall(k)

    def _deferred_answer(self) -> None:
        """Lockstep: a deferred request's stall timeout passed; answer its tick if its command has not come."""
        self._defer_timer.cancel()
        k, self._deferred = self._deferred, None
        if k is not None and k == self.k and not self.finished:
            self._answer_stall(k)

    def _answer_stall(self, k: int) -> None:
        """Lockstep: answer tick ``k`` with the watchdog (hold, then ramp to zero); commands count as lost."""
        self.commands_lost = True
        t = cv.tick_time(k, self.dt)
        out, active = self._watchdog_output(t)
        self.watchdog_ticks += 1
        self.get_logger().warning(
            f"no gradient command for tick {k} within {self.graph.stall_timeout_s} s (wall): "
            + ("ramping to zero" if active else "holding"), throttle_duration_sec=1.0)
        self._emit(k, t, np.zeros(self.dims), out, watchdog=active)

    def _on_command(self, msg: Any) -> None:
        """A gradient command, in its flat form (``Vector3Stamped``: ``header_stamp_sec``, ``vector_x`` ...)."""
        stamp = cv.stamp_ns(msg)
        k, on_grid = cv.tick_of_ns(stamp, self.dt)
        if not on_grid:
            self.reject("gradient_command", "off_tick_stamp", f"stamp {stamp} ns")
            return
        self.note_input_tick("gradient_command", k)  # the controller's last command, if it dies (the launcher)
        self._last_command_wall = time.monotonic()
        if self.lockstep and k != self.k:
            self.reject("gradient_command", "stale_tick" if k < self.k else "future_tick", f"tick {k}, driver at {self.k}")
            return
        if not self.lockstep and k > self.tick_now:
            # never take time from a stamp beyond the plant's announced tick
            if k > self.tick_now + self._future_ticks:
                self.reject("gradient_command", "future_stamp", f"tick {k}, plant announced {self.tick_now}")
            else:  # a little early (the /clock is on its way): apply it when its tick is announced
                self._pending = (k, msg)
            return
        self._apply(k, msg, stamp)

    def _apply(self, k: int, msg: Any, stamp: int) -> None:
        if not self.lockstep and cv.tick_time(k, self.dt) < self._t_last:
            self.reject("gradient_command", "stale_stamp", f"stamp {stamp} ns older than the last applied")
            return
        x, y, z = msg.vector_x, msg.vector_y, msg.vector_z
        ok = self.check("gradient_command", frame_id=msg.header_frame_id_cdr, stamp_ns=stamp, values=(x, y, z),
                        y_values=(y,))
        # malformed -> the limiter's reject rule, never dropped
        g = cv.vector_array(x, y, z, self.dims) if ok else np.full(self.dims, np.nan)
        if ok:
            self.count_received("gradient_command")
        self.commands_lost = False
        t = cv.tick_time(k, self.dt)
        try:
            out = self.limiter.apply(t, g)
        except ModelInputError as exc:  # e.g. a time before the limiter's last output: never crash
            self.reject("gradient_command", "stale_stamp", str(exc))
            return
        self.rejected_commands += int(out.rejected)
        self._emit(k, t, g if ok else np.zeros(self.dims), out, watchdog=False)

    # ------------------------------------------------------------------ outputs
    def _publish_phase(self, k: int) -> None:
        """Publish the phase window of tick ``k`` if it is not the one last published (continuous: only once)."""
        if self._window is not None and not self._multiplexed:
            return
        t = cv.tick_time(k, self.dt)
        w = window_at(self.sequence, t)
        if self._window is not None and (w.phase, w.index) == (self._window.phase, self._window.index):
            return
        self._window = w
        self.publish("sequence_phase", cv.sequence_phase_msg(t, w, self._latency, self._duty))

    def _emit(self, k: int, t: float, commanded: np.ndarray, out: CoilOutput, watchdog: bool) -> None:
        self._t_last = t
        if self._multiplexed and k + 1 < self.n_ticks:
            self._publish_phase(k + 1)  # the phase of the next tick, before anything of that tick
        self.publish("coil_applied", cv.gradient_flat(t, out.applied, self.dims))
        # what was commanded (zero for a rejected command or a watchdog tick: never a non-finite value)
        cmd = commanded if all(map(math.isfinite, commanded)) else np.zeros(self.dims)
        self.publish("coil_state", cv.coil_state_flat(k, t, cmd, out, self.limits, watchdog, *self._dbdt, self.dims))
        self.period_done(k)
        if self.lockstep:
            self.k = k + 1
            if self._deferred is not None:  # the deferred tick's command came in time
                self._deferred = None
                self._defer_timer.cancel()
            if self.k >= self.n_ticks:
                self.mark_finished()

    def _watchdog_output(self, t: float) -> tuple[CoilOutput, bool]:
        out = self.limiter.watchdog(t)
        if out is None:  # within command_timeout_s: hold (and the next command slews from this tick, not before)
            return self.limiter.hold(t), False
        return out, True

    def on_realtime_tick(self, k: int) -> None:
        """Real time, tick ``k`` announced: apply an early command now due, else run the watchdog at t_k."""
        if self._pending is not None and self._pending[0] <= k:
            kp, msg = self._pending
            self._pending = None
            self._apply(kp, msg, cv.stamp_ns(msg))
        t = cv.tick_time(k, self.dt)
        if t <= self._t_last:
            return
        out = self.limiter.watchdog(t)
        if out is not None:
            self.watchdog_ticks += 1
            self._emit(k, t, np.zeros(self.dims), out, watchdog=True)

    def diagnostic_values(self) -> dict[str, str]:
        return {
            "tick": str(self.k - 1),
            "watchdog_ticks": str(self.watchdog_ticks),
            "deferred_stalls": str(self.deferred_stalls),
            "rejected_commands": str(self.rejected_commands),
            "commands_lost": "true" if self.commands_lost else "false",
        } | {f"applied_{axis}_T_per_m": repr(float(g))
             for axis, g in zip(AXES[self.dims], self.limiter.applied, strict=True)}


def main(argv: list[str] | None = None) -> int:
    """Console script ``vesselbot_coil_driver``."""
    return run_node(CoilDriverNode, argv, exit_process=True)


if __name__ == "__main__":
    sys.exit(main())
