"""Observer (25) and law (24) on three axes (vesselbot_ros.control.loop3d_stages): the planar rules, axis by axis."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vesselbot_ros.control.backstepping import BacksteppingGains, ControllerParams, backstepping_u
from vesselbot_ros.control.bspline_reference import RefSample
from vesselbot_ros.control.estimate import Estimate
from vesselbot_ros.control.high_gain_observer import HighGainObserver, ObserverParams, axis_gains
from vesselbot_ros.control.imager_model import Measurement
from vesselbot_ros.control.loop3d_stages import Backstepping3D, HighGainObserver3D, axis_gains3d
from vesselbot_ros.errors import ModelInputError


class _FreeModel:
    """F = 0: the bead coasts (dims 2 or 3), B = b I."""

    def __init__(self, dims: int, b: float = 2.0) -> None:
        self.input_gain = b
        self.input_matrix = b * np.eye(dims)
        self.stats = np.zeros(4, dtype=np.int64)

    def new_contact_state(self) -> np.ndarray:
        return np.zeros(4)

    def propagate(self, t0, t1, y, u, contact):  # type: ignore[no-untyped-def]
        d = len(u)
        h = t1 - t0
        y[:d] = y[:d] + h * y[d:] + 0.5 * h * h * u
        y[d:] = y[d:] + h * u

    def F(self, t, x, z, flow_scale=1.0):  # type: ignore[no-untyped-def]
        return -0.5 * np.asarray(z) * flow_scale


def test_gains_y_takes_the_transverse_pair() -> None:
    prm = ObserverParams()
    gx, gz = axis_gains(prm)
    g3x, g3z = axis_gains3d(prm)
    assert list(g3x) == [gx[0], gx[1], gx[1]] and list(g3z) == [gz[0], gz[1], gz[1]]


def test_observer_in_the_plane_is_the_planar_observer() -> None:
    prm = ObserverParams(delay_compensation=True)
    o2 = HighGainObserver(prm, _FreeModel(2), [0.0, 1e-3], [0.0, 0.0])
    o3 = HighGainObserver3D(prm, _FreeModel(3), [0.0, 0.0, 1e-3], [0.0, 0.0, 0.0])
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


def test_observer_converges_on_y_and_rejects_bad_frames() -> None:
    o3 = HighGainObserver3D(ObserverParams(innovation_gate_m=2e-3), _FreeModel(3), [0.0, 0.0, 0.0])
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


def test_law_24_per_axis() -> None:
    prm = ControllerParams(gains=BacksteppingGains(k1=5.0, k2=10.0))
    m = _FreeModel(3, b=4.0)
    c = Backstepping3D(prm, m)
    x, z = np.array([1e-3, 2e-4, -3e-4]), np.array([1e-3, 0.0, -2e-3])
    ref = RefSample(np.array([2e-3, 0.0, 0.0]), np.array([4e-3, 1e-4, 0.0]), np.array([0.0, 0.0, 1e-2]))
    cmd = c.command(0.0, Estimate(0.0, x, z, 0.0, np.zeros(3), True, False), ref)
    u_ref = backstepping_u(5.0, 10.0, x, z, m.F(0.0, x, z), ref.p, ref.v, ref.a)
    assert cmd.status == "ok" and np.allclose(cmd.u_m_per_s2, u_ref, rtol=1e-14, atol=0)
    assert np.allclose(cmd.gradient_T_per_m, u_ref / 4.0, rtol=1e-14)
    stale = c.command(0.0, Estimate(0.0, x, z, 1.0, np.zeros(3), False, False), ref)
    assert stale.status == "stale" and not stale.gradient_T_per_m.any()
    with pytest.raises(ModelInputError, match="non-finite estimate"):
        c.command(0.0, Estimate(0.0, np.array([math.nan, 0, 0]), z, 0.0, np.zeros(3), True, False), ref)


def test_law_midpoint_and_flow_compensation_use_the_model() -> None:
    prm = ControllerParams(sample_hold="midpoint", flow_compensation="estimate")
    m = _FreeModel(3)
    c = Backstepping3D(prm, m, hold_period_s=1e-3)
    x, z = np.zeros(3), np.array([1e-3, 0.0, 0.0])
    ref = RefSample(np.zeros(3), np.zeros(3), np.zeros(3))
    cmd = c.command(0.0, Estimate(0.0, x, z, 0.0, np.zeros(3), True, False, 2.0), ref)
    s, cc, h = 15.0, 51.0, 0.5e-3
    a = -s * z
    f = m.F(h, x + h * z + 0.5 * h * h * a, z + h * a, 2.0)
    assert np.allclose(cmd.u_m_per_s2, a - f, rtol=1e-14) and cc == 51.0
    with pytest.raises(ModelInputError, match="flow scale"):
        c.command(0.0, Estimate(0.0, x, z, 0.0, np.zeros(3), True, False, 0.0), ref)
