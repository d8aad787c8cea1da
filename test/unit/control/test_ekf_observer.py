"""Extended Kalman observer: flow-scale estimate, chi-square gate, delay compensation, robustness."""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
import pytest

from vesselbot_ros.analysis.scanner_study import StudyCell, cell_scenario
from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.ekf_observer import ExtendedKalmanObserver, gate_on_axes
from vesselbot_ros.control.ekf_params import CHI2_2DOF_999, EkfParams
from vesselbot_ros.control.model import DynamicsModel
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.scanner.imager_model import Measurement
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.plant import PlantSimulator
from vesselbot_ros.sim.scenario import load_scenario, scenario_from_mapping, scenario_with, shipped_scenarios

EKF_SCENARIO = load_scenario(shipped_scenarios()["sound_small_artery_ekf"])
TRUE_SCALE = 0.025 / 0.02625  # the plant's V_f over the model's (the paper's 5 % error)


def _meas(t_acq: float, p: tuple[float, float]) -> Measurement:
    return Measurement(t_acq, np.array(p), False)


def test_chi2_quantile() -> None:
    assert CHI2_2DOF_999 == pytest.approx(13.8155, abs=1e-4)


def test_params_are_validated() -> None:
    with pytest.raises(ConfigError, match="measurement_sigma_m must be > 0"):
        EkfParams(measurement_sigma_m=0.0)
    with pytest.raises(ConfigError, match="gate_chi2"):
        EkfParams(gate_chi2=-1.0)
    with pytest.raises(ConfigError, match=r"max_rejection_s must be >= 0"):
        EkfParams(max_rejection_s=-0.1)
    with pytest.raises(ConfigError, match=r"flung_restart_sigmas must be finite, got nan"):
        EkfParams(flung_restart_sigmas=float("nan"))
    from vesselbot_ros.config import to_mapping

    assert "flung_restart_sigmas" not in to_mapping(EkfParams())  # off: every scenario's hash as it was
    assert to_mapping(EkfParams(flung_restart_sigmas=5.0))["flung_restart_sigmas"] == 5.0
    with pytest.raises(ConfigError, match=r"wall_constraint_sigma_m must be >= 0"):
        EkfParams(wall_constraint_sigma_m=-1e-6)
    assert "wall_constraint_sigma_m" not in to_mapping(EkfParams())
    assert to_mapping(EkfParams(wall_constraint_sigma_m=5e-6))["wall_constraint_sigma_m"] == 5e-6


@pytest.mark.parametrize("seed", [0, 1])
def test_closed_loop_estimates_the_flow_scale_and_gates_the_outliers(seed: int) -> None:
    ts = run_closed_loop(EKF_SCENARIO, seed).timeseries
    s_hat = ts["flow_scale_hat"]
    late = ts["t_s"] >= 0.6
    assert np.all(np.abs(s_hat[late] - TRUE_SCALE) < 0.03), (s_hat[late].min(), s_hat[late].max())
    assert abs(float(np.mean(s_hat[late])) - TRUE_SCALE) < 0.01  # the 5 % model error is seen and removed
    outlier, rejected = ts["meas_outlier"], ts["meas_rejected"]
    assert outlier.sum() == 20 and (outlier & rejected).sum() == 20  # every aberrant frame refused
    assert (rejected & ~outlier).sum() <= 6  # 99.9 % gate: about 2 of 2000 clean frames expected
    assert np.all(np.isfinite(ts["x_hat"])) and np.all(np.isfinite(ts["z_hat"]))


