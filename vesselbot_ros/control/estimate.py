"""The observer's output port, shared by every observer (high-gain (25), extended Kalman, a user's)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

__all__ = ["Estimate"]


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
