"""Tests of eq. (14)."""

import math

import pytest

from vesselbot_ros.physics.apparent_weight import apparent_weight_z, sphere_volume


def test_table3_apparent_weight():
    vol = 4 / 3 * math.pi * (250e-6) ** 3
    assert float(sphere_volume(250e-6)) == pytest.approx(vol, rel=1e-14)
    rho = 0.8 * 7874 + 0.2 * 1500
    w = float(apparent_weight_z(vol, rho, 1060.0, 9.81))
    assert w == pytest.approx(-vol * (rho - 1060) * 9.81, rel=1e-14)
    assert w == pytest.approx(-3.556e-6, rel=1e-3)
    assert float(apparent_weight_z(vol, 1000.0, 1060.0, 9.81)) > 0  # lighter than blood: floats up