def test_delayed_frame_gives_the_state_of_the_on_time_frame() -> None:
    """A frame fused 20 ticks late, by correction at t_acq and re-prediction, equals on-time fusion.

    Equal up to the prediction's integration error: the late filter re-predicts
    with its own adaptive step sizes, so the integrator runs at a tight tolerance here.
    """
    tight = dataclasses.replace(EKF_SCENARIO.sim.integrator, rtol=1e-11, atol_position_m=1e-15,
                                atol_velocity_m_per_s=1e-13)
    model_a = DynamicsModel(EKF_SCENARIO.model_physics(), tight)
    model_b = DynamicsModel(EKF_SCENARIO.model_physics(), tight)
    params = EkfParams()
    a = ExtendedKalmanObserver(params, model_a, (0.0, 1e-3), tick_s=1e-3)
    b = ExtendedKalmanObserver(params, model_b, (0.0, 1e-3), tick_s=1e-3)
    rng = np.random.default_rng(3)
    # about the gradient that holds the bead against gravity: it stays in free flow (no stiff wall contact)
    gradients = np.column_stack([np.full(200, 0.01), np.full(200, 0.035)]) + rng.uniform(-0.003, 0.003, size=(200, 2))
    plant = PlantSimulator(EKF_SCENARIO.physics, EKF_SCENARIO.sim.integrator, 1e-3, (0.0, 1e-3), (0.0, 0.0))
    truth = []
    for k in range(200):
        truth.append(plant.output().p.copy())
        plant.step(gradients[k])
    assert max(abs(p[1]) for p in truth) < 1.05e-3  # far from the walls at +-1.25 mm
    frames = {k: (k * 1e-3, (truth[k][0] + rng.normal(0, 1e-4), truth[k][1] + rng.normal(0, 1e-4)))
              for k in range(0, 200, 40)}
    gradients = np.vstack([np.zeros((1, 2)), gradients])  # applied since the previous tick
    for k in range(200):
        t = k * 1e-3
        g = gradients[k]
        fa = _meas(*frames[k]) if k in frames else None
        late = k - 20
        fb = _meas(*frames[late]) if late in frames and late > 0 else (_meas(*frames[0]) if k == 0 else None)
        ea = a.update(t, fa, g)
        eb = b.update(t, fb, g)
        if k >= 20 and (k - 20) % 40 == 0:  # b just fused the frame a fused 20 ticks ago
            np.testing.assert_allclose(eb.x_hat, ea.x_hat, rtol=0, atol=1e-9)
            np.testing.assert_allclose(eb.z_hat, ea.z_hat, rtol=0, atol=1e-7)
            assert eb.flow_scale == pytest.approx(ea.flow_scale, rel=0, abs=1e-9)
            np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-6, atol=1e-16)
    assert b.rejected == 0 and a.rejected == 0 and abs(eb.flow_scale - 1.0) > 1e-6  # frames were used


def test_never_non_finite_when_latency_is_not_compensated() -> None:
    """Regression: 25 frames/s, 20 ms latency, no compensation drove the robot to a wall and the EKF to NaN."""
    m = copy.deepcopy(EKF_SCENARIO.to_mapping())
    m["imager"].update(frame_rate_Hz=25.0, latency_s=0.02)
    m["observer"]["ekf"]["delay_compensation"] = False
    ts = run_closed_loop(scenario_from_mapping(m), 0).timeseries
    assert np.all(np.isfinite(ts["x_hat"])) and np.all(np.isfinite(ts["flow_scale_hat"]))


def test_bad_frames_are_rejected_without_moving_the_state() -> None:
    model = DynamicsModel(EKF_SCENARIO.model_physics(), EKF_SCENARIO.sim.integrator)
    obs = ExtendedKalmanObserver(EkfParams(), model, (0.0, 1e-3), tick_s=1e-3)
    obs.update(0.0, _meas(0.0, (0.0, 1e-3)), np.zeros(2))
    before = obs.state
    for bad in (_meas(1e-3, (math.nan, 0.0)), _meas(5.0, (0.0, 1e-3)), _meas(math.inf, (0.0, 1e-3))):
        e = obs.update(1e-3, bad, np.zeros(2))
        assert e.rejected and not e.used_measurement
    after = obs.update(1e-3, None, np.zeros(2))
    assert np.all(np.isfinite(after.x_hat))
    assert obs.rejected == 3
    with pytest.raises(ModelInputError, match="non-decreasing"):
        obs.update(0.0, None, np.zeros(2))
    with pytest.raises(ModelInputError, match="applied gradient"):
        obs.update(2e-3, None, np.array([math.nan, 0.0]))
    assert before.shape == (5,)


