"""A user's tracker as a stage kind: the bead's position in each MR frame, named in a scenario by ``module:Class``.

With ``imager.kind: mr_images`` the imager delivers MR frames (a gradient-echo slice, or MS-SET's three 1-D
projections) and the tracker stage turns each into a measurement.  The default tracker, ``dipole_fit``, fits the
bead's dipole artefact.  This one is the simplest that works on MS-SET projections: the excited spins lie in a shell
that the dipole field makes symmetric about the bead, so per axis the centroid of the magnitude above a noise
threshold, less the centroid's offset for a bead at the view's centre (calibrated once, on a noiseless projection
of the model: the readout shift of the off-resonant spins and the background's asymmetry), is the bead's position.  It runs, with
the same numbers, in ``vesselbot simulate``, ``vesselbot campaign`` and inside the tracker node of
``vesselbot run``::

    PYTHONPATH=examples vesselbot simulate --config config/plans/clinical_3t.yaml \\
        --set imager.kind=mr_images --set "imager.fov_centre_m=[4.0e-3, 0.0, 0.0]" \\
        --set tracker.kind=plugin_tracker:CentroidTracker

The convention (as for every stage kind; ``vesselbot kinds tracker`` lists the registered ones):

* ``ROLE = "tracker"``; ``Params``: a frozen dataclass with a ``kind: str`` field (the scenario's ``tracker``
  section, validated by the package's loader);
* ``__init__(params, context)``: ``context.scenario.imager`` holds the acquisition (``.imaging``: matrix, pixel,
  bandwidth, excitation offset ...);
* ``track(t_s, frame) -> Measurement | None``: ``frame`` is a :class:`vesselbot_ros.imaging.frames.MrFrame`
  (``t_acq_s``, ``data`` with the complex samples and the field of view's centre, ``index``); return a
  :class:`vesselbot_ros.scanner.imager_model.Measurement` stamped ``frame.t_acq_s`` with the position on the
  loop's axes ((x, z) in a planar scenario, (x, y, z) in a 3-D tree), or None to reject the frame.  Never NaN.

To bring a tracker as a ROS node instead: ``vesselbot run --without tracker`` prints the slot's contract
(subscribe ``imager/frame``, publish ``measurement``).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from vesselbot_ros.config import ConfigError
from vesselbot_ros.imaging.acquisition import ProjectionFrame, projection_data
from vesselbot_ros.scanner.imager_model import Measurement


@dataclasses.dataclass(frozen=True)
class CentroidParams:
    """``tracker`` section: ``threshold_sigma``, the samples in the centroid exceed this many noise sigmas (> 0)."""

    kind: str = "plugin_tracker:CentroidTracker"
    threshold_sigma: float = 5.0

    def __post_init__(self) -> None:
        if not self.threshold_sigma > 0.0:
            raise ConfigError(f"tracker.threshold_sigma must be > 0, got {self.threshold_sigma!r}")


class CentroidTracker:
    """Per projection, the centroid of the magnitude above the noise (MS-SET frames only)."""

    ROLE = "tracker"
    Params = CentroidParams

    def __init__(self, params: CentroidParams, context: Any) -> None:
        imaging = context.scenario.imager.imaging
        if imaging.acquisition != "projections":
            raise ConfigError("tracker.kind: CentroidTracker tracks MS-SET projections, not slices")
        self.threshold = params.threshold_sigma
        self.dims = context.scenario.dims
        # calibration: the centroid of a noiseless projection of a bead at the view's centre (the excited spins' readout
        # shift, the background's asymmetry), in pixels from the centre
        centre = np.asarray(context.scenario.imager.fov_centre_m, dtype=np.float64)
        clean = np.abs(projection_data(imaging, context.scenario.physics.robot, centre, centre,
                                       context.scenario.imager.vessel_diameter_m))
        n = clean.shape[1]
        self.offset_px = [self._centroid(clean[a], 0.0) - n / 2 for a in range(3)]
        self.rejected: dict[str, int] = {}
        self.frames = 0

    def track(self, t_s: float, frame: Any) -> Measurement | None:
        """The centroid on each axis, or None (nothing above the threshold, or not finite)."""
        self.frames += 1
        data: ProjectionFrame = frame.data
        mag = np.abs(data.data)
        if not np.all(np.isfinite(mag)):
            return self._reject("nan_in_data")
        n = mag.shape[1]
        q = np.empty(3)
        for a in range(3):
            c = self._centroid(mag[a], self.threshold * data.sigma)
            if not np.isfinite(c):
                return self._reject("no_bead")
            q[a] = data.centre_m[a] + (c - self.offset_px[a] - n / 2) * data.pixel_m
        p = q if self.dims == 3 else np.array([q[0], q[2]])
        return Measurement(float(frame.t_acq_s), p, False)

    @staticmethod
    def _centroid(mag: np.ndarray, floor: float) -> float:
        """The centroid (samples) of ``mag`` above ``floor``; NaN if nothing is above it."""
        w = np.maximum(mag - floor, 0.0)
        total = float(w.sum())
        return float(np.dot(w, np.arange(len(w))) / total) if total > 0.0 else float("nan")

    def _reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
        return None
