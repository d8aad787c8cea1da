"""MRI imager node: noisy position frames at a frame rate, with latency, outliers and dropouts.

Thin adapter over :class:`vesselbot_ros.scanner.imager_model.ImagerModel`,
seeded with ``numpy.random.default_rng(seed)`` exactly as the pure runner.

Ports (frame ``vessel``):

=============================  ================================  ===============================  =====
port                           type                              rate                             units
=============================  ================================  ===============================  =====
in  ``/vesselbot/truth``       vesselbot_msgs/PlantState         per tick                         m
out ``/vesselbot/measurement`` geometry_msgs/PointStamped        per tick (lockstep) / frames     m
srv ``imager/inject_fault``    vesselbot_msgs/InjectFault        on demand                        s, m
out ``/diagnostics``           diagnostic_msgs/DiagnosticArray   1 Hz wall                        frames, outliers
=============================  ================================  ===============================  =====

Measurement stamp = the frame's *acquisition* time (s); ``point`` = measured
position (y = 0 in a planar scenario; a 3-D tree's frames are noisy in y too).  Lockstep: exactly one message per truth tick: the frame
delivered at t_k, else the last delivered frame again (same stamp: consumers
see it is not fresh).  Before the first frame is ever delivered (latency, or a
dropout at t = 0) the placeholder has an *empty* ``frame_id`` and stamp 0:
"no frame yet".  Real-time: only delivered frames are published.

InjectFault: ``OUTLIER_BURST`` / ``DROPOUT`` at ``start_time`` (s, sim; < 0 =
the next tick) for ``duration`` (s) with ``magnitude`` (m, outliers only);
invalid values are refused (``accepted = false`` and the reason).

Fault reporting: every fault, injected through the service or scheduled in the
scenario (``imager.outliers`` / ``imager.dropouts``), is announced on
``/diagnostics`` at once when it is accepted (injected) or when its start tick
is reached (scheduled), with the KeyValues ``fault_kind`` (``outlier_burst`` /
``dropout``), ``fault_start`` (s, sim), ``fault_duration`` (s),
``fault_magnitude`` (m, 0 for a dropout), ``fault_source`` (``service`` /
``schedule``), plus the running counts ``faults_announced``,
``outlier_frames`` (frames delivered with an outlier) and ``dropout_frames``
(ticks inside a dropout window).  ``vesselbot report`` shades these intervals.

MR frames (``imager.kind: mr_images``): the imager publishes no measurement but its frames, for the tracker
node: ``imager/frame`` (``sensor_msgs/Image``, 64FC2 complex samples, stamp = acquisition time; lockstep: once
per tick, an empty image stamped t_k when no frame is delivered) and their magnitude on ``imager/image`` (32FC1,
on each frame, for viewers).  It takes no injected faults (``inject_fault`` refuses them, saying so).

Input checks: a truth message with a wrong frame_id, non-finite numbers,
non-zero y (planar scenarios), a position outside the vessel (+ ``graph.position_margin_m``), a
stale/future tick (lockstep) or stamp (real-time) is rejected; no frame is
taken from it.
"""

from __future__ import annotations

import sys
from typing import Any

from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import Image
from vesselbot_msgs.msg import PlantState
from vesselbot_msgs.srv import InjectFault

from vesselbot_ros.config import ConfigError
from vesselbot_ros.imaging.frames import frame_samples_of
from vesselbot_ros.nodes import conversions as cv
from vesselbot_ros.nodes.base import VesselbotNode
from vesselbot_ros.nodes.process import run_node
from vesselbot_ros.sim.closed_loop import build_stage
from vesselbot_ros.sim.kinds import delivers_frames

__all__ = ["ImagerNode", "main"]


