"""dB/dt limit as a coil slew limit: the closed-form fixed point, and what the coil does with it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vesselbot_ros.config import ConfigError, load_dataclass
from vesselbot_ros.scanner.actuator_limits import CoilLimiter, CoilLimits
from vesselbot_ros.scanner.hardware import (
    DbdtLimit,
    dbdt_at,
    dbdt_axis_slew_limit,
    effective_coil_limits,
    iec_normal_mode_dbdt,
)


@given(st.floats(0.01, 1.0), st.floats(0.05, 2.0))
@settings(max_examples=200, deadline=None)
def test_axis_slew_is_the_fixed_point_of_the_iec_limit(g_sat, radius):
    s = dbdt_axis_slew_limit(g_sat, radius)
    if math.isinf(s):  # the allowance grows faster with a shorter ramp than dB/dt does: no bound
        assert math.sqrt(2.0) * radius <= 16.0 * 0.36e-3 / g_sat
        return
    # dB/dt of a diagonal full-scale ramp at that slew, within radius r, equals the limit at that ramp time
    assert math.sqrt(2.0) * s * radius == pytest.approx(iec_normal_mode_dbdt(1e3 * g_sat / s), rel=1e-12)
    assert math.sqrt(2.0) * s * radius == pytest.approx(dbdt_at(DbdtLimit("iec_normal_mode", radius), g_sat, s),
                                                        rel=1e-12)


def test_clinical_numbers_by_hand():
    # 45 mT/m, r = 0.2 m: S = 16 / (0.2 sqrt 2 - 16 * 0.36e-3 / 0.045) = 16 / (0.28284 - 0.128) = 103.33 T/m/s
    assert dbdt_axis_slew_limit(0.045, 0.2) == pytest.approx(103.3307, rel=1e-5)
    assert dbdt_at(DbdtLimit("iec_normal_mode", 0.2), 0.045, 103.3307) == pytest.approx(29.226, rel=1e-4)
    assert dbdt_axis_slew_limit(0.4, 0.2) == pytest.approx(59.603, rel=1e-4)


def test_effective_limits_lower_the_slew_only_when_it_binds():
    coil = CoilLimits(saturation_T_per_m=0.045, slew_rate="custom", custom_slew_rate_T_per_m_per_s=200.0)
    assert effective_coil_limits(coil, DbdtLimit()) is coil  # off: the paper's coil
    eff = effective_coil_limits(coil, DbdtLimit("iec_normal_mode", 0.2))
    assert eff.slew_rate_T_per_m_per_s == pytest.approx(103.3307, rel=1e-5)
    assert eff.saturation_T_per_m == 0.045
    slow = CoilLimits(saturation_T_per_m=0.045, slew_rate="custom", custom_slew_rate_T_per_m_per_s=50.0)
    assert effective_coil_limits(slow, DbdtLimit("iec_normal_mode", 0.2)) is slow


@given(st.integers(0, 2**32 - 1))
@settings(max_examples=30, deadline=None)
def test_the_limited_coil_keeps_db_dt_within_the_limit(seed):
    """Random commands through the coil with the effective limits: r |dG|/dt <= the IEC limit at every step."""
    lim = DbdtLimit("iec_normal_mode", 0.2)
    eff = effective_coil_limits(CoilLimits(saturation_T_per_m=0.4, slew_rate="custom",
                                           custom_slew_rate_T_per_m_per_s=200.0), lim)
    allowed = dbdt_at(lim, eff.saturation_T_per_m, eff.slew_rate_T_per_m_per_s)
    rng = np.random.default_rng(seed)
    dt = 1e-3
    coil = CoilLimiter(eff, -dt)
    prev = np.zeros(2)
    for k in range(200):
        out = coil.apply(k * dt, rng.uniform(-1.0, 1.0, 2))
        assert lim.radius_m * float(np.hypot(*(out.applied - prev))) / dt <= allowed * (1 + 1e-12)
        prev = out.applied


def test_bad_values_name_the_key():
    with pytest.raises(ConfigError, match="dbdt.mode"):
        load_dataclass(DbdtLimit, {"mode": "iec"}, "dbdt")
    with pytest.raises(ConfigError, match="radius_m"):
        DbdtLimit("iec_normal_mode", 3.0)
    with pytest.raises(ConfigError, match="radius_m"):
        DbdtLimit("iec_normal_mode", -0.1)
