"""Magnetic motive forces of the three designs, eqs. (2)-(6) (Section III-A).

* Bead pulling (2): F_m = tau_m V (M . grad) B.  With M saturated along B_0 the
  force is tau_m V M grad_B, grad_B = (dB/dx, dB/dz) (T/m).  Scales as r^3.
* Elastic flagellum (4): F_m = omega zeta_perp gamma_0^2 L^4 / (4 k^2) Z(S_p), with
  gamma_0 = tau_m V M B_0, zeta_perp = 4 pi eta / (ln(L/(2 kappa)) + 0.193),
  S_p = (L^4 omega zeta_perp / k)^(1/4).  For a design at fixed S_p the bending
  stiffness is k = L^4 omega zeta_perp / S_p^4, so
  F_m = gamma_0^2 S_p^8 Z(S_p) / (4 L^4 omega zeta_perp)  ~ r^2 (with L, kappa ~ r).
* Helical tail (5)-(6): F_m = 2 pi n r [r cos(phi) (zeta_perp - zeta_par) omega e
  - (zeta_perp sin^2 phi + zeta_par cos^2 phi)/sin(phi) (v - v_f)]; the first
  (driving) term scales as r^2.

Z(S_p) is derived here (Evans and Lauga [14] give it numerically): the
small-amplitude filament obeys zeta_perp y_t = -k y_xxxx.  With y =
Re[(gamma_0 L^2/k) Y(s) e^{i omega t}], s = x/L, Y'''' + i S_p^4 Y = 0 on [0, 1]
with torque gamma_0 at the base (Y''(0) = -1), a free distal end (Y''(1) =
Y'''(1) = 0) and either a hinged base (Y(0) = 0, default) or a force-free base
(Y'''(0) = 0).  Resistive-force theory with zeta_par = zeta_perp / 2 gives the
time-averaged thrust (zeta_perp - zeta_par) int <y_t y_x> dx.  The time average
of a product of two harmonics is <Re(a e^{iwt}) Re(b e^{iwt})> = Re(a conj(b))/2,
so the thrust is (zeta_perp / 2) omega (gamma_0 L^2/k)^2 int_0^1 Re(i Y conj(Y'))/2 ds,
i.e. exactly the form (4) with Z = |int_0^1 Re(i Y conj(Y')) ds| (the two halves
make the 1/4 of (4)), evaluated in closed form.  Results: hinged, Z(3.4) =
1.257e-3 and Z S_p^4 -> (2 - sqrt 2)/4 for large S_p (decreasing, as the paper
states); force-free base, Z = 1/(2 S_p^4) exactly.  An independent check (a
collocation solution of the filament and a thrust averaged over sampled times) is in
``test/unit/physics/test_magnetic_force.py``.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import numpy.typing as npt
from numba.extending import register_jitable

from vesselbot_ros.blas_free import solve
from vesselbot_ros.config import ConfigError
from vesselbot_ros.physics._validate import finite_array, positive
from vesselbot_ros.physics.apparent_weight import sphere_volume

__all__ = [
    "bead_pulling_force",
    "sperm_number_function",
    "ef_tail_length",
    "flagellum_normal_drag",
    "elastic_flagellum_force",
    "helix_drag_coefficients",
    "helical_tail_thrust",
    "helical_tail_slowdown_gain",
]


@register_jitable
def bead_pulling_force(tau_m, volume, magnetization, grad):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """tau_m V M grad_B (N) for each gradient component grad (T/m); arrays broadcast."""
    return tau_m * volume * magnetization * grad


def sperm_number_function(sperm_number: float, base: Literal["hinged", "free"] = "hinged") -> float:
    """Z(S_p) (-) of eq. (4) for a torque-driven filament (see module doc).

    Raises:
        ConfigError: S_p not finite and > 0, or unknown base condition.
    """
    if not (math.isfinite(sperm_number) and sperm_number > 0):
        raise ConfigError(f"sperm_number must be finite and > 0, got {sperm_number!r}")
    if base not in ("hinged", "free"):
        raise ConfigError(f"ef_base must be one of ['hinged', 'free'], got {base!r}")
    mu = sperm_number * np.exp(1j * (-np.pi / 2 + 2 * np.pi * np.arange(4)) / 4)  # mu^4 = -i S_p^4
    a = np.zeros((4, 4), complex)
    b = np.zeros(4, complex)
    a[0], b[0] = mu**2, -1.0
    a[1] = np.ones(4) if base == "hinged" else mu**3
    a[2] = mu**2 * np.exp(mu)
    a[3] = mu**3 * np.exp(mu)
    c = solve(a, b)  # no LAPACK: the same doubles on every CPU (vesselbot_ros.blas_free)
    # int_0^1 Y conj(Y') ds = sum_jk c_j conj(c_k mu_k) (e^{nu_jk} - 1)/nu_jk, nu_jk = mu_j + conj(mu_k)
    nu = mu[:, None] + np.conj(mu)[None, :]
    small = np.abs(nu) < 1e-12
    integ = np.where(small, 1.0, (np.exp(nu) - 1.0) / np.where(small, 1.0, nu))
    total = np.sum(c[:, None] * np.conj(c * mu)[None, :] * integ)
    return float(abs(np.real(1j * total)))


@register_jitable
def ef_tail_length(r, n_turns, pitch_rad, contour):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """EF tail length L (m): helix contour 2 pi n r / sin(phi) (contour=1) or axial 2 pi n r / tan(phi)."""
    return contour * 2.0 * np.pi * n_turns * r / np.sin(pitch_rad) + (1.0 - contour) * 2.0 * np.pi * n_turns * r / np.tan(pitch_rad)


@register_jitable
def flagellum_normal_drag(eta, length, kappa):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """zeta_perp = 4 pi eta / (ln(L / (2 kappa)) + 0.193) (N s/m^2), below eq. (4)."""
    return 4.0 * np.pi * eta / (np.log(length / (2.0 * kappa)) + 0.193)


@register_jitable
def elastic_flagellum_force(tau_m, volume, magnetization, field, omega, length, zeta_perp, sperm, z_sp):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """|F_m| (N) of eq. (4) with k eliminated through S_p (see module doc)."""
    gamma0 = tau_m * volume * magnetization * field
    return gamma0 * gamma0 * sperm**8 * z_sp / (4.0 * length**4 * omega * zeta_perp)


@register_jitable
def helix_drag_coefficients(eta, r, kappa, pitch_rad):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(zeta_perp, zeta_par) (N s/m^2) of eq. (6)."""
    lg = np.log(0.36 * np.pi * r / (kappa * np.sin(pitch_rad)))
    return 4.0 * np.pi * eta / (lg + 0.5), 2.0 * np.pi * eta / lg