def test_track_restarts_after_too_many_rejections() -> None:
    model = DynamicsModel(EKF_SCENARIO.model_physics(), EKF_SCENARIO.sim.integrator)
    obs = ExtendedKalmanObserver(EkfParams(max_consecutive_rejections=3), model, (0.0, 1e-3), tick_s=1e-3)
    obs.update(0.0, _meas(0.0, (0.0, 1e-3)), np.zeros(2))
    far = (0.0, -1e-3)  # 2 mm away: gated
    for k in range(1, 4):
        assert obs.update(k * 1e-3, _meas(k * 1e-3, far), np.zeros(2)).rejected
    e = obs.update(4e-3, _meas(4e-3, far), np.zeros(2))
    assert e.used_measurement and obs.track_resets == 1
    np.testing.assert_allclose(e.x_hat, far, rtol=0, atol=1e-12)


@pytest.mark.parametrize("projection", ["none", "lumen"])
def test_wall_projection_puts_an_estimate_inside_the_wall_back_one_brush_length_from_it(projection: str) -> None:
    """A frame below the lower wall (noise, the bead resting on it): with ``lumen`` the corrected estimate sits
    one brush length L0 from the wall with no velocity into it; with ``none`` the correction is left in the wall."""
    from vesselbot_ros.physics.kernel import diameter_at

    ph = EKF_SCENARIO.model_physics()
    model = DynamicsModel(ph, EKF_SCENARIO.sim.integrator)
    r, l0 = ph.robot.radius_m, ph.interactions.brush_length_m
    wall = -(0.5 * float(diameter_at(0.0, model.p)) - r)  # the centre of a bead touching the lower wall at t = 0
    obs = ExtendedKalmanObserver(dataclasses.replace(EkfParams(), wall_projection=projection), model,
                                 (0.0, wall + 50e-6), tick_s=1e-3)
    obs.update(0.0, _meas(0.0, (0.0, wall + 50e-6)), np.zeros(2))
    e = obs.update(0.0, _meas(0.0, (0.0, wall - 300e-6)), np.zeros(2))
    assert e.used_measurement
    if projection == "lumen":
        assert e.x_hat[1] == pytest.approx(wall + l0, abs=1e-12) and e.z_hat[1] >= 0.0
    else:
        assert e.x_hat[1] < wall


def _resting_filters(height_above_wall_m: float) -> dict[float, ExtendedKalmanObserver]:
    """Two filters (``wall_constraint_sigma_m`` 0 and 5 um, ``wall_projection: lumen``) that fused one frame of a bead
    ``height_above_wall_m`` above the straight vessel's lower wall and predicted one tick under no gradient."""
    from vesselbot_ros.physics.kernel import diameter_at

    ph = EKF_SCENARIO.model_physics()
    model = DynamicsModel(ph, EKF_SCENARIO.sim.integrator)
    wall = -(0.5 * float(diameter_at(0.0, model.p)) - ph.robot.radius_m)  # a bead touching the lower wall at t = 0
    out = {}
    for sigma in (0.0, 5e-6):
        params = dataclasses.replace(EkfParams(), wall_projection="lumen", wall_constraint_sigma_m=sigma)
        obs = ExtendedKalmanObserver(params, model, (0.0, wall + height_above_wall_m), tick_s=1e-3)
        obs.update(0.0, _meas(0.0, (0.0, wall + height_above_wall_m)), np.zeros(2))
        obs.update(1e-3, None, np.zeros(2))
        out[sigma] = obs
    return out


