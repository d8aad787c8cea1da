"""High-gain observer node: position and velocity from imager frames and the applied gradient.

Thin adapter over :class:`vesselbot_ros.control.high_gain_observer.HighGainObserver`
(eq. (25)), built by :func:`vesselbot_ros.sim.closed_loop.build_stage`.

Ports (frame ``vessel``):

================================  ================================  ========================  ===============
port                              type                              rate                      units
================================  ================================  ========================  ===============
in  ``/vesselbot/measurement``    geometry_msgs/PointStamped        per tick / frames         m
in  ``/vesselbot/coil/applied``   geometry_msgs/Vector3Stamped      per tick                  T/m
out ``/vesselbot/estimate``       nav_msgs/Odometry                 per tick                  m, m/s
out ``/diagnostics``              diagnostic_msgs/DiagnosticArray   1 Hz wall                 counts
================================  ================================  ========================  ===============

``estimate``: stamp t_k, ``pose.pose.position`` = x_hat (m), ``twist.twist.linear``
= z_hat (m/s), ``pose.covariance[35]`` = age of the last used measurement (s)
(see :mod:`vesselbot_ros.nodes.conversions`).

Lockstep: the n-th ``measurement`` message belongs to tick n (the imager sends
exactly one per tick).  Tick k is processed once ``measurement`` k and
``coil/applied`` k-1 are in (k = 0 needs no applied: zero, as the runner): the
measurement is passed to the core only if its stamp is newer than the last
one passed (fresh frame), else None (zero-order hold); an empty frame_id is
the imager's "no frame yet" placeholder.

Real-time: on each tick the plant announces (its ``/clock``, validated) the
observer publishes one estimate for that tick; a fresh measurement arriving
during the tick corrects the state at once, and the correction goes out with
the next tick's estimate (one estimate per tick: no duplicate traffic
downstream).  The latest ``coil/applied`` is the input.

Measurement loss: the observer never stops publishing; without fresh frames
it predicts with its model (eq. (25) with no correction).  When the time since
the last used measurement exceeds ``lost_after_s`` = 2 frame periods + the
imager latency (at least 2 ticks), the loss is flagged at once on
``/diagnostics`` (``measurement_lost: true``, ``measurement_age_s``,
``measurement_losses`` = number of loss episodes) and cleared on the next used
frame.  Downstream, ``pose.covariance[35]`` carries the age, which the
controller's stale-estimate safe behaviour reads.

Input checks: wrong frame_id, non-finite, non-zero y (planar scenarios), measured position
farther than ``graph.position_margin_m`` outside the vessel, off-grid or
stale/future ticks (lockstep) or stamps (real-time), and (lockstep) an
acquisition stamp after the tick the message belongs to (``future_stamp``):
rejected (WARN diagnostics).  In lockstep a rejected measurement still closes its tick (as
"no fresh frame"), so the loop never stalls on bad input.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
from geometry_msgs.msg import PointStamped, Vector3Stamped
from nav_msgs.msg import Odometry

from vesselbot_ros.nodes import conversions as cv
from vesselbot_ros.nodes.base import VesselbotNode
from vesselbot_ros.nodes.process import run_node
from vesselbot_ros.nodes.tick_join import TickJoin
from vesselbot_ros.scanner.imager_model import Measurement
from vesselbot_ros.sim.closed_loop import build_stage

__all__ = ["ObserverNode", "main"]

_NO_FRAME = object()
#: An empty ``header.frame_id`` as a flat form holds it (the imager's "no frame yet" placeholder)
_EMPTY_CDR = b"\0"


class ObserverNode(VesselbotNode):
    """The high-gain observer (see module docstring)."""

    ROLE = "observer"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.ROLE, **kwargs)
        im = self.scenario.imager
        self.lost_after_s = max(2.0 / im.frame_rate_Hz, 2.0 * self.dt) + im.latency_s
        self.reset_state()
        self.add_publisher("estimate", Odometry)
        self.add_subscription("measurement", PointStamped, self._on_measurement)
        self.add_subscription("coil_applied", Vector3Stamped, self._on_applied)
        self.realtime_clock()

    def reset_state(self) -> None:
        """The observer as built from the scenario, at tick 0 with no input yet."""
        self.observer = build_stage(self.scenario, self.stage)
        self.model = self.observer.model
        # lockstep: tick k needs measurement k (the k-th message) and coil/applied k-1
        self.join = TickJoin(self, {"measurement": 0, "coil_applied": 1}, windows={"measurement": None, "coil_applied": 3})
        self.n_meas = 0  # measurement messages received (lockstep: = ticks)
        self._last_stamp_ns = -1
        self._g_prev = np.zeros(self.dims)
        self.used = 0
        self.rejected_by_core = 0
        self.measurement_age_s = float("inf")
        self.measurement_lost = False
        self.measurement_losses = 0
        self._t_last = 0.0

    # ------------------------------------------------------------------ inputs
    def _parse_measurement(self, msg: Any) -> Any:
        """A Measurement, _NO_FRAME (placeholder / not fresh) or None (rejected); ``msg`` in its flat form."""
        if msg.header_frame_id_cdr == _EMPTY_CDR and msg.header_stamp_sec == 0 and msg.header_stamp_nanosec == 0:
            return _NO_FRAME
        x, y, z = msg.point_x, msg.point_y, msg.point_z
        stamp = cv.stamp_ns(msg)
        if not self.check("measurement", frame_id=msg.header_frame_id_cdr, stamp_ns=stamp, values=(x, y, z),
                          y_values=(y,), z_position=z, x_position=x, y_position=y,
                          extra_age_s=self.scenario.imager.latency_s):
            return None
        j, on_grid = cv.tick_of_ns(stamp, self.dt)
        if not on_grid:
            self.reject("measurement", "off_tick_stamp", f"acquisition stamp {stamp} ns is not a tick time")
            return None
        if self.lockstep and j > self.n_meas:
            # the n-th measurement belongs to tick n: a frame acquired after that tick comes from the future
            self.reject("measurement", "future_stamp", f"acquisition tick {j} after the current tick {self.n_meas}")
            return None
        if stamp <= self._last_stamp_ns:
            if self.lockstep and stamp == self._last_stamp_ns:
                return _NO_FRAME  # zero-order hold: the same frame again
            self.reject("measurement", "stale_stamp", f"frame stamp {stamp} ns not newer than {self._last_stamp_ns} ns")
            return None
        self._last_stamp_ns = stamp
        return Measurement(cv.tick_time(j, self.dt), cv.vector_array(x, y, z, self.dims), False)

    def _on_measurement(self, msg: Any) -> None:
        meas = self._parse_measurement(msg)
        if meas is not None:
            self.count_received("measurement")
        if self.lockstep:
            self.note_input_tick("measurement", self.n_meas)  # the imager's message of tick n_meas
            self.join.put("measurement", self.n_meas, meas if isinstance(meas, Measurement) else None)
            self.n_meas += 1
            self._drain()
        elif isinstance(meas, Measurement):
            self._update_now(meas)

    def _on_applied(self, msg: Any) -> None:
        """The applied gradient, in its flat form (``Vector3Stamped``)."""
        x, y, z = msg.vector_x, msg.vector_y, msg.vector_z
        stamp = cv.stamp_ns(msg)
        if not self.check("coil_applied", frame_id=msg.header_frame_id_cdr, stamp_ns=stamp, values=(x, y, z),
                          y_values=(y,)):
            return
        k = self.join.tick_of("coil_applied", stamp)
        if k is None:
            return
        if not self.lockstep:
            self.count_received("coil_applied")
            self._g_prev = cv.vector_array(x, y, z, self.dims)
            return
        if self.join.put("coil_applied", k, cv.vector_array(x, y, z, self.dims)):
            self.count_received("coil_applied")
            self._drain()

    # ------------------------------------------------------------------ updates
    def _drain(self) -> None:
        while (inputs := self.join.pop_ready()) is not None:
            k = self.join.k - 1
            g_prev = np.zeros(self.dims) if inputs["coil_applied"] is None else inputs["coil_applied"]
            self._publish(self.observer.update(cv.tick_time(k, self.dt), inputs["measurement"], g_prev))
            self.period_done(k)
            if self.join.k >= self.n_ticks:
                self.mark_finished()

    def _publish(self, est: Any) -> None:
        self._t_last = est.t_s
        self.used += int(est.used_measurement)
        self.rejected_by_core += int(est.rejected)
        self.publish("estimate", cv.estimate_flat(est.t_s, est.x_hat, est.z_hat, est.time_since_measurement_s,
                                                  getattr(est, "flow_scale", 1.0), self.dims))
        self.measurement_age_s = float(est.time_since_measurement_s)
        lost = est.t_s > self.lost_after_s and self.measurement_age_s > self.lost_after_s + 1e-9
        if lost != self.measurement_lost:
            self.measurement_lost = lost
            self.measurement_losses += int(lost)
            if lost:
                self.get_logger().warning(f"no measurement for {self.measurement_age_s:.4f} s at t = {est.t_s:.4f} s: "
                                          "predicting without correction")
            self.publish_diagnostics()

    def _update_now(self, meas: Measurement | None) -> None:
        """Real time: update at the plant's announced tick (never backwards, never beyond it).

        One estimate per tick: the tick's own estimate is published when the
        tick is announced; a fresh frame arriving later in the tick corrects the
        state, and the correction goes out with the next tick's estimate.
        """
        if self.tick_now < 0:
            return
        t = max(cv.tick_time(self.tick_now, self.dt), self._t_last)
        est = self.observer.update(t, meas, self._g_prev)
        if t > self._t_last or self.period_tick < self.tick_now:
            self._publish(est)
            self.period_done(self.tick_now)
        else:
            self.used += int(est.used_measurement)
            self.rejected_by_core += int(est.rejected)

    def on_realtime_tick(self, k: int) -> None:
        if cv.tick_time(k, self.dt) > self._t_last:
            self._update_now(None)

    def diagnostic_values(self) -> dict[str, str]:
        return {
            "tick": str(self.join.k - 1),
            "measurements_used": str(self.used),
            "measurements_rejected": str(self.rejected_by_core),
            "observer_rhs_evals": str(int(self.model.stats[2])),
            "measurement_lost": "true" if self.measurement_lost else "false",
            "measurement_age_s": repr(self.measurement_age_s),
            "measurement_losses": str(self.measurement_losses),
        }


def main(argv: list[str] | None = None) -> int:
    """Console script ``vesselbot_observer``."""
    return run_node(ObserverNode, argv, exit_process=True)


if __name__ == "__main__":
    sys.exit(main())
