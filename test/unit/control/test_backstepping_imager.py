"""Tests of the backstepping law (24) and the imager model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vesselbot_ros.control.backstepping import BacksteppingController, BacksteppingGains, ControllerParams, backstepping_u
from vesselbot_ros.control.imager_model import ImagerModel, ImagerParams, OutlierBurst
from vesselbot_ros.control.input_mapping import input_matrix
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.params import PhysicsParams


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


def test_input_mapping_tau_m() -> None:
    phys = PhysicsParams()
    rho = 0.8 * 7874 + 0.2 * 1500
    b = input_matrix(phys, "with_tau_m")
    np.testing.assert_allclose(b, 0.8 * 1.72e6 / rho * np.eye(2), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(input_matrix(phys, "paper_printed"), 1.72e6 / rho * np.eye(2), rtol=1e-12, atol=1e-9)


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


def _frames(prm: ImagerParams, seed: int, n: int = 200, dt: float = 1e-3) -> list:
    im = ImagerModel(prm, np.random.default_rng(seed))
    return [im.frame(k * dt, np.array([0.0, 1e-3])) for k in range(n)]


def test_imager_rate_latency_and_noise_sigma() -> None:
    frames = _frames(ImagerParams(frame_rate_Hz=50.0, latency_s=0.005), 0)
    got = [(k, f) for k, f in enumerate(frames) if f is not None]
    assert [k for k, _ in got] == [5, 25, 45, 65, 85, 105, 125, 145, 165, 185]
    assert [f.t_acq_s for _, f in got] == pytest.approx([0.0, 0.02, 0.04, 0.06, 0.08, 0.1, 0.12, 0.14, 0.16, 0.18])
    im = ImagerModel(ImagerParams(frame_rate_Hz=1000.0), np.random.default_rng(1))
    z = np.array([im.frame(k * 1e-3, np.zeros(2)).p for k in range(4000)])
    assert np.std(z) == pytest.approx(100e-6, rel=0.05)  # sigma, not a bound
    assert abs(np.mean(z)) < 5e-6


def test_imager_outliers_dropouts_and_draw_order() -> None:
    base = ImagerParams(frame_rate_Hz=1000.0)
    clean = _frames(base, 7)
    burst = _frames(ImagerParams(frame_rate_Hz=1000.0, outliers=(OutlierBurst(0.05, 0.01, 1e-3),)), 7)
    for k, (a, b) in enumerate(zip(clean, burst)):
        if 50 <= k < 60:
            assert b.outlier
            assert np.linalg.norm(b.p - a.p) == pytest.approx(1e-3, rel=1e-9)
        else:  # outliers do not shift the noise of other frames
            np.testing.assert_array_equal(a.p, b.p)
    im = ImagerModel(base, np.random.default_rng(7))
    im.inject_dropout(0.05, 0.01)
    im.inject_outliers(0.1, 0.005, 2e-3)
    out = [im.frame(k * 1e-3, np.array([0.0, 1e-3])) for k in range(200)]
    assert all(out[k] is None for k in range(50, 60))
    assert all(out[k].outlier for k in range(100, 105))
    np.testing.assert_array_equal(out[150].p, clean[150].p)
    with pytest.raises(ModelInputError, match="true position must be a finite"):
        im.frame(0.3, np.array([math.nan, 0.0]))


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


def _burst_offsets(burst: OutlierBurst, seed: int = 3) -> tuple[np.ndarray, list[np.ndarray]]:
    im = ImagerModel(ImagerParams(noise_sigma_m=1e-5, frame_rate_Hz=1000.0, outliers=(burst,)), np.random.default_rng(seed))
    ref = ImagerModel(ImagerParams(noise_sigma_m=1e-5, frame_rate_Hz=1000.0), np.random.default_rng(seed))
    offsets, clean = [], []
    for k in range(40):
        t = k * 1e-3
        a, b = im.frame(t, [0.0, 0.0]), ref.frame(t, [0.0, 0.0])
        (offsets if a.outlier else clean).append(a.p - b.p)
    return np.array(offsets), clean


def test_outlier_direction_is_an_option_fixed_offset_or_random_per_frame() -> None:
    fixed, clean = _burst_offsets(OutlierBurst(0.01, 0.02, 1e-3, direction="fixed", angle_rad=math.pi / 2))
    assert fixed.shape == (20, 2)
    np.testing.assert_allclose(fixed, np.tile([0.0, 1e-3], (20, 1)), rtol=0, atol=1e-15)  # the same offset, +z
    assert all(np.array_equal(c, [0.0, 0.0]) for c in clean)  # the noise stream is not shifted
    rnd, _ = _burst_offsets(OutlierBurst(0.01, 0.02, 1e-3, direction="random_per_frame"))
    np.testing.assert_allclose(np.linalg.norm(rnd, axis=1), 1e-3, rtol=1e-12)
    assert len({round(math.atan2(z, x), 6) for x, z in rnd}) == 20  # a new direction every frame
    with pytest.raises(Exception, match="direction must be one of"):
        OutlierBurst(direction="sideways")  # type: ignore[arg-type]


def test_paper_scenarios_default_to_a_fixed_outlier_offset() -> None:
    from pathlib import Path

    from vesselbot_ros.sim.scenario import load_scenario

    for name in ("paper_small_artery", "sound_small_artery"):
        sc = load_scenario(Path(__file__).resolve().parents[3] / "config" / f"{name}.yaml")
        assert [(o.direction, o.angle_rad) for o in sc.imager.outliers] == [("fixed", 0.0)], name


def test_variate_buffer_draws_the_generators_stream_and_gives_it_back_where_it_was_used_up_to():
    from vesselbot_ros.control.imager_model import VariateBuffer, fill_variates

    direct = np.random.default_rng(7)
    expected = np.zeros(1 + 4 * 300)
    fill_variates(direct, expected, 2)  # 300 acquisitions straight from the generator
    buffered = VariateBuffer(np.random.default_rng(7))
    got = []
    for _ in range(300):  # more than one block
        b = buffered.ready()
        i = int(b[0])
        got.extend(b[i + 1:i + 5])
        b[0] = i + 4  # what the compiled next_normal / next_uniform do, four times
    assert np.array_equal(np.array(got), expected[1:])
    # the generator comes back exactly where 300 acquisitions left it, whatever was drawn ahead
    assert buffered.generator().random() == direct.random()


def test_the_imager_per_tick_and_its_generator_handed_on_continue_one_stream():
    from vesselbot_ros.control.imager_model import fill_variates

    params = ImagerParams(frame_rate_Hz=1000.0, noise_sigma_m=1e-4, latency_s=0.0)
    a = ImagerModel(params, np.random.default_rng(3))
    b = ImagerModel(params, np.random.default_rng(3))
    p = np.array([1e-3, 2e-4])
    for k in range(10):
        assert a.frame(k * 1e-3, p).p.tolist() == b.frame(k * 1e-3, p).p.tolist()
    a_next = a.rng.standard_normal()
    b.frame(10e-3, p)  # b draws one more acquisition: two normals first
    ref = np.random.default_rng(3)
    fill_variates(ref, np.zeros(1 + 4 * 10), 2)
    assert a_next == ref.standard_normal()


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
    with pytest.raises(ConfigError, match="straight vessel"):
        net = PhysicsParams(vessel=VesselParams(network="paper_iiic_artery"))
        BacksteppingController(ControllerParams(wall_contact="carried"), DynamicsModel(net).F, input_matrix(net))
    with pytest.raises(ConfigError, match="straight vessel"):  # a user's F: the law cannot see the wall
        BacksteppingController(ControllerParams(wall_contact="carried"), lambda t, x, z, s=1.0: np.zeros(2), b)
