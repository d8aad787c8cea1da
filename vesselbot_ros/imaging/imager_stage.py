"""The imager from MR data (the ``mr_images`` kind) and its default tracker (the ``dipole_fit`` tracker kind).

The ``mri`` imager adds Gaussian jitter to the true position.  The ``mr_images`` imager makes the measurement a
product of the scanner, in two stages, as on a real scanner:

1. :class:`MrImager` (the imager role): at each acquisition it synthesises the frame of
   :mod:`vesselbot_ros.imaging.acquisition` (a gradient-echo slice or MS-SET's three projections) at the bead's
   positions during the acquisition, with the acquisition's complex noise, and delivers it as an
   :class:`MrFrame` when its reconstruction latency has passed;
2. a tracker (the tracker role, :class:`DipoleFitTracker` by default, or a user's kind): the position of the
   bead in a delivered frame, which is the measurement.  A frame the tracker rejects (no bead, all noise,
   clipped, NaN, a failed fit, or a position outside the central :data:`FOV_USED` of the view: ``edge_of_view``)
   delivers nothing, and is counted (:attr:`DipoleFitTracker.rejected`); never a NaN measurement.

The per-tick loop calls the tracker on each frame the imager delivers; in the node graph the imager node
publishes the frames (``imager/frame``) and the tracker node the measurements, with the same numbers.

When:

* ``sequence.mode: continuous``: one acquisition every ``1 / frame_rate_Hz`` from t = 0, of the bead where it
  is then, delivered ``latency_s`` later;
* ``sequence.mode: multiplexed``: one acquisition per tracking window, of the bead's positions at the
  window's ticks (the lines of a slice, or the three projections, spread over them: the motion during the
  window is in the data), stamped and delivered as the ``mri`` imager's (``t_acq_s``, ``t_deliver_s`` of the
  window; the sequence's latency).

At most one frame is delivered per tick: the newest due (an older one due at the same tick is superseded and
counted; with at most one frame per control period, as the scenario requires, none is).

Frames: the field of view is centred at ``fov_centre_m`` (x, y, z); in a planar scenario the bead is at
y = 0 and the measurement is the tracked (x, z).  B0 runs along x (docs/imaging.md).  The loop runs these
stages tick by tick (they have no compiled form); their numbers are reproducible from the run's seed.
"""

from __future__ import annotations

import math
from collections import Counter, deque

import numpy as np
import numpy.typing as npt

from vesselbot_ros.imaging.acquisition import (
    MrImagingParams,
    ProjectionFrame,
    SliceFrame,
    acquire_projections,
    acquire_slice,
    check_field_of_view,
)
from vesselbot_ros.imaging.frames import MrFrame, frame_of, frame_samples_of
from vesselbot_ros.imaging.imager_params import MrImagerParams, TrackerParams
from vesselbot_ros.imaging.tracker import ProjectionTracker, SliceTracker, Track
from vesselbot_ros.physics.params import PhysicsParams, RobotParams
from vesselbot_ros.scanner.imager_model import Measurement, check_frame_inputs
from vesselbot_ros.scanner.sequence import SequenceParams, tracking_window_of

__all__ = ["MrImagerParams", "TrackerParams", "MrFrame", "MrImager", "DipoleFitTracker", "FOV_USED", "inside_view",
           "frame_samples_of", "frame_of"]

#: The share of the field of view (centred, per encoded axis) in which a bead is imaged and a tracked position
#: accepted: a position at the edge is where a fit of a bead outside the view, or of noise, ends.
FOV_USED = 0.9


def _in_view(q: npt.ArrayLike, centre: npt.NDArray[np.float64], fov_m: float, slice_: bool) -> bool:
    """Whether ``q`` (3,) lies in the central :data:`FOV_USED` of a view of ``fov_m`` centred at ``centre`` on every
    encoded axis (a slice's x and z; the projections' x, y and z)."""
    q = np.asarray(q, dtype=np.float64)
    half = 0.5 * FOV_USED * fov_m
    return all(abs(float(q[i] - centre[i])) <= half for i in ((0, 2) if slice_ else (0, 1, 2)))


def inside_view(frame: SliceFrame | ProjectionFrame, q: npt.ArrayLike) -> bool:
    """Whether ``q`` (3,) lies in the central :data:`FOV_USED` of ``frame``'s field of view on every encoded axis."""
    slice_ = isinstance(frame, SliceFrame)
    n = (frame.image if isinstance(frame, SliceFrame) else frame.data).shape[1]
    return _in_view(q, frame.centre_m, n * frame.pixel_m, slice_)


