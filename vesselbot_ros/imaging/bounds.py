"""The Cramer-Rao bound of the bead's position under the acquisition's own image model.

The data are ``d = c mu(p) + n``: ``mu`` the noiseless frame (:func:`~vesselbot_ros.imaging.acquisition.slice_image`
or :func:`~vesselbot_ros.imaging.acquisition.projection_data`), ``c`` an unknown complex scale (the receiver's
gain and phase, as the tracker fits it; one per projection), ``n`` complex Gaussian with real and imaginary parts
each N(0, sigma^2).  The Fisher information of the real parameters ``theta`` (the position, then Re c and Im c
of each scale) is ``F = Re(J^H J) / sigma^2``, ``J`` the derivatives of the noiseless data: by central
differences in the position (step ``step_m``, a fiftieth of a pixel unless given), and ``mu``, ``i mu`` in the
scales (at c = 1).  The bound on the position is the position block of ``F^-1``: the scales are nuisances.

The slice bounds the in-plane position (x, z); the projections bound (x, y, z).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from vesselbot_ros.imaging.acquisition import (
    MrImagingParams,
    as_position3,
    noise_sigma,
    projection_data,
    slice_image,
)
from vesselbot_ros.physics.params import RobotParams

__all__ = ["slice_crb", "projection_crb", "crb_from_jacobian"]

Array = npt.NDArray[np.float64]
CArray = npt.NDArray[np.complex128]


def crb_from_jacobian(jac: CArray, sigma: float, n_position: int) -> Array:
    """The position block (n_position, n_position) of ``inv(Re(J^H J) / sigma^2)``; ``jac`` (samples, params)."""
    fisher = (jac.conj().T @ jac).real / sigma ** 2
    return np.asarray(np.linalg.inv(fisher)[:n_position, :n_position], dtype=np.float64)


def slice_crb(params: MrImagingParams, robot: RobotParams, position_m: npt.ArrayLike,
              centre_m: npt.ArrayLike = (0.0, 0.0, 0.0), vessel_diameter_m: float = 0.0,
              step_m: float | None = None) -> Array:
    """The 2 x 2 covariance bound (m^2) of the in-plane position (x, z) from one slice of ``params``."""
    p = as_position3(position_m, "position_m")
    h = params.pixel_m / 50.0 if step_m is None else step_m
    mu = slice_image(params, robot, p, centre_m, vessel_diameter_m).ravel()
    cols = []
    for axis in (0, 2):
        e = np.zeros(3)
        e[axis] = h
        up = slice_image(params, robot, p + e, centre_m, vessel_diameter_m).ravel()
        dn = slice_image(params, robot, p - e, centre_m, vessel_diameter_m).ravel()
        cols.append((up - dn) / (2.0 * h))
    jac = np.stack([*cols, mu, 1j * mu], axis=1)
    return crb_from_jacobian(jac, noise_sigma(params), 2)


def projection_crb(params: MrImagingParams, robot: RobotParams, position_m: npt.ArrayLike,
                   centre_m: npt.ArrayLike = (0.0, 0.0, 0.0), vessel_diameter_m: float = 0.0,
                   step_m: float | None = None) -> Array:
    """The 3 x 3 covariance bound (m^2) of (x, y, z) from one set of three projections, a complex scale per
    projection."""
    p = as_position3(position_m, "position_m")
    h = params.pixel_m / 50.0 if step_m is None else step_m
    mu = projection_data(params, robot, p, centre_m, vessel_diameter_m)
    n = params.matrix
    cols = []
    for axis in range(3):
        e = np.zeros(3)
        e[axis] = h
        up = projection_data(params, robot, p + e, centre_m, vessel_diameter_m)
        dn = projection_data(params, robot, p - e, centre_m, vessel_diameter_m)
        cols.append(((up - dn) / (2.0 * h)).ravel())
    for a in range(3):
        m = np.zeros((3, n), dtype=np.complex128)
        m[a] = mu[a]
        cols += [m.ravel(), 1j * m.ravel()]
    return crb_from_jacobian(np.stack(cols, axis=1), noise_sigma(params), 3)