def test_wall_constraint_conditions_the_covariance_on_the_wall_normal_position() -> None:
    """Resting on the lower wall (its weight presses it there): with ``wall_constraint_sigma_m`` the prediction's
    covariance knows the wall-normal position to that sigma, the frames' 100 um no longer; the mean is the
    unconstrained filter's to the bit (a pseudo-measurement of zero innovation) and the covariance stays positive."""
    from vesselbot_ros.physics.params import PhysicsParams

    l0 = PhysicsParams().interactions.brush_length_m
    f = _resting_filters(l0)
    off, on = f[0.0].covariance, f[5e-6].covariance
    assert off[1, 1] > (30e-6) ** 2  # the frames' uncertainty across the wall
    assert on[1, 1] <= (5e-6) ** 2 * (1 + 1e-9)
    assert on[0, 0] <= off[0, 0] and on[0, 0] > 0.5 * off[0, 0]  # along the wall: the frames' own
    assert np.all(np.linalg.eigvalsh(on) > -1e-18)
    np.testing.assert_array_equal(f[0.0].state, f[5e-6].state)


def test_wall_constraint_leaves_a_free_estimate_alone() -> None:
    """Mid-lumen nothing presses the estimate onto a wall: the option changes no bit."""
    f = _resting_filters(1.5e-3)
    np.testing.assert_array_equal(f[0.0].covariance, f[5e-6].covariance)
    np.testing.assert_array_equal(f[0.0].state, f[5e-6].state)


def test_wall_projection_is_validated() -> None:
    with pytest.raises(ConfigError, match="wall_projection"):
        EkfParams(wall_projection="sky")


def test_wall_projection_keeps_the_track_on_the_wall_where_the_stiff_jacobian_lost_it() -> None:
    """The clinical 3 T plan rides the lower wall; seed 53 lost the bead (3.75 mm) while the covariance's Jacobian
    held the wall's contact: a delayed frame's velocity gain threw the re-prediction 1.6 mm off the wall."""
    from pathlib import Path

    plan = Path(__file__).resolve().parents[3] / "config" / "plans" / "clinical_3t.yaml"
    res = run_closed_loop(load_scenario(plan), 53)
    assert res.metrics["estimation_error_max_m"] < 300e-6 and res.metrics["tracking_error_max_m"] < 500e-6


def test_wall_projection_away_from_a_wall_keeps_every_force_in_the_covariance() -> None:
    """Mid-lumen on the 400 mT/m insert (20 ms tracking windows), the bead swings to 200 um of the upper wall
    pulled away from it by its weight: the wall is no constraint there.  Without the image charge's gradient
    (5 m/s^2 at a radius from the wall) in the covariance, a noise-free estimate was 300-500 um off; with
    ``lumen`` the estimate is as good as with ``none``."""
    cell = cell_scenario(EKF_SCENARIO, StudyCell("propulsion_insert", 0.01, 0.0, "ekf_k300"))
    rms = {}
    for projection in ("none", "lumen"):
        sc = scenario_with(cell, {"observer.ekf.wall_projection": projection, "imager.noise_sigma_m": 0.0})
        rms[projection] = run_closed_loop(sc, 0).metrics["estimation_error_rms_m"]
    assert rms["none"] < 30e-6
    assert rms["lumen"] < 1.1 * rms["none"]


