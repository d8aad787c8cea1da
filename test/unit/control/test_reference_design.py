"""Tests of the wall band where the observer error is unstable and of the safe reference height."""

import numpy as np
import pytest

from vesselbot_ros.control.high_gain_observer import ObserverParams
from vesselbot_ros.control.reference_design import observer_error_jacobian, observer_unstable_gap_m, wall_safe_delta_m
from vesselbot_ros.physics.params import PhysicsParams

P = PhysicsParams()
OBS = ObserverParams()


def test_centre_is_stable_and_free_flow_eigenvalues_match_gains():
    a = observer_error_jacobian(P, 0.75, 0.0, 0.01, OBS)
    assert np.max(np.linalg.eigvals(a).real) < 0.0


def test_band_widens_with_printed_electrostatics_and_safe_delta_formula():
    band = observer_unstable_gap_m(P, OBS, n=300)
    printed = observer_unstable_gap_m(P.with_overrides({"interactions.electrostatic_model": "paper_printed"}), OBS, n=300)
    assert 10e-6 < band < printed < 1e-3
    # unstable at the widest unstable gap found, stable well outside it
    half = 0.5 * 3e-3 * 0.9
    t = 0.5  # sin(2 pi t + pi/2) = -1: narrowest diameter
    inside = observer_error_jacobian(P, t, half - 250e-6 - band, 0.01, OBS)  # widest unstable gap
    outside = observer_error_jacobian(P, t, half - 250e-6 - 2.0 * band, 0.01, OBS)
    assert np.max(np.linalg.eigvals(inside).real) > 0.0
    assert np.max(np.linalg.eigvals(outside).real) < 0.0
    d = wall_safe_delta_m(P, OBS, 150e-6)
    assert d == pytest.approx(half - 250e-6 - observer_unstable_gap_m(P, OBS) - 150e-6, rel=1e-12)
