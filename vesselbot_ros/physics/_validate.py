"""Entry checks shared by the public numpy API of the physics core."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from vesselbot_ros.config import ConfigError
from vesselbot_ros.errors import ModelInputError

__all__ = ["finite_array", "finite_vector", "positive", "diameter_ratio"]


def finite_array(name: str, value: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Return ``value`` as a float64 array; raise ModelInputError if any entry is not finite."""
    arr = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise ModelInputError(f"{name} must be finite, got {value!r}")
    return arr


def finite_vector(name: str, value: npt.ArrayLike, size: int = 2) -> npt.NDArray[np.float64]:
    """Return a finite float64 vector of shape (size,) or raise ModelInputError."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (size,):
        raise ModelInputError(f"{name} must have shape ({size},), got shape {arr.shape}")
    return finite_array(name, arr)


def positive(name: str, value: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Return a finite, strictly positive float64 array or raise ConfigError."""
    arr = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(arr)) or not np.all(arr > 0.0):
        raise ConfigError(f"{name} must be finite and > 0, got {value!r}")
    return arr


def diameter_ratio(name: str, value: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Return lambda = 2r/D as an array in [0, 1) or raise ConfigError."""
    arr = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(arr)) or not np.all((arr >= 0.0) & (arr < 1.0)):
        raise ConfigError(f"{name} (lambda = 2 r / D) must be in [0, 1), got {value!r}")
    return arr
