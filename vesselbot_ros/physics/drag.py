"""Hydrodynamic drag with the wall effect, eqs. (7), (8), (10), (11).

With u = v - v_f the relative velocity (m/s) and f(lambda) the wall factor (10),
the paper's (11) evaluates the unbounded-fluid law (7)-(8) at the *equivalent
free-stream velocity* u_inf = f u::

    f(lambda) = (1 + (lambda/lambda0)^alpha0) / (1 - lambda^alpha0)
    Re_inf    = 2 r rho_f |u_inf| / eta
    C_d(Re)   = 24/Re + 6/(1 + sqrt(Re)) + 0.4
    F_d       = -1/2 rho_f |u_inf|^2 A C_d(Re_inf) u/|u|,   A = pi r^2

Expanding 24/Re cancels the 1/|u| singularity exactly, so we evaluate::

    F_d = -[6 pi eta r f + 1/2 rho_f A f^2 |u| (6/(1 + sqrt(Re_inf)) + 0.4)] u

which is continuous (and C^1) at u = 0, equals 0 there, and tends to the
Stokes law with the wall factor, -6 pi eta r f(lambda) u, as Re -> 0.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numba.extending import register_jitable

from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics._validate import diameter_ratio, finite_array, positive

__all__ = ["wall_factor", "drag_coefficient", "drag_gain", "drag_force"]


@register_jitable
def wall_factor(lam, alpha0, lambda0):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """f(lambda) = (1 + (lambda/lambda0)^alpha0) / (1 - lambda^alpha0), eq. (10)-(11) (-)."""
    return (1.0 + (lam / lambda0) ** alpha0) / (1.0 - lam**alpha0)


@register_jitable
def drag_coefficient(re):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """C_d(Re) = 24/Re + 6/(1 + sqrt(Re)) + 0.4, eq. (8) (-); Re > 0."""
    return 24.0 / re + 6.0 / (1.0 + np.sqrt(re)) + 0.4


@register_jitable
def drag_gain(speed, r, eta, rho_f, f):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Scalar gain c (N s/m) with F_d = -c u; ``speed`` = |u| (m/s), arrays broadcast."""
    u_inf = f * speed
    re = 2.0 * r * rho_f * u_inf / eta
    return 6.0 * np.pi * eta * r * f + 0.5 * rho_f * np.pi * r * r * f * u_inf * (6.0 / (1.0 + np.sqrt(re)) + 0.4)


def drag_force(
    u_rel: npt.ArrayLike,
    radius_m: npt.ArrayLike,
    viscosity_Pa_s: npt.ArrayLike,
    fluid_density_kg_per_m3: float,
    diameter_ratio_lambda: npt.ArrayLike,
    alpha0: float = 1.5,
    lambda0: float = 0.29,
) -> npt.NDArray[np.float64]:
    """Drag force F_d (N), eq. (11), on a sphere with relative velocity ``u_rel``.

    Args:
        u_rel: (..., 2) relative velocity v - v_f (m/s), frame W (x, z).
        radius_m: r (m), broadcastable to ``u_rel[..., 0]``.
        viscosity_Pa_s: eta (Pa s), broadcastable.
        fluid_density_kg_per_m3: rho_f (kg/m^3).
        diameter_ratio_lambda: lambda = 2r/D in [0, 1), broadcastable.
        alpha0, lambda0: Wall-factor constants (-).

    Returns:
        (..., 2) drag force (N), opposite to ``u_rel``.

    Raises:
        ModelInputError: non-finite ``u_rel``.
        ConfigError: non-positive radius/viscosity/density, lambda outside [0, 1).
    """
    u = finite_array("u_rel", u_rel)
    if u.shape[-1:] != (2,):
        raise ModelInputError(f"u_rel must have shape (..., 2), got {u.shape}")
    r = positive("radius_m", radius_m)
    eta = positive("viscosity_Pa_s", viscosity_Pa_s)
    rho = positive("fluid_density_kg_per_m3", fluid_density_kg_per_m3)
    lam = diameter_ratio("diameter_ratio_lambda", diameter_ratio_lambda)
    speed = np.sqrt(u[..., 0] ** 2 + u[..., 1] ** 2)
    c = drag_gain(speed, r, eta, rho, wall_factor(lam, alpha0, lambda0))
    return -np.asarray(c)[..., None] * u
