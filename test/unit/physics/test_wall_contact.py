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


def test_reloading_beyond_delta_max_follows_loading_law_continuously():
    # state says UNLOADING (delta_max = 2e-7) but an integrator stage probes deeper:
    # the force must re-load along (15), continuous at delta_max, never extrapolate (16)
    dmax, d0, p = 2e-7, 2e-8, 2.0
    fmax = K * dmax**1.5
    for d in (2.0000001e-7, 3e-7, 1e-6, 1e-5):
        f = float(contact_force_magnitude(d, UNLOADING, dmax, fmax, d0, K, p))
        assert f == pytest.approx(K * d**1.5, rel=1e-12)
    below = float(contact_force_magnitude(dmax * (1 - 1e-9), UNLOADING, dmax, fmax, d0, K, p))
    above = float(contact_force_magnitude(dmax * (1 + 1e-9), UNLOADING, dmax, fmax, d0, K, p))
    assert above == pytest.approx(below, rel=1e-8)
    # the extrapolated unloading law would have been ((1e-5 - d0)/(dmax - d0))^2 ~ 3e3 x F_max
    extrapolated = fmax * ((1e-5 - d0) / (dmax - d0)) ** p
    assert float(contact_force_magnitude(1e-5, UNLOADING, dmax, fmax, d0, K, p)) < extrapolated / 5.0


def test_unloading_is_bounded_by_loading_law():
    import numpy as np

    dmax, d0 = 2e-7, 2e-8
    fmax = K * dmax**1.5
    d = np.linspace(-1e-7, 5e-7, 601)
    for p in (1.5, 2.0, 2.5):
        f = contact_force_magnitude(d, UNLOADING, dmax, fmax, d0, K, p)
        assert np.all(f <= K * np.maximum(d, 0.0) ** 1.5 * (1 + 1e-12) + 1e-30)
        assert np.all(np.isfinite(f)) and np.all(f >= 0.0)