def test_track_restarts_once_the_rejected_frames_span_max_rejection_s() -> None:
    """At a few frames per second a count of rejections is seconds of a locked-out filter: the time rule restarts
    the track once the frames rejected in a row span ``max_rejection_s`` (a shorter burst of aberrant frames is
    refused and the track kept), on the frame's position at its acquisition time."""
    model = DynamicsModel(EKF_SCENARIO.model_physics(), EKF_SCENARIO.sim.integrator)
    params = EkfParams(max_rejection_s=0.03)  # the count rule (50) never fires here
    obs = ExtendedKalmanObserver(params, model, (0.0, 1e-3), tick_s=1e-3)
    obs.update(0.0, _meas(0.0, (0.0, 1e-3)), np.zeros(2))
    far = (0.0, -1e-3)  # 2 mm away: gated
    for t in (0.016, 0.032):  # two rejected frames 16 ms apart: a 20 ms burst, kept out
        assert obs.update(t, _meas(t, far), np.zeros(2)).rejected and obs.track_resets == 0
    here = obs.update(0.047, None, np.zeros(2)).x_hat  # where the filter has the bead (it moves with the blood)
    back = obs.update(0.048, _meas(0.048, tuple(here)), np.zeros(2))  # the burst is over: the track goes on
    assert back.used_measurement and obs.track_resets == 0
    for t in (0.064, 0.080):
        assert obs.update(t, _meas(t, far), np.zeros(2)).rejected
    e = obs.update(0.096, _meas(0.096, far), np.zeros(2))  # rejected frames span 32 ms >= 30 ms: restart on it
    assert e.used_measurement and obs.track_resets == 1
    np.testing.assert_allclose(e.x_hat, far, rtol=0, atol=1e-12)


def test_the_gate_keeps_its_probability_on_three_axes() -> None:
    """The configured gate is a 2-degree-of-freedom quantile (99.9 %); a tree's innovation has three: the same
    probability's quantile there."""
    assert gate_on_axes(CHI2_2DOF_999, 2) == CHI2_2DOF_999
    assert gate_on_axes(CHI2_2DOF_999, 3) == pytest.approx(16.266, abs=1e-3)
    assert gate_on_axes(0.0, 3) == 0.0  # off stays off


def test_an_estimate_sunk_into_a_trees_wall_is_predicted_again_from_the_lumen_not_failed() -> None:
    """A multiplexed flight in the III-C 3-D tree (the insert's plan, predictive controller, seed 2) left the filter's
    estimate in the trunk's wall (30 um into its steady surface), where the model's Hertz contact collapsed the integrator's step and the
    run failed ("prediction failed, step size collapsed").  The prediction is now made again from the lumen (a brush
    length from the wall, a fresh contact state), once, and counted; the estimate is back inside the lumen.

    Since the ball diameter's fix at convex creases (docs/vessels.md, "surface_wall": the local diameter there had
    been the point's own distance, making the wall-effect drag stiff) the model crosses that state at its least
    step of 1 ns; the failure is forced here by a least step of 10 us, with the estimate a further 30 um in."""
    from vesselbot_ros.vessels.network import load_network
    from vesselbot_ros.vessels.tree_field import meshed_wall

    sc = load_scenario(shipped_scenarios()["paper_iiic_network_upper_3d"])
    model = DynamicsModel(sc.model_physics(), dataclasses.replace(sc.sim.integrator, min_step_s=1e-5))
    x0 = np.array([0.004093538346975535, -2.1618320522845738e-05, -0.0013658445686964636])
    v0 = np.array([-0.009860168222125928, 0.00486886455932823, -0.0037401213394286396])
    wall = meshed_wall(load_network(sc.physics.vessel.network))
    x0 = x0 - 30e-6 * wall.query(x0)["normal"][0]
    assert wall.query(x0)["sdist"][0] < sc.physics.robot.radius_m - 2e-5  # the bead overlaps the wall
    obs = ExtendedKalmanObserver(EkfParams(), model, x0, v0, t0_s=0.109)
    est = obs.update(0.110, None, np.zeros(3))
    assert obs.wall_recoveries == 1
    q = wall.query(est.x_hat)
    fl = sc.physics.flow
    eps = fl.diameter_pulsation * math.sin(fl.angular_frequency_rad_per_s * 0.110 + fl.phase_rad)
    clearance = q["sdist"][0] + 0.5 * q["diameter"][0] * eps  # to the pulsating wall, as the plant has it
    # on the wall, as the model's bead presses into it (Hertz: micrometres), no longer tens of micrometres in it
    assert clearance > sc.physics.robot.radius_m - 1e-5
    assert np.all(np.isfinite(obs.covariance))
