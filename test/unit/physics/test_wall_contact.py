"""Tests of the Hertz contact (15)-(16) and its explicit state."""

import math

import pytest

from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.wall_contact import (
    FREE,
    LOADING,
    UNLOADING,
    ContactState,
    contact_force_magnitude,
    hertz_stiffness,
    update_contact_state,
)

K = (4 * math.sqrt(250e-6) / 3) / ((1 - 0.27**2) / 1e9 + (1 - 0.2**2) / 1e9)


def test_stiffness_table3():
    assert float(hertz_stiffness(250e-6, 1e9, 0.27, 1e9, 0.2)) == pytest.approx(K, rel=1e-14)
    assert K == pytest.approx(1.117e7, rel=1e-3)


def test_loading_law_and_continuity_at_zero():
    d = 1e-7
    assert float(contact_force_magnitude(d, LOADING, 0, 0, 0, K, 2.0)) == pytest.approx(K * d**1.5)
    assert float(contact_force_magnitude(0.0, LOADING, 0, 0, 0, K, 2.0)) == 0.0
    assert float(contact_force_magnitude(-1e-6, FREE, 0, 0, 0, K, 2.0)) == 0.0
    assert float(contact_force_magnitude(1e-15, FREE, 0, 0, 0, K, 2.0)) < 1e-15


def test_unloading_law_hand_value_and_continuity_at_delta_max():
    dmax, d0, p = 2e-7, 2e-8, 2.0
    fmax = K * dmax**1.5
    d = 1e-7
    expected = fmax * ((d - d0) / (dmax - d0)) ** p
    assert float(contact_force_magnitude(d, UNLOADING, dmax, fmax, d0, K, p)) == pytest.approx(expected, rel=1e-12)
    assert float(contact_force_magnitude(dmax, UNLOADING, dmax, fmax, d0, K, p)) == pytest.approx(fmax, rel=1e-12)
    assert float(contact_force_magnitude(d0, UNLOADING, dmax, fmax, d0, K, p)) == 0.0


def test_state_machine_cycle():
    s = ContactState()
    s = update_contact_state(s, -1e-6, K, 0.1)
    assert s == ContactState()
    s = update_contact_state(s, 1e-7, K, 0.1)
    assert s.phase == LOADING and s.delta_max_m == 1e-7 and s.force_max_N == pytest.approx(K * 1e-7**1.5)
    s = update_contact_state(s, 2e-7, K, 0.1)
    assert s.delta_max_m == 2e-7
    s = update_contact_state(s, 1.5e-7, K, 0.1)
    assert s.phase == UNLOADING and s.delta_0_m == pytest.approx(2e-8)
    s2 = update_contact_state(s, 3e-7, K, 0.1)
    assert s2.phase == LOADING and s2.delta_max_m == 3e-7
    s = update_contact_state(s, 1e-8, K, 0.1)
    assert s == ContactState()


def test_array_round_trip_and_errors():
    s = ContactState(2, 1e-7, 3e-4, 1e-8)
    assert ContactState.from_array(s.to_array()) == s
    with pytest.raises(ModelInputError, match="delta_m must be finite"):
        update_contact_state(s, float("nan"), K, 0.1)
