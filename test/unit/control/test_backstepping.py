"""Law (24) (vesselbot_ros.control.backstepping) on three axes: the planar rule, axis by axis, in one class."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vesselbot_ros.control.backstepping import BacksteppingController, BacksteppingGains, ControllerParams, backstepping_u
from vesselbot_ros.control.bspline_reference import RefSample
from vesselbot_ros.control.estimate import Estimate
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.scanner.input_mapping import input_matrix


class _FreeModel:
    """F = 0: the bead coasts (dims 2 or 3), B = b I."""

    def __init__(self, dims: int, b: float = 2.0) -> None:
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


def test_law_24_per_axis() -> None:
    prm = ControllerParams(gains=BacksteppingGains(k1=5.0, k2=10.0))
    m = _FreeModel(3, b=4.0)
    c = BacksteppingController(prm, m.F, m.input_matrix)
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
    c = BacksteppingController(prm, m.F, m.input_matrix, hold_period_s=1e-3)
    x, z = np.zeros(3), np.array([1e-3, 0.0, 0.0])
    ref = RefSample(np.zeros(3), np.zeros(3), np.zeros(3))
    cmd = c.command(0.0, Estimate(0.0, x, z, 0.0, np.zeros(3), True, False, 2.0), ref)
    s, cc, h = 15.0, 51.0, 0.5e-3
    a = -s * z
    f = m.F(h, x + h * z + 0.5 * h * h * a, z + h * a, 2.0)
    assert np.allclose(cmd.u_m_per_s2, a - f, rtol=1e-14) and cc == 51.0
    with pytest.raises(ModelInputError, match="flow scale"):
        c.command(0.0, Estimate(0.0, x, z, 0.0, np.zeros(3), True, False, 0.0), ref)


def test_law_24_hand_computed() -> None:
    k1, k2 = 5.0, 10.0
    x, z, f = np.array([1.0, 2.0]), np.array([0.5, -0.5]), np.array([0.1, 0.2])
    pr, vr, ar = np.array([1.5, 1.0]), np.array([0.0, 1.0]), np.array([0.3, 0.0])
    u = backstepping_u(k1, k2, x, z, f, pr, vr, ar)
    expected = ar + 15 * vr + 51 * pr - 51 * x - 15 * z - f
    np.testing.assert_allclose(u, expected, rtol=1e-15, atol=1e-12)


def test_exact_loop_error_decays_with_lyapunov_rate() -> None:
    # double integrator with F known exactly: e'' + 15 e' + 51 e = 0
    f = lambda t, x, z: -3.0 * z + 1.0  # noqa: E731
    ctrl = BacksteppingController(ControllerParams(), f, np.eye(2))
    x, z = np.array([1e-3, -2e-3]), np.zeros(2)
    dt = 1e-4
    e0 = np.linalg.norm(x)
    for k in range(20000):  # 2 s
        u = ctrl.command_arrays(k * dt, x, z, 0.0, np.zeros(2), np.zeros(2), np.zeros(2)).u_m_per_s2
        a = f(0, x, z) + u
        z = z + dt * a
        x = x + dt * z
    # slowest root -7.5 + sqrt(5.25) = -5.21 1/s: e(2 s) ~ e0 exp(-10.4) * O(1)
    assert np.linalg.norm(x) < 1e-3 * e0


def test_stale_estimate_safe_actions() -> None:
    f = lambda t, x, z: np.zeros(2)  # noqa: E731
    zero = BacksteppingController(ControllerParams(stale_timeout_s=0.1, stale_action="zero"), f, np.eye(2))
    cmd = zero.command_arrays(0.0, np.ones(2), np.zeros(2), 0.5, np.zeros(2), np.zeros(2), np.zeros(2))
    assert cmd.status == "stale"
    np.testing.assert_array_equal(cmd.gradient_T_per_m, [0.0, 0.0])
    hold = BacksteppingController(ControllerParams(stale_timeout_s=0.1, stale_action="hold"), f, np.eye(2))
    ok = hold.command_arrays(0.0, np.ones(2), np.zeros(2), 0.0, np.zeros(2), np.zeros(2), np.zeros(2))
    stale = hold.command_arrays(0.1, np.ones(2), np.zeros(2), math.inf, np.zeros(2), np.zeros(2), np.zeros(2))
    np.testing.assert_array_equal(stale.gradient_T_per_m, ok.gradient_T_per_m)


def test_controller_bad_input() -> None:
    f = lambda t, x, z: np.array([math.nan, 0.0])  # noqa: E731
    ctrl = BacksteppingController(ControllerParams(), f, np.eye(2))
    cmd = ctrl.command_arrays(0.0, np.zeros(2), np.zeros(2), 0.0, np.zeros(2), np.zeros(2), np.zeros(2))
    assert cmd.status == "nonfinite" and np.all(np.isfinite(cmd.gradient_T_per_m))
    with pytest.raises(ModelInputError, match="non-finite estimate"):
        ctrl.command_arrays(0.0, np.array([math.nan, 0.0]), np.zeros(2), 0.0, np.zeros(2), np.zeros(2), np.zeros(2))
    with pytest.raises(ModelInputError, match="invertible"):
        BacksteppingController(ControllerParams(), f, np.zeros((2, 2)))
    with pytest.raises(Exception, match=r"k1 must be > 0, got -1"):
        BacksteppingGains(k1=-1.0)


def test_midpoint_sample_hold_evaluates_F_at_mid_hold_state():
    from vesselbot_ros.control.backstepping import BacksteppingController, ControllerParams

    calls = []

    def f(t, x, z):
        calls.append((t, x.copy(), z.copy()))
        return np.array([2.0 * t, -1.0])

    T = 1e-3
    c = BacksteppingController(ControllerParams(sample_hold="midpoint"), f, np.eye(2), hold_period_s=T)
    x, z = np.array([1e-3, 2e-3]), np.array([0.01, -0.02])
    pr, vr, ar = np.array([1.1e-3, 2.0e-3]), np.array([0.012, 0.0]), np.array([0.1, 0.2])
    cmd = c.command_arrays(0.5, x, z, 0.0, pr, vr, ar)
    a = ar + 15.0 * vr + 51.0 * pr - 51.0 * x - 15.0 * z  # k1 = 5, k2 = 10
    h = T / 2
    t_mid, x_mid, z_mid = calls[-1]
    assert t_mid == pytest.approx(0.5 + h, abs=1e-15)
    np.testing.assert_allclose(x_mid, x + h * z + 0.5 * h * h * a, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(z_mid, z + h * a, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(cmd.u_m_per_s2, a - np.array([2.0 * (0.5 + h), -1.0]), rtol=1e-12, atol=1e-12)
    # 'none' (printed) evaluates F at the tick
    c0 = BacksteppingController(ControllerParams(), f, np.eye(2), hold_period_s=T)
    c0.command_arrays(0.5, x, z, 0.0, pr, vr, ar)
    assert calls[-1][0] == 0.5
    with pytest.raises(ModelInputError, match="hold_period_s"):
        BacksteppingController(ControllerParams(), f, np.eye(2), hold_period_s=-1.0)


def test_carried_wall_contact_drops_the_vertical_command_where_the_reference_rests_on_the_lower_wall() -> None:
    """``wall_contact: carried``: a reference on the lower wall leaves the weight and the wall to hold the bead
    (U z = 0, U x as printed); above the contact height the law is (24) as printed."""
    from vesselbot_ros.config import ConfigError
    from vesselbot_ros.control.model import DynamicsModel
    from vesselbot_ros.physics.kernel import diameter_at
    from vesselbot_ros.physics.params import VesselParams

    ph = PhysicsParams()
    model = DynamicsModel(ph)
    b = input_matrix(ph)
    printed = BacksteppingController(ControllerParams(), model.F, b)
    carried = BacksteppingController(ControllerParams(wall_contact="carried"), model.F, b)
    t = 0.3
    touch = -(0.5 * float(diameter_at(t, model.p)) - ph.robot.radius_m)
    est = dict(x_hat=np.array([1e-3, touch + 20e-6]), z_hat=np.array([2e-3, 0.0]), time_since_measurement_s=0.0,
               flow_scale=1.0)
    for z_ref, dropped in ((touch - 25e-6, True), (touch, True), (touch + 1e-6, False), (0.0, False)):
        args = (t, est["x_hat"], est["z_hat"], 0.0, np.array([1.2e-3, z_ref]), np.array([4.5e-3, 0.0]), np.zeros(2))
        a, c = printed.command_arrays(*args), carried.command_arrays(*args)
        assert c.u_m_per_s2[0] == a.u_m_per_s2[0]
        assert (c.u_m_per_s2[1] == 0.0) if dropped else (c.u_m_per_s2[1] == a.u_m_per_s2[1])
    with pytest.raises(ConfigError, match="needs the model's F"):  # a user's F: the law cannot see the wall
        BacksteppingController(ControllerParams(wall_contact="carried"), lambda t, x, z, s=1.0: np.zeros(2), b)
    assert VesselParams  # (the network and tree cases: the next test)


@pytest.mark.parametrize("network", ["straight_table3", "paper_iiic_artery_3d", "carotid_bifurcation_3d"])
def test_carried_wall_contact_finds_the_floor_of_a_network_and_of_a_3d_tree(network: str) -> None:
    """In a planar network and a 3-D tree the model's meshed wall says where the reference rests on a wall below
    it: on the floor the command's component along the floor's inward normal is dropped (the vertical one on a level
    floor), at the centre and under the roof the law is (24) as printed."""
    from vesselbot_ros.control.model import DynamicsModel
    from vesselbot_ros.physics.integrator import wall_frames
    from vesselbot_ros.physics.params import VesselParams

    ph = PhysicsParams(vessel=VesselParams(network=network))
    model = DynamicsModel(ph)
    d, r = model.dims, ph.robot.radius_m
    printed = BacksteppingController(ControllerParams(), model.F, model.input_matrix)
    carried = BacksteppingController(ControllerParams(wall_contact="carried"), model.F, model.input_matrix)
    # the inlet branch, along x at y = z = 0: (radius, an x on it)
    radius, x0 = (4.0e-3, -20e-3) if network.startswith("carotid") else (1.5e-3, 0.0)
    t = 0.3

    def at(z: float) -> np.ndarray:
        return np.array([x0, z] if d == 2 else [x0, 0.0, z])

    x_hat, z_hat = at(0.0), np.zeros(d)
    z_hat[0] = 2e-3
    for z_ref, dropped in ((-(radius - 0.5 * r), True), (0.0, False), (radius - 0.5 * r, False)):
        args = (t, x_hat, z_hat, 0.0, at(z_ref), np.eye(d)[0] * 4.5e-3, np.zeros(d))
        a, c = printed.command_arrays(*args), carried.command_arrays(*args)
        if not dropped:
            assert np.array_equal(c.u_m_per_s2, a.u_m_per_s2)
            continue
        # the command's component along the floor's inward normal (up, tilted by the facets) is the wall's: gone,
        # the rest as printed (the estimate is mid-lumen: the normal is the reference's wall's)
        _s, n, _d = (np.asarray(v) for v in wall_frames(np.array([t]), at(z_ref)[None, :], model.geom))
        n = n[0]
        assert n[-1] > 0.99
        assert abs(float(c.u_m_per_s2 @ n)) < 1e-12 * np.abs(a.u_m_per_s2).max() and a.u_m_per_s2 @ n != 0.0
        np.testing.assert_allclose(c.u_m_per_s2, a.u_m_per_s2 - (a.u_m_per_s2 @ n) * n, rtol=0, atol=1e-12)
