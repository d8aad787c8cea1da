"""Tracker node: the bead's position in each MR frame of the imager (only with ``imager.kind: mr_images``).

Thin adapter over the scenario's tracker stage (``tracker.kind``: ``dipole_fit`` by default,
:class:`vesselbot_ros.imaging.imager_stage.DipoleFitTracker`, or a user's ``module:Class``), exactly as the pure
runner calls it: each frame the imager delivers is rebuilt from its samples and the scenario's imager section
(:func:`vesselbot_ros.imaging.frames.frame_of`) and tracked; an accepted position is the measurement, a rejected
frame delivers nothing (counted).

Ports (frame ``vessel``):

=================================  ================================  ===============================  =====
port                               type                              rate                             units
=================================  ================================  ===============================  =====
in  ``/vesselbot/imager/frame``    sensor_msgs/Image (64FC2)         per tick (lockstep) / frames     a.u.
out ``/vesselbot/measurement``     geometry_msgs/PointStamped        per tick (lockstep) / frames     m
out ``/diagnostics``               diagnostic_msgs/DiagnosticArray   1 Hz wall                        frames
=================================  ================================  ===============================  =====

Lockstep: the n-th frame message belongs to tick n and is answered by the n-th measurement: the frame's
position (stamp = its acquisition time), else (an empty image: no frame at this tick; a rejected frame) the last
measurement again, unchanged, or before the first the "no frame yet" placeholder (empty ``frame_id``, stamp 0),
as the ``mri`` imager publishes it.  Real time: only accepted frames are answered.

Input checks: a wrong frame_id, an empty image whose stamp is not its tick's, a frame stamped after its tick
(lockstep) or in the future (real time), or samples that are not the acquisition's (encoding, shape): rejected
(WARN diagnostics); in lockstep the tick is still answered, so the loop never stalls on bad input.

Diagnostics: ``imager_frames`` (frames tracked), ``imager_frames_rejected`` and ``imager_rejected_reasons``
(the tracker's reasons, ``reason: count``), which the launcher adds to the run's metrics, as the pure runner's.
"""

from __future__ import annotations

import sys
from typing import Any

from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import Image

from vesselbot_ros.config import ConfigError
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.imaging.frames import frame_of
from vesselbot_ros.nodes import conversions as cv
from vesselbot_ros.nodes.base import VesselbotNode
from vesselbot_ros.nodes.process import run_node
from vesselbot_ros.sim.closed_loop import build_stage, frame_counts
from vesselbot_ros.sim.kinds import delivers_frames

__all__ = ["TrackerNode", "main"]


class TrackerNode(VesselbotNode):
    """The tracker (see module docstring)."""

    ROLE = "tracker"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.ROLE, **kwargs)
        if not delivers_frames(self.scenario):
            raise ConfigError(f"imager.kind {self.scenario.imager.kind!r} delivers positions: the tracker node has no "
                              "frames to track (it joins a graph whose imager delivers MR frames: imager.kind mr_images)")
        self.reset_state()
        self.add_publisher("measurement", PointStamped)
        self.add_subscription("mr_frame", Image, self._on_frame)
        self.realtime_clock()

    def reset_state(self) -> None:
        """The tracker as built from the scenario, no frame yet."""
        self.tracker = build_stage(self.scenario, self.stage)
        self.k_next = 0
        self.frames_in = 0
        self._last_msg: Any = None

    def _answer(self, k: int, msg: Any) -> None:
        """Lockstep: answer tick ``k`` with ``msg`` (a fresh measurement) or the last one (None)."""
        if msg is not None:
            self._last_msg = msg
        if msg is not None or self.lockstep:
            self.publish("measurement", self._last_msg if self._last_msg is not None else PointStamped())
        if not self.lockstep:  # real time: it works on frames, not on every tick; the ticks between are not missed
            self.period_tick = max(self.period_tick, k - 1)
        self.period_done(k)
        if self.lockstep and k + 1 >= self.n_ticks:
            self.mark_finished()

    def _on_frame(self, msg: Any) -> None:
        stamp = cv.ns_of_stamp(msg.header.stamp)
        k = self.k_next if self.lockstep else max(self.tick_now, 0)
        if self.lockstep and k >= self.n_ticks:
            self.reject("mr_frame", "future_tick", f"frame message {k + 1} of a run of {self.n_ticks} ticks")
            return
        t_k = cv.tick_time(k, self.dt)
        if self.lockstep:
            self.k_next = k + 1
        if not self.check("mr_frame", frame_id=msg.header.frame_id, stamp_ns=stamp):
            self._answer(k, None)
            return
        try:
            samples = cv.frame_samples(msg)
            if samples is None:
                if self.lockstep and stamp != cv.ns_of_time(t_k):
                    self.reject("mr_frame", "stamp_tick_mismatch", f"an empty frame of tick {k} stamped {stamp} ns")
                else:
                    self.count_received("mr_frame")
                self._answer(k, None)
                return
            if self.lockstep and stamp > cv.ns_of_time(t_k):
                self.reject("mr_frame", "future_stamp", f"a frame acquired at {stamp} ns delivered at tick {k}")
                self._answer(k, None)
                return
            frame = frame_of(self.scenario.imager, samples,  # type: ignore[arg-type]  # mr_images: MrImagerParams
                              stamp * 1e-9, self.frames_in)
        except (ValueError, ModelInputError) as exc:
            self.reject("mr_frame", "malformed", str(exc))
            self._answer(k, None)
            return
        self.count_received("mr_frame")
        self.frames_in += 1
        meas = self.tracker.track(t_k, frame)
        self._answer(k, None if meas is None else cv.measurement_flat(meas.t_acq_s, meas.p, self.dims))

    def diagnostic_values(self) -> dict[str, str]:
        # the pure runner's counts (no frame is superseded here: the imager node sends the newest due)
        counts = frame_counts(None, self.tracker)
        if not hasattr(self.tracker, "frames"):  # a user's tracker that counts nothing: the frames it was given
            counts["imager_frames"] = self.frames_in
        return {"tick": str(self.k_next - 1), **{k: str(v) for k, v in counts.items()}}


def main(argv: list[str] | None = None) -> int:
    """Console script ``vesselbot_tracker``."""
    return run_node(TrackerNode, argv, exit_process=True)


if __name__ == "__main__":
    sys.exit(main())
