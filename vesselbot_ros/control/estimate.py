"""The observer's output port, shared by every observer (high-gain (25), extended Kalman, a user's)."""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

__all__ = ["Estimate", "measurement_arrays"]


class Estimate(NamedTuple):
    """Observer output at one tick.

    Attributes:
        t_s: Time of the estimate (s).
        x_hat: (2,) estimated position, m, frame W.
        z_hat: (2,) estimated velocity, m/s, frame W.
        time_since_measurement_s: Time since the last accepted measurement
            (s); ``inf`` before the first one.
        innovation: (2,) last innovation ``X_hat - Y`` used (m); zeros if none.
        used_measurement: True if a measurement corrected this tick.
        rejected: True if a measurement was offered and rejected this tick.
        flow_scale: Estimated blood-velocity scale ``s_hat`` (-): the truth is
            ``s`` times the model's ``V_f``; 1 for observers that do not
            estimate it (this one).
    """

    t_s: float
    x_hat: npt.NDArray[np.float64]
    z_hat: npt.NDArray[np.float64]
    time_since_measurement_s: float
    innovation: npt.NDArray[np.float64]
    used_measurement: bool
    rejected: bool
    flow_scale: float = 1.0


def measurement_arrays(measurement: Any | None, dims: int) -> tuple[bool, float, npt.NDArray[np.float64]]:
    """A delivered frame or None -> ``(has, t_acq_s, p (dims,))`` for a compiled observer update on ``dims`` axes.

    No frame: ``(False, nan, nan...)``; a position of the wrong shape travels as nan, which the compiled update
    rejects like any non-finite measurement.
    """
    m = np.full(int(dims), math.nan)
    if measurement is None:
        return False, math.nan, m
    yp = np.asarray(measurement.p, dtype=np.float64)
    if yp.shape == (int(dims),):
        m[:] = yp
    return True, float(measurement.t_acq_s), m
