"""An MR frame as the ``mr_images`` imager delivers it, and its samples as they travel on ``imager/frame``.

Light to import (the imager and tracker nodes load it; the trackers' scipy.optimize only where a tracker is built).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt

from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.imaging.acquisition import ProjectionFrame, SliceFrame, as_position3, noise_sigma
from vesselbot_ros.imaging.imager_params import MrImagerParams

__all__ = ["MrFrame", "frame_samples_of", "frame_of"]


@dataclasses.dataclass(frozen=True)
class MrFrame:
    """One frame as the imager delivers it: acquired at ``t_acq_s`` (s; the middle of its tracking window when
    multiplexed), its data (:class:`~vesselbot_ros.imaging.acquisition.SliceFrame` or ``ProjectionFrame``), and
    its acquisition count from 0 (``index``)."""

    t_acq_s: float
    data: SliceFrame | ProjectionFrame
    index: int


def frame_samples_of(frame: MrFrame) -> npt.NDArray[np.complex128]:
    """The frame's complex samples as they travel on ``imager/frame`` (a slice's image; the projections' 3 rows)."""
    data = frame.data
    return data.image if isinstance(data, SliceFrame) else data.data


def frame_of(params: MrImagerParams, samples: npt.ArrayLike, t_acq_s: float, index: int) -> MrFrame:
    """The :class:`MrFrame` of complex ``samples`` acquired at ``t_acq_s`` with the scenario's imager ``params``
    (its geometry and noise level): what a tracker node rebuilds from an ``imager/frame`` message.

    Raises:
        ModelInputError: the samples' shape is not the acquisition's (matrix x matrix, or 3 x matrix).
    """
    imaging = params.imaging
    a = np.asarray(samples, dtype=np.complex128)
    n = imaging.matrix
    shape = (n, n) if imaging.acquisition == "slice" else (3, n)
    if a.shape != shape:
        raise ModelInputError(f"an {imaging.acquisition} frame of matrix {n} has {shape[0]} x {shape[1]} samples, "
                              f"got {a.shape[0] if a.ndim else 0} x {a.shape[1] if a.ndim > 1 else 0}")
    centre = as_position3(params.fov_centre_m, "fov_centre_m")
    sigma = noise_sigma(imaging)
    data: SliceFrame | ProjectionFrame
    if imaging.acquisition == "slice":
        data = SliceFrame(a, centre, 0 if imaging.readout_axis == "x" else 2, imaging.pixel_m, sigma)
    else:
        data = ProjectionFrame(a, centre, imaging.pixel_m, sigma)
    return MrFrame(float(t_acq_s), data, int(index))
