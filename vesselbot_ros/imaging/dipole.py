"""The bead's field perturbation: a uniformly magnetised sphere, a point dipole outside it.

Frame convention.  The project's frame ``vessel`` (W) has x along the vessel, z vertical and y the scanner's
horizontal axis across the bore (:mod:`vesselbot_ros.physics.axes`, docs/graph.md).  The bore, and so the main
field B0, therefore runs along **+x**: the scanner's own "z" (the MR convention's B0 axis) is our x.  The bead is
saturated along B0 (the paper, Section II-A: the torque aligns M with B0), so its moment is ``m = m e_x``.

To first order in ``|dB| / B0`` (18 mT against 1.5-3 T at 1 mm; far smaller where there is signal) only the
perturbation's component along B0 changes the Larmor frequency, so everything here is that component,
``dB(r) = (mu0 m / 4 pi) (3 cos^2 theta - 1) / r^3`` with ``cos theta = (r . e_x) / |r|`` and
``m = tau_m (4/3) pi a^3 M`` (the magnetic volume at saturation, :func:`bead_moment_Am2`).

Inside the sphere (``|r| < a``) the field of a uniformly magnetised sphere is uniform,
``(2/3) mu0 M_eff = 2 (mu0 m / 4 pi) / a^3`` with ``M_eff = tau_m M`` the sphere's mean magnetisation; it equals
the outside field on the B0 axis at the surface.  No protons live there: the acquisition gives the sphere zero
proton density (a signal void), so the interior value only matters to whoever samples the field itself.

Worked example (the paper's bead: a = 250 um, tau_m = 0.8, M = 1.72e6 A/m): m = 9.0e-5 A m^2 and, on the B0
axis 1 mm from the centre, dB = 2 x 1e-7 x 9.0e-5 / 1e-9 = 18 mT (test/unit/imaging/test_dipole.py).
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.params import RobotParams

__all__ = ["MU0_T_M_PER_A", "GAMMA_BAR_HZ_PER_T", "B0_AXIS", "bead_moment_Am2", "dipole_prefactor",
           "dipole_dbz", "dipole_dbz_grad", "dipole_field_T"]

#: Vacuum permeability mu0 (T m / A), CODATA 2018.
MU0_T_M_PER_A = 1.25663706212e-6
#: Proton gyromagnetic ratio over 2 pi (Hz / T), CODATA 2018.
GAMMA_BAR_HZ_PER_T = 42.577478518e6
#: Index of B0's axis in an (x, y, z) vector: x, the bore (see the module's docstring).
B0_AXIS = 0


def bead_moment_Am2(robot: RobotParams) -> float:
    """The bead's moment at saturation, ``m = tau_m (4/3) pi a^3 M`` (A m^2), from the robot's parameters
    (``magnetic_ratio``, ``radius_m``, ``magnetization_A_per_m``)."""
    return robot.magnetic_ratio * (4.0 / 3.0) * math.pi * robot.radius_m ** 3 * robot.magnetization_A_per_m


def dipole_prefactor(moment_Am2: float) -> float:
    """``k = mu0 m / (4 pi)`` (T m^3): ``dB = k (3 cos^2 theta - 1) / r^3``."""
    return MU0_T_M_PER_A * moment_Am2 / (4.0 * math.pi)


@numba.njit(cache=True, nogil=True, fastmath=False)
def dipole_dbz_grad(dx, dy, dz, k, a):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(dB, d dB/dx, d dB/dy, d dB/dz)`` at offset ``(dx, dy, dz)`` (m) from the centre (T, T/m).

    B0 along x (the bore).  Inside the sphere (``r < a``): the uniform interior field ``2 k / a^3``, gradient 0.
    """
    r2 = dx * dx + dy * dy + dz * dz
    if r2 < a * a:
        return 2.0 * k / (a * a * a), 0.0, 0.0, 0.0
    inv_r2 = 1.0 / r2
    k5 = k * inv_r2 * inv_r2 * math.sqrt(inv_r2)  # k / r^5
    k7 = k5 * inv_r2
    dx2 = dx * dx
    db = k5 * (3.0 * dx2 - r2)
    gx = k7 * dx * (9.0 * r2 - 15.0 * dx2)
    c = k7 * (3.0 * r2 - 15.0 * dx2)
    return db, gx, c * dy, c * dz


def dipole_field_T(points: npt.ArrayLike, centre: npt.ArrayLike, moment_Am2: float,
                   radius_m: float) -> npt.NDArray[np.float64]:
    """dB along B0 (T) at ``points`` (..., 3) (m, frame W: x, y, z) of a bead at ``centre`` (3,): vectorised
    numpy, the reference the compiled kernels are checked against.  Inside the sphere: the uniform interior
    field."""
    p = np.asarray(points, dtype=np.float64)
    c = np.asarray(centre, dtype=np.float64)
    if p.shape[-1] != 3 or c.shape != (3,):
        raise ModelInputError(f"dipole_field_T: points must be (..., 3) and centre (3,), got {p.shape} and {c.shape}")
    if not (math.isfinite(moment_Am2) and math.isfinite(radius_m) and radius_m > 0):
        raise ModelInputError(f"dipole_field_T: moment and radius must be finite (radius > 0), got "
                              f"{moment_Am2!r}, {radius_m!r}")
    k = dipole_prefactor(moment_Am2)
    d = p - c
    r2 = np.einsum("...i,...i->...", d, d)
    inside = r2 < radius_m ** 2
    r2s = np.where(inside, 1.0, r2)
    out = k * (3.0 * d[..., B0_AXIS] ** 2 - r2s) / r2s ** 2.5
    return np.where(inside, 2.0 * k / radius_m ** 3, out)


def dipole_dbz(points: npt.ArrayLike, centre: npt.ArrayLike, robot: RobotParams) -> npt.NDArray[np.float64]:
    """:func:`dipole_field_T` of the robot's bead (its moment at saturation and radius)."""
    return dipole_field_T(points, centre, bead_moment_Am2(robot), robot.radius_m)