class ImagerNode(VesselbotNode):
    """The imager (see module docstring)."""

    ROLE = "imager"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.ROLE, **kwargs)
        self.dt = self.scenario.sim.dt_control_s
        self.reset_state()
        self._windows: list[tuple[float, float]] = [(d.start_s, d.start_s + d.duration_s)
                                                    for d in self.scenario.imager.dropouts]
        self._scheduled = sorted(
            [("outlier_burst", o.start_s, o.duration_s, o.magnitude_m) for o in self.scenario.imager.outliers]
            + [("dropout", d.start_s, d.duration_s, 0.0) for d in self.scenario.imager.dropouts],
            key=lambda f: f[1])
        self.frames_mode = delivers_frames(self.scenario)
        if self.frames_mode:
            self.add_publisher("mr_frame", Image)
            self.add_publisher("mr_image", Image)
        else:
            self.add_publisher("measurement", PointStamped)
        self.add_subscription("truth", PlantState, self._on_truth)
        self.add_service("inject_fault", InjectFault, self._on_inject)
        self.realtime_clock()

    def reset_state(self) -> None:
        """The imager as built from the scenario (its noise generator seeded again), no frame yet, no injected fault."""
        self.imager = build_stage(self.scenario, self.stage)
        self.k_next = 0
        self._last_msg: Any = None  # the last frame published (flat form)
        self.frames = 0
        self.outlier_frames = 0
        self.dropout_frames = 0
        # (kind, start_s, duration_s, magnitude_m, source), in announcement order
        self._faults: list[tuple[str, float, float, float, str]] = []

    def _on_truth(self, msg: Any) -> None:
        """The plant's truth, in its flat form (``PlantState``: ``tick``, ``position_x`` ...)."""
        x, y, z = msg.position_x, msg.position_y, msg.position_z
        stamp = cv.stamp_ns(msg)
        if not self.check("truth", frame_id=msg.header_frame_id_cdr, stamp_ns=stamp, values=(x, y, z),
                          y_values=(y,), z_position=z, x_position=x, y_position=y):
            return
        k = msg.tick
        if cv.ns_of_time(cv.tick_time(k, self.dt)) != stamp:
            self.reject("truth", "stamp_tick_mismatch", f"tick {k} but stamp {stamp} ns")
            return
        if k < self.k_next or (self.lockstep and k != self.k_next):
            self.reject("truth", "stale_tick" if k < self.k_next else "future_tick", f"tick {k}, expected {self.k_next}")
            return
        self.count_received("truth")
        self.k_next = k + 1
        t_k = cv.tick_time(k, self.dt)
        while self._scheduled and self._scheduled[0][1] <= t_k + 0.5 * self.dt:
            kind, start, duration, magnitude = self._scheduled.pop(0)
            self._announce(kind, start, duration, magnitude, "schedule")
        if any(a - 1e-9 <= t_k < b - 1e-9 for a, b in self._windows):
            self.dropout_frames += 1
        meas = self.imager.frame(t_k, cv.vector_array(x, y, z, self.dims))
        if self.frames_mode:
            self._publish_frame(t_k, meas)
        elif meas is not None:
            self.frames += 1
            self.outlier_frames += int(meas.outlier)
            self._last_msg = cv.measurement_flat(meas.t_acq_s, meas.p, self.dims)
            self.publish("measurement", self._last_msg)
        elif self.lockstep:
            if self._last_msg is None:
                self.publish("measurement", PointStamped())  # "no frame yet": empty frame_id, stamp 0
            else:
                self.publish("measurement", self._last_msg)
        self.period_done(k)
        if self.lockstep and k + 1 >= self.n_ticks:
            self.mark_finished()

    def _publish_frame(self, t_k: float, frame: Any) -> None:
        """MR frames: the frame delivered at t_k (and its magnitude), else (lockstep) an empty one stamped t_k."""
        if frame is None:
            if self.lockstep:
                self.publish("mr_frame", cv.empty_frame_msg(t_k))
            return
        self.frames += 1
        samples = frame_samples_of(frame)
        self.publish("mr_image", cv.magnitude_image_msg(frame.t_acq_s, samples))
        self.publish("mr_frame", cv.frame_image_msg(frame.t_acq_s, samples))

    def _on_inject(self, req: Any, resp: Any) -> Any:
        start = float(req.start_time)
        if start < 0.0:
            start = self.k_next * self.dt
        if self.frames_mode:
            resp.accepted = False
            resp.message = ("the mr_images imager takes no injected faults (its frames' noise and rejections "
                            "are the scanner's)")
            resp.effective_start_time = start
            return resp
        try:
            if req.kind == InjectFault.Request.OUTLIER_BURST:
                self.imager.inject_outliers(start, float(req.duration), float(req.magnitude))
            elif req.kind == InjectFault.Request.DROPOUT:
                self.imager.inject_dropout(start, float(req.duration))
            else:
                raise ConfigError(f"kind must be OUTLIER_BURST (0) or DROPOUT (1), got {req.kind}")
        except ConfigError as exc:
            resp.accepted = False
            resp.message = str(exc)
            resp.effective_start_time = start
            return resp
        resp.accepted = True
        outlier = req.kind == InjectFault.Request.OUTLIER_BURST
        what = "outlier burst" if outlier else "dropout"
        resp.message = f"{what} from {start!r} s for {float(req.duration)!r} s"
        resp.effective_start_time = start
        self.get_logger().info(f"injected {resp.message}")
        if not outlier:
            self._windows.append((start, start + float(req.duration)))
        self._announce("outlier_burst" if outlier else "dropout", start, float(req.duration),
                       float(req.magnitude) if outlier else 0.0, "service")
        return resp

    def _announce(self, kind: str, start: float, duration: float, magnitude: float, source: str) -> None:
        """Record a fault and publish it on /diagnostics now."""
        self._faults.append((kind, start, duration, magnitude, source))
        self.publish_diagnostics()

    def diagnostic_values(self) -> dict[str, str]:
        out = {"tick": str(self.k_next - 1), "frames": str(self.frames), "outlier_frames": str(self.outlier_frames),
               "dropout_frames": str(self.dropout_frames), "faults_announced": str(len(self._faults))}
        if self._faults:
            kind, start, duration, magnitude, source = self._faults[-1]
            out.update(fault_kind=kind, fault_start=repr(start), fault_duration=repr(duration),
                       fault_magnitude=repr(magnitude), fault_source=source)
        return out


def main(argv: list[str] | None = None) -> int:
    """Console script ``vesselbot_imager``."""
    return run_node(ImagerNode, argv, exit_process=True)


if __name__ == "__main__":
    sys.exit(main())
