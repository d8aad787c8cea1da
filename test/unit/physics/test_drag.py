"""Tests of the drag law (7), (8), (10), (11)."""

import math

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.drag import drag_force, wall_factor

R, ETA, RHO = 250e-6, 0.016, 1060.0


def test_wall_factor_hand_values():
    lam = 0.5 / 3.0
    assert float(wall_factor(lam, 1.5, 0.29)) == pytest.approx((1 + (lam / 0.29) ** 1.5) / (1 - lam**1.5), rel=1e-14)
    assert float(wall_factor(0.0, 1.5, 0.29)) == 1.0


def test_stokes_limit_with_wall_factor():
    lam = 0.3
    f = (1 + (lam / 0.29) ** 1.5) / (1 - lam**1.5)
    u = np.array([1e-7, -2e-7])  # Re ~ 1e-5
    got = drag_force(u, R, ETA, RHO, lam)
    np.testing.assert_allclose(got, -6 * math.pi * ETA * R * f * u, rtol=1e-2, atol=0)


def test_zero_at_zero_relative_velocity_and_continuous():
    assert np.all(drag_force([0.0, 0.0], R, ETA, RHO, 0.2) == 0.0)
    small = drag_force([1e-12, 0.0], R, ETA, RHO, 0.2)
    assert abs(small[0]) < 1e-15


def test_matches_paper_form_at_moderate_reynolds():
    # eq. (11) written literally: F = -rho/2 |f u|^2 A C_d(Re_inf) u/|u|, Re_inf = 2 r rho |f u| / eta
    lam, u = 0.2, np.array([0.03, 0.01])
    f = (1 + (lam / 0.29) ** 1.5) / (1 - lam**1.5)
    speed = math.hypot(*u)
    re = 2 * R * RHO * f * speed / ETA
    cd = 24 / re + 6 / (1 + math.sqrt(re)) + 0.4
    expected = -0.5 * RHO * (f * speed) ** 2 * math.pi * R**2 * cd * u / speed
    np.testing.assert_allclose(drag_force(u, R, ETA, RHO, lam), expected, rtol=1e-12, atol=1e-20)


def test_opposes_relative_velocity_for_many_directions():
    rng = np.random.default_rng(0)
    u = rng.normal(size=(50, 2)) * 0.05
    f = drag_force(u, R, ETA, RHO, 0.1)
    assert np.all(np.sum(f * u, axis=1) < 0)
    np.testing.assert_allclose(f[:, 0] * u[:, 1] - f[:, 1] * u[:, 0], 0.0, atol=1e-18)


@pytest.mark.parametrize(
    ("args", "exc", "match"),
    [
        (([float("nan"), 0.0], R, ETA, RHO, 0.1), ModelInputError, "u_rel must be finite"),
        (([0.0, 0.0, 0.0], R, ETA, RHO, 0.1), ModelInputError, r"u_rel must have shape \(..., 2\)"),
        (([0.0, 0.0], -R, ETA, RHO, 0.1), ConfigError, "radius_m must be finite and > 0"),
        (([0.0, 0.0], R, ETA, RHO, 1.0), ConfigError, r"lambda = 2 r / D\) must be in \[0, 1\)"),
    ],
)
def test_errors(args, exc, match):
    with pytest.raises(exc, match=match):
        drag_force(*args)
