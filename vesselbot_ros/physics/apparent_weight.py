"""Apparent weight, eq. (14): W_a = V (rho - rho_f) g, along -z.

rho = tau_m rho_m + (1 - tau_m) rho_poly (see ``RobotParams.density_kg_per_m3``).
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable

__all__ = ["sphere_volume", "apparent_weight_z"]


@register_jitable
def sphere_volume(r):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """V = 4/3 pi r^3 (m^3) for radius r (m); arrays broadcast."""
    return 4.0 / 3.0 * np.pi * r * r * r


@register_jitable
def apparent_weight_z(volume, rho, rho_f, gravity):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """z component of W_a (N): -V (rho - rho_f) g, gravity along -z."""
    return -volume * (rho - rho_f) * gravity
