"""Tests of the wall band where the observer error is unstable and of the safe reference height."""

import numpy as np
import pytest

from vesselbot_ros.control.high_gain_observer import ObserverParams, linearised_error_matrix
from vesselbot_ros.control.reference_design import (
    _narrowest_time_s,
    observer_error_jacobian,
    observer_error_matrices,
    observer_unstable_gap_m,
    wall_safe_delta_m,
)
from vesselbot_ros.physics.kernel import accel_no_motive
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.vessels.cfd import packed_params

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


def _jacobian_one_by_one(physics: PhysicsParams, t: float, z: float, vx: float) -> np.ndarray:
    """The error matrix at one height as the scan first computed it: a Python state list per difference."""
    p, c = packed_params(physics), np.zeros(4)
    state = [0.0, z, vx, 0.0]
    j = np.zeros((2, 4))
    for col, (idx, h) in enumerate(((0, 1e-9), (1, 1e-9), (2, 1e-6), (3, 1e-6))):
        sp, sm = list(state), list(state)
        sp[idx] += h
        sm[idx] -= h
        j[:, col] = (np.array(accel_no_motive(t, *sp, c, p)) - np.array(accel_no_motive(t, *sm, c, p))) / (2 * h)
    return linearised_error_matrix(OBS, j[:, :2], j[:, 2:])


@pytest.mark.parametrize("printed", [False, True])
def test_the_compiled_scan_is_the_per_gap_scan_bit_for_bit(printed: bool) -> None:
    """The stacked matrices are, at every height (the wall band included, where the wall forces are steep), the
    doubles of a matrix computed one height at a time, and the scan picks that per-gap scan's widest unstable gap."""
    phys = P.with_overrides({"interactions.electrostatic_model": "paper_printed"}) if printed else P
    half = 0.5 * 3e-3 * 0.9
    gaps = np.geomspace(1e-8, 1e-3, 120)
    z = half - 250e-6 - gaps
    t = _narrowest_time_s(phys)
    a = observer_error_matrices(phys, t, z, 0.01, OBS)
    one = [_jacobian_one_by_one(phys, t, float(zk), 0.01) for zk in z]
    for k in range(z.size):
        assert np.array_equal(a[k], one[k]), k
        assert np.array_equal(observer_error_jacobian(phys, t, float(z[k]), 0.01, OBS), one[k]), k
    worst = max((float(g) for g, ak in zip(gaps, one, strict=True) if np.max(np.linalg.eigvals(ak).real) > 0.0),
                default=0.0)
    assert observer_unstable_gap_m(phys, OBS, n=120) == worst > 0.0
