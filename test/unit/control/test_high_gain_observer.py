"""Tests of the sampled high-gain observer (25)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.high_gain_observer import (
    HighGainObserver,
    ObserverParams,
    axis_gains,
    linearised_error_matrix,
    sampled_error_radius,
)
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.scanner.imager_model import Measurement


class LinearDragModel:
    """Exact test model: Xd = Z, Zd = -c Z + u (free flow, drag only)."""

    def __init__(self, c: float = 50.0) -> None:
        self.c = c
        self.input_matrix = np.eye(2)

    def new_contact_state(self) -> np.ndarray:
        return np.zeros(4)

    def propagate(self, t0, t1, y, u, contact) -> None:  # type: ignore[no-untyped-def]
        n = 20
        h = (t1 - t0) / n
        for _ in range(n):  # RK4 of the linear system
            def f(s):  # type: ignore[no-untyped-def]
                return np.concatenate([s[2:], -self.c * s[2:] + u])
            k1 = f(y)
            k2 = f(y + 0.5 * h * k1)
            k3 = f(y + 0.5 * h * k2)
            k4 = f(y + h * k3)
            y += h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def test_table_iii_free_flow_roots() -> None:
    prm = ObserverParams()
    gx, gz = axis_gains(prm)
    np.testing.assert_array_equal(gx, [-6.0, -12.0])
    np.testing.assert_array_equal(gz, [-13.0, -4.0])
    eig = np.sort_complex(np.linalg.eigvals(linearised_error_matrix(prm)))
    # x: s^2 + 30 s + 325 -> -15 +/- 10j ; z: s^2 + 60 s + 100 -> -30 +/- sqrt(800)
    expected = np.sort_complex(np.array([-15 + 10j, -15 - 10j, -30 + math.sqrt(800), -30 - math.sqrt(800)]))
    np.testing.assert_allclose(eig, expected, atol=1e-9)
    assert np.all(eig.real < 0)


def test_wall_gradient_destabilises_linearised_error() -> None:
    prm = ObserverParams()
    c = 268.0  # drag / mass (1/s)
    jz = -c * np.eye(2)
    # z block determinant: L|gx| c + L^2 |gz| - dFz/dz = 60 c + 100 - dFz/dz
    threshold = 5 * 12 * c + 25 * 4
    stable = linearised_error_matrix(prm, np.diag([0.0, 0.9 * threshold]), jz)
    unstable = linearised_error_matrix(prm, np.diag([0.0, 1.1 * threshold]), jz)
    assert np.max(np.linalg.eigvals(stable).real) < 0
    assert np.max(np.linalg.eigvals(unstable).real) > 0


def test_sampled_radius() -> None:
    prm = ObserverParams()
    assert sampled_error_radius(prm, 1e-3) < 1.0
    assert sampled_error_radius(prm, 0.02) < 1.0  # 50 Hz MRI
    assert sampled_error_radius(prm, 0.1) > 1.0  # 10 Hz: unstable with Table III gains
    with pytest.raises(ConfigError, match="period must be > 0"):
        sampled_error_radius(prm, 0.0)


def _run(prm: ObserverParams, period_s: float, x0_err: float, t_end: float = 2.0) -> list[float]:
    model = LinearDragModel()
    truth = np.array([0.0, 1e-3, 0.0, 0.0])
    obs = HighGainObserver(prm, model, truth[:2] + x0_err, (0.0, 0.0))
    errs = []
    dt = 1e-3
    u = np.array([0.5, -0.2])
    every = int(round(period_s / dt))
    for k in range(1, int(t_end / dt) + 1):
        t = k * dt
        model.propagate(t - dt, t, truth, u, None)
        meas = Measurement(t, truth[:2].copy(), False) if k % every == 0 else None
        est = obs.update(t, meas, u)
        errs.append(float(np.linalg.norm(est.x_hat - truth[:2]) + np.linalg.norm(est.z_hat - truth[2:])))
    return errs


@pytest.mark.parametrize("period_s", [1e-3, 0.02])
def test_error_converges_in_free_flow(period_s: float) -> None:
    prm = ObserverParams(init_from_first_measurement=False)
    errs = _run(prm, period_s, 1e-4)
    assert errs[0] > 1e-5
    assert errs[-1] < 1e-3 * errs[0]


def test_higher_gain_converges_faster() -> None:
    slow = _run(ObserverParams(init_from_first_measurement=False), 1e-3, 1e-4, 0.5)
    fast = _run(ObserverParams(high_gain=10.0, init_from_first_measurement=False), 1e-3, 1e-4, 0.5)
    assert fast[-1] < slow[-1]


def test_non_finite_measurement_is_rejected_and_prediction_continues() -> None:
    obs = HighGainObserver(ObserverParams(), LinearDragModel(), (0.0, 1e-3))
    obs.update(0.0, Measurement(0.0, np.array([0.0, 1e-3]), False), np.zeros(2))
    est = obs.update(0.001, Measurement(0.001, np.array([math.nan, 0.0]), False), np.array([1.0, 0.0]))
    assert est.rejected and not est.used_measurement
    assert np.all(np.isfinite(est.x_hat)) and np.all(np.isfinite(est.z_hat))
    assert est.z_hat[0] > 0.0  # predicted under the applied input
    assert est.time_since_measurement_s == pytest.approx(0.001)
    assert obs.rejected == 1


def test_innovation_gate_rejects_outlier() -> None:
    obs = HighGainObserver(ObserverParams(innovation_gate_m=5e-4), LinearDragModel(), (0.0, 1e-3))
    obs.update(0.0, Measurement(0.0, np.array([0.0, 1e-3]), False), np.zeros(2))
    est = obs.update(0.001, Measurement(0.001, np.array([1e-3, 1e-3]), True), np.zeros(2))
    assert est.rejected
    np.testing.assert_allclose(est.x_hat, [0.0, 1e-3], atol=1e-12)


def test_bad_inputs() -> None:
    obs = HighGainObserver(ObserverParams(), LinearDragModel(), (0.0, 0.0))
    with pytest.raises(ModelInputError, match="applied gradient"):
        obs.update(0.001, None, [math.nan, 0.0])
    obs.update(0.002, None, [0.0, 0.0])
    with pytest.raises(ModelInputError, match="non-decreasing"):
        obs.update(0.001, None, [0.0, 0.0])
    with pytest.raises(ConfigError, match=r"g2 must be < 0"):
        ObserverParams(g2=1.0)
    with pytest.raises(ConfigError, match=r"high_gain must be > 0, got 0"):
        ObserverParams(high_gain=0.0)


# ---- three axes (a 3-D tree): one observer class, the axis count its data -----------------------------------------
class _FreeModel:
    """F = 0: the bead coasts (dims 2 or 3), B = b I; a user's model (runs the observer's Python path)."""

    def __init__(self, dims: int, b: float = 2.0) -> None:
        self.input_matrix = b * np.eye(dims)

    def new_contact_state(self) -> np.ndarray:
        return np.zeros(4)

    def propagate(self, t0, t1, y, u, contact):  # type: ignore[no-untyped-def]
        d = len(u)
        h = t1 - t0
        y[:d] = y[:d] + h * y[d:] + 0.5 * h * h * u
        y[d:] = y[d:] + h * u


def test_gains_on_three_axes_y_takes_the_transverse_pair() -> None:
    prm = ObserverParams()
    gx, gz = axis_gains(prm)
    g3x, g3z = axis_gains(prm, 3)
    assert list(g3x) == [gx[0], gx[1], gx[1]] and list(g3z) == [gz[0], gz[1], gz[1]]


def test_the_observer_on_three_axes_in_the_plane_is_the_observer_on_two() -> None:
    prm = ObserverParams(delay_compensation=True)
    o2 = HighGainObserver(prm, _FreeModel(2), [0.0, 1e-3], [0.0, 0.0])
    o3 = HighGainObserver(prm, _FreeModel(3), [0.0, 0.0, 1e-3], [0.0, 0.0, 0.0])
    rng = np.random.default_rng(0)
    for k in range(1, 300):
        t = k * 1e-3
        g = rng.normal(0, 0.05, 2)
        meas2 = meas3 = None
        if k % 20 == 0:
            y = rng.normal(0, 1e-4, 2) + [1e-5 * k, 1e-3]
            meas2 = Measurement(t - 2e-3, y, False)
            meas3 = Measurement(t - 2e-3, np.array([y[0], 0.0, y[1]]), False)
        e2 = o2.update(t, meas2, g)
        e3 = o3.update(t, meas3, np.array([g[0], 0.0, g[1]]))
        assert e3.x_hat[1] == 0.0 and e3.z_hat[1] == 0.0
        assert e3.x_hat[0] == e2.x_hat[0] and e3.x_hat[2] == e2.x_hat[1]  # bit for bit
        assert e3.z_hat[0] == e2.z_hat[0] and e3.z_hat[2] == e2.z_hat[1]
        assert e3.time_since_measurement_s == e2.time_since_measurement_s and e3.used_measurement == e2.used_measurement


def test_the_observer_on_three_axes_converges_on_y_and_rejects_bad_frames() -> None:
    o3 = HighGainObserver(ObserverParams(innovation_gate_m=2e-3), _FreeModel(3), [0.0, 0.0, 0.0])
    est = None
    for k in range(1, 3000):
        t = k * 1e-3
        est = o3.update(t, Measurement(t, np.array([0.0, 5e-4, 0.0]), False), np.zeros(3))
    assert est is not None and abs(est.x_hat[1] - 5e-4) < 1e-6
    e = o3.update(3.0, Measurement(3.0, np.array([0.0, 5e-3, 0.0]), False), np.zeros(3))  # beyond the gate
    assert e.rejected and not e.used_measurement
    e = o3.update(3.001, Measurement(3.001, np.array([np.nan, 0.0, 0.0]), False), np.zeros(3))
    assert e.rejected and o3.rejected == 2
    with pytest.raises(ModelInputError, match=r"\(3,\)"):
        o3.update(3.002, None, np.zeros(2))
