"""Tests of the vdW (17)-(18), electrostatic (19) and steric (22) forces."""

import math

import numba
import numpy as np
import pytest
from scipy.integrate import quad

from vesselbot_ros.physics.params import BOLTZMANN_J_PER_K, VACUUM_PERMITTIVITY_F_PER_M
from vesselbot_ros.physics.wall_interactions import (
    EXP_ZERO_BELOW,
    decaying_exp,
    electrostatic_force,
    interaction_forces_along_n,
    max_charge,
    steric_coefficient,
    steric_force,
    vdw_force,
    wall_pair_forces_z,
)

R, A = 250e-6, 4e-19
EPS = 70 * VACUUM_PERMITTIVITY_F_PER_M


def potential(gap):
    h = gap / R
    return -A / 6 * (1 / h + 1 / (2 + h) + math.log(h / (2 + h)))


@pytest.mark.parametrize("gap", [1e-9, 1e-7, 1e-5, 3e-4])
def test_vdw_is_minus_gradient_of_potential(gap):
    step = gap * 1e-5
    numeric = (potential(gap + step) - potential(gap - step)) / (2 * step)  # dV/dgap > 0: attraction
    assert float(vdw_force(gap, R, A, 0.4e-9)) == pytest.approx(numeric, rel=1e-6)


def test_vdw_small_gap_limit_and_floor():
    g = 1e-9
    assert float(vdw_force(g, R, A, 0.4e-9)) == pytest.approx(A * R / (6 * g * g), rel=1e-5)
    floor = float(vdw_force(0.4e-9, R, A, 0.4e-9))
    assert float(vdw_force(0.0, R, A, 0.4e-9)) == floor
    assert np.isfinite(floor) and floor == pytest.approx(1.04e-4, rel=1e-2)


def test_hays_charge_reading():
    q = 1e-6 * 4 * math.pi * R**2 * 30 * (100 * R) ** -0.3
    assert float(max_charge(R)) == pytest.approx(q, rel=1e-14)
    assert q == pytest.approx(7.13e-11, rel=1e-2)


def test_electrostatic_printed_vs_image_charge_at_the_wall():
    q = float(max_charge(R))
    printed = float(electrostatic_force(0.0, R, q, EPS, 1.0))
    image = float(electrostatic_force(0.0, R, q, EPS, 0.25))
    assert printed == pytest.approx(q * q / (4 * math.pi * EPS * R * R), rel=1e-14)
    assert image == pytest.approx(q * q / (4 * math.pi * EPS * (2 * R) ** 2), rel=1e-14)
    bp_max = 0.8 * 4 / 3 * math.pi * R**3 * 1.72e6 * 0.08
    assert printed == pytest.approx(1.04e-5, rel=1e-2)
    assert printed > bp_max > image  # the printed form traps the robot at the upper wall


def test_steric_is_derjaguin_integral_of_plate_pressure():
    kbt, tau, l0 = BOLTZMANN_J_PER_K * 310, 1e15, 100e-9
    coef = float(steric_coefficient(R, l0, kbt, tau))
    gap = 30e-9
    pressure = lambda z: 50 * kbt * tau**1.5 * math.exp(-2 * math.pi * z / l0)  # noqa: E731  eq. (21)
    integral = 2 * math.pi * R * quad(pressure, gap, 50 * l0)[0]
    assert float(steric_force(gap, coef, l0)) == pytest.approx(integral, rel=1e-8)


def test_signs_attraction_towards_wall_repulsion_by_steric():
    q = float(max_charge(R))
    vdw, el, st = interaction_forces_along_n(-20e-9, R, A, 0.4e-9, q, EPS, 0.25, 1e-7, 100e-9, 0.0)
    assert vdw > 0 and el > 0 and st < 0
    # near the upper wall the z components point up (+z), steric down
    vz, ez, sz = wall_pair_forces_z(-20e-9, -2e-3, R, A, 0.4e-9, q, EPS, 0.25, 1e-7, 100e-9, 0.0)
    assert vz > 0 and ez > 0 and sz < 0
    # symmetric position: both walls cancel
    vz, ez, sz = wall_pair_forces_z(-1e-3, -1e-3, R, A, 0.4e-9, q, EPS, 0.25, 1e-7, 100e-9, 0.0)
    assert vz == 0 and ez == 0 and sz == 0


def test_contact_modes_hold_vs_paper_heaviside():
    q = float(max_charge(R))
    hold = interaction_forces_along_n(1e-9, R, A, 0.4e-9, q, EPS, 0.25, 1e-7, 100e-9, 0.0)
    at_zero = interaction_forces_along_n(0.0, R, A, 0.4e-9, q, EPS, 0.25, 1e-7, 100e-9, 0.0)
    np.testing.assert_allclose(hold, at_zero, rtol=1e-12, atol=1e-18)  # continuous at delta = 0
    paper = interaction_forces_along_n(1e-9, R, A, 0.4e-9, q, EPS, 0.25, 1e-7, 100e-9, 1.0)
    assert paper == (0.0, 0.0, 0.0) or np.allclose(paper, 0.0)


@numba.njit
def _compiled_steric(gap, coefficient, brush_length):
    return steric_force(gap, coefficient, brush_length)


def test_compiled_decaying_exp_is_exp_bit_for_bit():
    # around the cut, through the subnormal results, far below it, and the ordinary range
    xs = np.concatenate([np.linspace(-800.0, -700.0, 20001), [EXP_ZERO_BELOW, np.nextafter(EXP_ZERO_BELOW, 0.0),
                         -745.13321910194122, -1e6, -np.inf, -1.0, 0.0, 3.0]])
    for x in xs:
        assert decaying_exp(x) == np.exp(x)
        assert _compiled_exp(x) == _compiled_plain_exp(x), x  # what the kernels computed before
    assert np.exp(EXP_ZERO_BELOW) == 0.0  # the cut is where exp is already exactly zero


@numba.njit
def _compiled_exp(x):
    return decaying_exp(x)


@numba.njit
def _compiled_plain_exp(x):
    return np.exp(x)


@pytest.mark.parametrize("gap", [0.0, 5e-9, 50e-9, 2e-6, 1e-4, 3e-3])
def test_compiled_steric_force_is_the_numpy_one(gap):
    assert _compiled_steric(gap, 1e-7, 100e-9) == steric_force(np.float64(gap), 1e-7, 100e-9)
