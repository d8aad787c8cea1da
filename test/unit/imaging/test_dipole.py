"""The bead's dipole field: the issue's worked example, the interior field, the compiled kernel and its gradient."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.imaging.dipole import (
    bead_moment_Am2,
    dipole_dbz,
    dipole_dbz_grad,
    dipole_field_T,
    dipole_prefactor,
)
from vesselbot_ros.physics.params import RobotParams


def test_the_papers_bead_gives_9e_5_A_m2_and_18_mT_on_the_B0_axis_1_mm_away() -> None:
    robot = RobotParams(radius_m=250e-6, magnetic_ratio=0.8, magnetization_A_per_m=1.72e6)
    m = bead_moment_Am2(robot)
    assert m == pytest.approx(9.0e-5, rel=1e-2)
    assert m == pytest.approx(0.8 * 4.0 / 3.0 * math.pi * 250e-6 ** 3 * 1.72e6, rel=1e-12)
    on_axis = dipole_dbz(np.array([1e-3, 0.0, 0.0]), np.zeros(3), robot)  # B0 along x, the bore
    assert float(on_axis) == pytest.approx(18.0e-3, rel=1e-2)
    # across B0 (y or z), the field is -1/2 of the on-axis value; on the magic angle it vanishes
    assert float(dipole_dbz(np.array([0.0, 1e-3, 0.0]), np.zeros(3), robot)) == pytest.approx(-0.5 * float(on_axis))
    assert float(dipole_dbz(np.array([0.0, 0.0, -1e-3]), np.zeros(3), robot)) == pytest.approx(-0.5 * float(on_axis))
    c = 1.0 / math.sqrt(3.0)
    assert abs(float(dipole_dbz(1e-3 * np.array([c, math.sqrt(1 - c * c), 0.0]), np.zeros(3), robot))) < 1e-12


def test_inside_the_sphere_the_field_is_uniform_and_meets_the_outside_on_the_axis() -> None:
    robot = RobotParams()
    a = robot.radius_m
    inside = dipole_dbz(np.array([[0.0, 0.0, 0.0], [0.5 * a, 0.2 * a, 0.0], [0.0, 0.0, 0.99 * a]]), np.zeros(3), robot)
    mu0 = 4e-7 * math.pi
    assert inside == pytest.approx(2.0 / 3.0 * mu0 * robot.magnetic_ratio * robot.magnetization_A_per_m, rel=1e-6)
    outside = float(dipole_dbz(np.array([a * (1 + 1e-9), 0.0, 0.0]), np.zeros(3), robot))
    assert outside == pytest.approx(float(inside[0]), rel=1e-6)


def test_the_compiled_kernel_and_its_gradient_match_the_reference() -> None:
    rng = np.random.default_rng(3)
    k = dipole_prefactor(9e-5)
    a = 250e-6
    pts = rng.uniform(-5e-3, 5e-3, (200, 3))
    pts = pts[np.linalg.norm(pts, axis=1) > 2 * a]
    ref = dipole_field_T(pts, np.zeros(3), 9e-5, a)
    h = 1e-8
    for p, r in zip(pts, ref, strict=True):
        db, gx, gy, gz = dipole_dbz_grad(p[0], p[1], p[2], k, a)
        assert db == pytest.approx(r, rel=1e-12, abs=1e-18)
        for axis, g in enumerate((gx, gy, gz)):
            e = np.zeros(3)
            e[axis] = h
            fd = (dipole_field_T(p + e, np.zeros(3), 9e-5, a) - dipole_field_T(p - e, np.zeros(3), 9e-5, a)) / (2 * h)
            assert g == pytest.approx(float(fd), rel=1e-5, abs=1e-6 * abs(db) / 1e-3)


def test_bad_inputs_raise() -> None:
    with pytest.raises(ModelInputError):
        dipole_field_T(np.zeros((4, 2)), np.zeros(3), 1e-5, 1e-4)
    with pytest.raises(ModelInputError):
        dipole_field_T(np.zeros((4, 3)), np.zeros(3), math.nan, 1e-4)
