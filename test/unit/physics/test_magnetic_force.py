"""Tests of the motive forces (2), (4)-(6) and of Z(S_p)."""

import math

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.physics.magnetic_force import (
    bead_pulling_force,
    ef_tail_length,
    elastic_flagellum_force,
    flagellum_normal_drag,
    helical_tail_slowdown_gain,
    helical_tail_thrust,
    helix_drag_coefficients,
    sperm_number_function,
)

ETA = 0.016
PHI = math.radians(35)
OMEGA = 2 * math.pi * 30


def bp(r):
    return float(bead_pulling_force(0.8, 4 / 3 * math.pi * r**3, 1.72e6, 0.08))


def ef(r):
    length = ef_tail_length(r, 10.0, PHI, 1.0)
    zeta = flagellum_normal_drag(ETA, length, 0.02 * r)
    return float(elastic_flagellum_force(0.8, 4 / 3 * math.pi * r**3, 1.72e6, 2e-3, OMEGA, length, zeta, 3.4, sperm_number_function(3.4)))


def ht(r):
    zp, zl = helix_drag_coefficients(ETA, r, 0.02 * r, PHI)
    return float(helical_tail_thrust(r, 10.0, PHI, zp, zl, OMEGA))


def test_bp_table3_value():
    assert bp(250e-6) == pytest.approx(0.8 * 6.545e-11 * 1.72e6 * 0.08, rel=1e-3)
    assert bp(250e-6) == pytest.approx(7.2e-6, rel=1e-2)


@pytest.mark.parametrize(("fn", "power"), [(bp, 3), (ef, 2), (ht, 2)])
def test_scalings(fn, power):
    assert fn(2e-4) / fn(1e-4) == pytest.approx(2**power, rel=1e-9)


def test_ef_equals_eq4_with_explicit_stiffness():
    r = 1e-5
    length = 2 * math.pi * 10 * r / math.sin(PHI)
    kappa = 0.02 * r
    zeta = 4 * math.pi * ETA / (math.log(length / (2 * kappa)) + 0.193)
    k_bend = length**4 * OMEGA * zeta / 3.4**4  # S_p = 3.4
    gamma0 = 0.8 * 4 / 3 * math.pi * r**3 * 1.72e6 * 2e-3
    eq4 = OMEGA * zeta * gamma0**2 * length**4 / (4 * k_bend**2) * sperm_number_function(3.4)
    assert ef(r) == pytest.approx(eq4, rel=1e-12)


def test_z_of_sperm_number():
    # force-free base: exact closed form 1/(2 S_p^4); hinged base: (2 - sqrt 2)/4 / S_p^4 asymptotically
    for sp in (3.4, 5.0, 10.0):
        assert sperm_number_function(sp, "free") == pytest.approx(1 / (2 * sp**4), rel=1e-9)
    assert sperm_number_function(40.0) * 40.0**4 == pytest.approx((2 - math.sqrt(2)) / 4, rel=1e-6)
    assert sperm_number_function(3.4) == pytest.approx(1.257e-3, rel=1e-3)
    zs = [sperm_number_function(s) for s in np.linspace(3.4, 20, 20)]
    assert np.all(np.diff(zs) < 0)
    with pytest.raises(ConfigError, match="sperm_number must be finite and > 0"):
        sperm_number_function(-1.0)


def test_helix_coefficients_hand_values():
    r, kappa = 1e-5, 2e-7
    lg = math.log(0.36 * math.pi * r / (kappa * math.sin(PHI)))
    zp, zl = helix_drag_coefficients(ETA, r, kappa, PHI)
    assert zp == pytest.approx(4 * math.pi * ETA / (lg + 0.5))
    assert zl == pytest.approx(2 * math.pi * ETA / lg)
    assert zp > zl
    c = helical_tail_slowdown_gain(r, 10.0, PHI, zp, zl)
    assert c == pytest.approx(2 * math.pi * 10 * r * (zp * math.sin(PHI) ** 2 + zl * math.cos(PHI) ** 2) / math.sin(PHI))


def test_bp_numpy_entry_validates():
    from vesselbot_ros.config import ConfigError as CE
    from vesselbot_ros.errors import ModelInputError
    from vesselbot_ros.physics.magnetic_force import bead_pulling_force_W

    f = bead_pulling_force_W(0.8, 250e-6, 1.72e6, [0.0, 0.08])
    np.testing.assert_allclose(f, [0.0, bp(250e-6)], rtol=1e-12, atol=1e-18)
    with pytest.raises(ModelInputError, match="gradient_T_per_m must be finite"):
        bead_pulling_force_W(0.8, 250e-6, 1.72e6, [np.nan, 0.0])
    with pytest.raises(CE, match="radius_m must be finite and > 0"):
        bead_pulling_force_W(0.8, -1.0, 1.72e6, [0.0, 0.0])


def _rft_thrust_from_a_sampled_filament(sp: float, base: str) -> float:
    """Time-averaged RFT thrust of a torque-driven filament, computed without the closed form.

    Units: L = k = zeta_perp = gamma_0 = 1, so omega = S_p^4.  The filament
    zeta_perp y_t = -k y_xxxx is solved for its harmonic shape Y (y = Re(Y e^{i omega t}))
    with scipy's collocation BVP solver; the thrust (zeta_perp - zeta_par) int y_t y_x dx
    (zeta_par = zeta_perp / 2) is averaged over sampled times of one period.
    """
    from scipy.integrate import solve_bvp, trapezoid

    s4 = sp**4

    def rhs(x, u):  # u = (a, a1, a2, a3, b, b1, b2, b3): Y = a + i b and its derivatives; Y'''' = -i S^4 Y
        return np.vstack([u[1], u[2], u[3], s4 * u[4], u[5], u[6], u[7], -s4 * u[0]])

    def bc(u0, u1):
        base_bc = [u0[0], u0[4]] if base == "hinged" else [u0[3], u0[7]]  # Y(0) = 0, or no force at the base
        return np.array([*base_bc, u0[2] + 1.0, u0[6], u1[2], u1[6], u1[3], u1[7]])  # torque at 0, free end

    x = np.linspace(0.0, 1.0, 401)
    sol = solve_bvp(rhs, bc, x, np.zeros((8, x.size)), tol=1e-10, max_nodes=100_000)
    assert sol.success, sol.message
    u = sol.sol(x)
    shape, slope = u[0] + 1j * u[4], u[1] + 1j * u[5]
    omega = s4
    thrust = []
    for t in np.linspace(0.0, 2 * np.pi / omega, 400, endpoint=False):
        ph = np.exp(1j * omega * t)
        y_t = np.real(1j * omega * shape * ph)
        y_x = np.real(slope * ph)
        thrust.append((1.0 - 0.5) * trapezoid(y_t * y_x, x))
    return abs(float(np.mean(thrust)))


@pytest.mark.parametrize("base", ["hinged", "free"])
@pytest.mark.parametrize("sp", [3.4, 6.0])
def test_z_matches_an_independent_time_averaged_thrust(sp, base):
    # eq. (4) in these units: F = omega zeta_perp gamma_0^2 L^4 / (4 k^2) Z = S_p^4 Z / 4
    thrust = _rft_thrust_from_a_sampled_filament(sp, base)
    assert sperm_number_function(sp, base) == pytest.approx(4.0 * thrust / sp**4, rel=1e-4)
