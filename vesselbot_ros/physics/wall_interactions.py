"""Van der Waals (17)-(18), electrostatic (19) and steric (22) robot-wall forces.

All three are functions of the gap g = -delta (m) between the robot surface and
one wall and act along that wall's outward normal n: vdW and electrostatic
attract (+n, towards the wall), steric repels (-n).  The returned magnitudes
are signed along +n (positive = attraction).

* van der Waals: V = -(A_h/6)(1/h + 1/(2+h) + ln(h/(2+h))), h = g/r.  Its
  derivative simplifies exactly to  F = 2 A_h / (3 r h^2 (h+2)^2)  (-> A_h r/(6 g^2)
  for g << r).  It diverges as g -> 0, so g is floored at ``g_min``
  (``InteractionParams.vdw_floor_m``): by default the compressed thickness of
  the polymer brush, 0.2 L0 = 20 nm (``vdw_min_separation: brush_limited``;
  the brush keeps the core that far from the endothelium, and eq. (20) is only
  valid above 0.2 L0), or an explicit value such as the 0.4 nm atomic
  contact distance (``explicit``).
* electrostatic: paper (19) prints q^2/(4 pi eps eps0 (r + g)^2).  The image force
  on a charge at distance s = r + g from a conducting plane is
  q^2/(4 pi eps eps0 (2 s)^2), 4x smaller: ``factor`` = 1 (printed) or 1/4 (image).
  q is Hays' maximum charge [33]: q(uC) = 4 pi r^2 * 30 (100 r)^-0.3, read with r in m
  (30 uC/m^2 surface density scaled by the radius in cm): 7.1e-11 C at r = 250 um.
* steric (Derjaguin, valid for 0.2 L0 < g < 0.9 L0 and applied everywhere):
  |F_s| = 50 r L0 k_B T tau^(3/2) exp(-2 pi g / L0), repulsive.

Two ways to treat contact (delta > 0): ``hold`` (default) evaluates each force at
zero gap (vdW at g_min), which is continuous at delta = 0; ``paper_heaviside``
multiplies by H(-delta) as printed.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numba import types
from numba.extending import overload, register_jitable

from vesselbot_ros.physics._validate import finite_array, positive
from vesselbot_ros.physics.params import VACUUM_PERMITTIVITY_F_PER_M

__all__ = [
    "electrostatic_factor",
    "contact_heaviside_flag",
    "robot_charge",
    "max_charge",
    "vdw_force",
    "electrostatic_force",
    "steric_force",
    "decaying_exp",
    "EXP_ZERO_BELOW",
    "steric_coefficient",
    "interaction_forces_along_n",
    "wall_pair_forces_z",
]


def electrostatic_factor(model: str) -> float:
    """1.0 for ``'paper_printed'`` eq. (19), 0.25 for the ``'image_charge'`` force."""
    return 1.0 if model == "paper_printed" else 0.25


def contact_heaviside_flag(mode: str) -> float:
    """1.0 if interactions are cut by H(-delta) in contact (``'paper_heaviside'``), else 0.0."""
    return 1.0 if mode == "paper_heaviside" else 0.0


def robot_charge(radius_m, charge_C: float | None, charge_scale: float):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """q (C): ``charge_C`` or Hays' maximum at ``radius_m`` (scalar or array), times ``charge_scale``."""
    return (max_charge(radius_m) if charge_C is None else charge_C) * charge_scale


@register_jitable
def max_charge(r):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Hays' maximum allowable charge (C) of a sphere of radius r (m)."""
    return 1.0e-6 * 4.0 * np.pi * r * r * 30.0 * (100.0 * r) ** -0.3


@register_jitable
def vdw_force(gap, r, hamaker, g_min):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Attractive vdW force (N, along +n) at gap (m) >= 0, floored at ``g_min``."""
    h = np.maximum(gap, g_min) / r
    return 2.0 * hamaker / (3.0 * r * h * h * (h + 2.0) ** 2)


@register_jitable
def electrostatic_force(gap, r, charge, eps_eps0, factor):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Attractive electrostatic force (N, along +n); factor 1 = eq. (19) as printed, 1/4 = image."""
    s = r + np.maximum(gap, 0.0)
    return factor * charge * charge / (4.0 * np.pi * eps_eps0 * s * s)