class MrImager:
    """The ``mr_images`` imager on ``dims`` axes (module docstring); call :meth:`frame` once per tick."""

    def __init__(self, params: MrImagerParams, physics: PhysicsParams, sequence: SequenceParams,
                 rng: np.random.Generator, dims: int = 2, tick_s: float = 1e-3) -> None:
        self.params, self.dims, self.rng, self.sequence, self.tick_s = params, int(dims), rng, sequence, tick_s
        self.imaging = params.imaging
        if params.vessel_diameter_m > 0.0:
            check_field_of_view(self.imaging, params.vessel_diameter_m)
        self.robot = physics.robot
        self._centre = np.asarray(params.fov_centre_m, dtype=np.float64)
        self.frames = 0
        #: frames superseded by a newer one due at the same tick (never delivered)
        self.superseded = 0
        self._queue: deque[tuple[float, MrFrame]] = deque()
        self._t_last = -math.inf
        self._next_acq_s = 0.0
        self._window: int = -1
        self._window_p: list[npt.NDArray[np.float64]] = []

    def _space(self, p: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        return p.copy() if self.dims == 3 else np.array([p[0], 0.0, p[1]])

    def _inside(self, q: npt.NDArray[np.float64]) -> bool:
        return _in_view(q, self._centre, self.imaging.fov_m, self.imaging.acquisition == "slice")

    def _acquire(self, positions: list[npt.NDArray[np.float64]], t_acq: float, t_deliver: float) -> None:
        inside = [p for p in positions if self._inside(p)]
        # a bead outside the field of view puts no signal in it (its aliasing is not modelled): a frame of the
        # background and noise, which the tracker rejects
        bead = None if not inside else (inside[0] if len(inside) == 1 else inside)
        acquire = acquire_slice if self.imaging.acquisition == "slice" else acquire_projections
        data = acquire(self.imaging, self.robot, bead, self.rng, self._centre, self.params.vessel_diameter_m)
        self._queue.append((t_deliver, MrFrame(float(t_acq), data, self.frames)))
        self.frames += 1

    def frame(self, t_s: float, p_true: npt.ArrayLike) -> MrFrame | None:
        """Acquire (if due) and deliver (if due) at tick ``t_s``: the newest frame delivered now, or None."""
        p = check_frame_inputs(t_s, p_true, self._t_last, self.dims)
        self._t_last = t_s
        if self.sequence.mode == "multiplexed":
            w = tracking_window_of(self.sequence, t_s)
            if w is not None:
                if w.index != self._window:
                    self._window, self._window_p = w.index, []
                self._window_p.append(self._space(p))
                if t_s + self.tick_s > w.end_s - 1e-12:  # the window's last tick: its data are complete
                    self._acquire(self._window_p, w.t_acq_s, w.t_deliver_s)
                    self._window_p = []
        elif t_s >= self._next_acq_s - 1e-12:
            self._acquire([self._space(p)], t_s, t_s + self.params.latency_s)
            self._next_acq_s += 1.0 / self.params.frame_rate_Hz
        out = None
        while self._queue and self._queue[0][0] <= t_s + 1e-12:
            if out is not None:
                self.superseded += 1
            out = self._queue.popleft()[1]
        return out


class DipoleFitTracker:
    """The default tracker (kind ``dipole_fit``): the bead's position in each :class:`MrFrame`, by a fit of the
    dipole artefact model (:mod:`vesselbot_ros.imaging.tracker`), or None for a rejected frame (counted by reason
    in :attr:`rejected`).

    Args:
        params: The ``tracker`` section (:class:`~vesselbot_ros.imaging.imager_params.TrackerParams`).
        imaging: The acquisition the frames come from (the model it fits).
        robot: The bead (radius, magnetisation).
        vessel_diameter_m: The vessel in the model's background (m; 0: tissue only).
        dims: The loop's axes (2: the measurement is the tracked (x, z)).
    """

    def __init__(self, params: TrackerParams, imaging: MrImagingParams, robot: RobotParams,
                 vessel_diameter_m: float = 0.0, dims: int = 2) -> None:
        self.params, self.dims = params, int(dims)
        tracker_type = SliceTracker if imaging.acquisition == "slice" else ProjectionTracker
        self.tracker = tracker_type(imaging, robot, vessel_diameter_m, params.min_chi2)
        self.rejected: Counter[str] = Counter()
        self.frames = 0
        self.last_track: Track | None = None

    def track(self, t_s: float, frame: MrFrame) -> Measurement | None:
        """The measurement of ``frame`` (delivered at ``t_s``), or None when the frame is rejected."""
        track = self.tracker.track(frame.data)  # type: ignore[arg-type]  # the tracker of this acquisition's frames
        self.frames += 1
        self.last_track = track
        if track.position_m is None or not inside_view(frame.data, track.position_m):
            self.rejected[track.reason or "edge_of_view"] += 1
            return None
        q = track.position_m
        p = q.copy() if self.dims == 3 else np.array([q[0], q[2]])
        return Measurement(float(frame.t_acq_s), p, False)

    def reset(self) -> None:
        """Back to the start of a run: no template, no counts."""
        self.tracker.reset()
        self.rejected.clear()
        self.frames = 0
        self.last_track = None