@register_jitable
def helical_tail_thrust(r, n_turns, pitch_rad, zeta_perp, zeta_par, omega):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Driving term of eq. (5): 2 pi n r^2 cos(phi) (zeta_perp - zeta_par) omega (N)."""
    return 2.0 * np.pi * n_turns * r * r * np.cos(pitch_rad) * (zeta_perp - zeta_par) * omega


@register_jitable
def helical_tail_slowdown_gain(r, n_turns, pitch_rad, zeta_perp, zeta_par):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Gain c (N s/m) of the slow-down term of eq. (5): F = -c (v - v_f)."""
    s = np.sin(pitch_rad)
    return 2.0 * np.pi * n_turns * r * (zeta_perp * s * s + zeta_par * np.cos(pitch_rad) ** 2) / s


def bead_pulling_force_W(
    magnetic_ratio: float, radius_m: float, magnetization_A_per_m: float, gradient_T_per_m: npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """Validated BP force (..., 2) (N) for a gradient (..., 2) (T/m) on a robot of radius r (m).

    Raises:
        ModelInputError: non-finite gradient.
        ConfigError: non-positive radius.
    """
    g = finite_array("gradient_T_per_m", gradient_T_per_m)
    vol = sphere_volume(float(positive("radius_m", radius_m)))
    return np.asarray(bead_pulling_force(magnetic_ratio, vol, magnetization_A_per_m, g))


__all__.append("bead_pulling_force_W")