@register_jitable
def steric_coefficient(r, brush_length, kb_t, grafting_density):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """50 r L0 k_B T tau^(3/2) (N): steric force at zero gap, eq. (22)."""
    return 50.0 * r * brush_length * kb_t * grafting_density**1.5


#: Below this argument ``exp`` is exactly 0.0 in double precision (its smallest subnormal result is exp(-744.4)).
EXP_ZERO_BELOW = -746.0


def decaying_exp(x):  # type: ignore[no-untyped-def]  # numpy and numba: any float or array
    """``np.exp(x)``: the same doubles; compiled for one float, 0.0 without calling ``exp`` where it is exactly 0.

    The steric force's ``exp(-2 pi g / L0)`` is exactly 0 a few brush lengths from a wall, that is for the far
    wall at every force evaluation and for both walls in mid-lumen, and libm takes its underflow path there
    (errno, the SVID wrapper): 7 % of a closed-loop run's time, measured with perf.
    """
    return np.exp(x)


@overload(decaying_exp)
def _decaying_exp_compiled(x):  # type: ignore[no-untyped-def]  # numba overload: returns the implementation for x's type
    if isinstance(x, types.Float):
        def scalar(x):  # type: ignore[no-untyped-def]  # numba implementation
            if x < EXP_ZERO_BELOW:
                return 0.0
            return np.exp(x)
        return scalar
    return lambda x: np.exp(x)


@register_jitable
def steric_force(gap, coefficient, brush_length):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Repulsive steric force magnitude (N, along -n) at gap (m)."""
    return coefficient * decaying_exp(-2.0 * np.pi * np.maximum(gap, 0.0) / brush_length)


@register_jitable
def interaction_forces_along_n(delta, r, hamaker, g_min, charge, eps_eps0, el_factor, st_coef, brush_length, heaviside):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(vdW, electrostatic, steric) components along +n (N) for one wall at ``delta`` (m).

    ``heaviside`` = 1 multiplies by H(-delta) (paper), 0 holds the zero-gap value.
    """
    gap = -delta
    on = 1.0 - heaviside * (delta > 0.0)
    return (on * vdw_force(gap, r, hamaker, g_min),
            on * electrostatic_force(gap, r, charge, eps_eps0, el_factor),
            -on * steric_force(gap, st_coef, brush_length))


@register_jitable
def wall_pair_forces_z(delta_up, delta_lo, r, hamaker, g_min, charge, eps_eps0, el_factor, st_coef, brush_length, heaviside):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """z components (N) of (vdW, electrostatic, steric), summed over both walls.

    The upper wall normal is +z and the lower one -z, so at the centreline the
    two walls cancel exactly and the sum is continuous everywhere.
    """
    vu, eu, su = interaction_forces_along_n(delta_up, r, hamaker, g_min, charge, eps_eps0, el_factor, st_coef, brush_length, heaviside)
    vl, el, sl = interaction_forces_along_n(delta_lo, r, hamaker, g_min, charge, eps_eps0, el_factor, st_coef, brush_length, heaviside)
    return vu - vl, eu - el, su - sl


def interaction_forces(
    gap_m: npt.ArrayLike,
    radius_m: float,
    hamaker_J: float,
    min_separation_m: float,
    charge_C: float,
    relative_permittivity: float,
    electrostatic_factor: float,
    steric_coefficient_N: float,
    brush_length_m: float,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Validated numpy entry: (vdW, electrostatic, steric) along +n (N) vs gap (m).

    Args:
        gap_m: Gap(s) -delta >= 0 (m), any shape.
        radius_m: r (m). hamaker_J: A_h (J). min_separation_m: vdW floor (m).
        charge_C: q (C). relative_permittivity: epsilon (-).
        electrostatic_factor: 1 (printed) or 0.25 (image charge).
        steric_coefficient_N: see :func:`steric_coefficient`. brush_length_m: L0 (m).

    Returns:
        Three arrays shaped like ``gap_m``: vdW (> 0), electrostatic (> 0), steric (< 0).
    """
    g = finite_array("gap_m", gap_m)
    r = float(positive("radius_m", radius_m))
    positive("min_separation_m", min_separation_m)
    positive("brush_length_m", brush_length_m)
    return interaction_forces_along_n(-g, r, hamaker_J, min_separation_m, charge_C,
                                      relative_permittivity * VACUUM_PERMITTIVITY_F_PER_M,
                                      electrostatic_factor, steric_coefficient_N, brush_length_m, 0.0)


__all__.append("interaction_forces")
