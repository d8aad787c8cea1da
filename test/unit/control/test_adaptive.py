"""Tests of the adaptive backstepping (control/adaptive.py and its use by BacksteppingController)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vesselbot_ros.config import ConfigError, load_dataclass
from vesselbot_ros.control.adaptive import AdaptiveParams, AdaptiveState, adaptation_step
from vesselbot_ros.control.backstepping import BacksteppingController, BacksteppingGains, ControllerParams
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios

finite = st.floats(-1e3, 1e3, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(e2=st.tuples(finite, finite), phi=st.tuples(finite, finite), dt=st.floats(1e-4, 1.0),
       gain=st.floats(0.0, 1e4), s0=st.floats(0.5, 2.0))
def test_estimates_stay_in_the_projection_bounds_and_move_along_phi_dot_e2(e2, phi, dt, gain, s0) -> None:
    prm = AdaptiveParams(flow_scale_gain_s3_per_m2=gain, magnetization_gain_s3_per_m2=gain)
    state = AdaptiveState(s0, s0, 0.0)
    adaptation_step(prm, state, dt, e2, phi, phi)
    for value in (state.flow_scale, state.magnetization_scale):
        assert prm.scale_min <= value <= prm.scale_max
        drive = phi[0] * e2[0] + phi[1] * e2[1]
        # the Lyapunov update: the estimate moves with the sign of phi . e2 (or is held at a bound)
        assert (value - s0) * drive >= 0.0
    assert state.t_last_s == dt


def test_first_call_and_repeated_tick_only_record_the_time() -> None:
    prm = AdaptiveParams(flow_scale_gain_s3_per_m2=10.0)
    state = AdaptiveState()
    adaptation_step(prm, state, 0.5, (1.0, 1.0), (1.0, 1.0), (1.0, 1.0))
    assert (state.flow_scale, state.t_last_s) == (1.0, 0.5)
    adaptation_step(prm, state, 0.5, (1.0, 1.0), (1.0, 1.0), (1.0, 1.0))
    assert state.flow_scale == 1.0
    adaptation_step(prm, state, 0.51, (1.0, 0.0), (2.0, 0.0), (1.0, 1.0))
    assert state.flow_scale == pytest.approx(1.0 + 0.01 * 10.0 * 2.0, rel=1e-12)
    assert state.magnetization_scale == 1.0  # gain 0: not adapted


@pytest.mark.parametrize(
    ("doc", "match"),
    [
        ({"flow_scale_gain_s3_per_m2": -1.0}, r"flow_scale_gain_s3_per_m2 must be >= 0, got -1\.0"),
        ({"magnetization_gain_s3_per_m2": math.nan}, r"magnetization_gain_s3_per_m2"),
        ({"scale_min": 0.0}, r"scale_min must be > 0"),
        ({"scale_min": 1.5, "scale_max": 1.2}, r"scale_max must be > scale_min"),
        ({"scale_min": 1.1, "scale_max": 2.0}, r"must contain 1"),
        ({"bogus": 1.0}, r"unknown key"),
    ],
)
def test_bad_adaptive_params_name_key_and_value(doc, match) -> None:
    with pytest.raises(ConfigError, match=match):
        load_dataclass(AdaptiveParams, doc, "adaptive")


def test_adaptive_kind_does_not_take_the_observers_flow_scale_too() -> None:
    with pytest.raises(ConfigError, match=r"flow_compensation must be 'none' with kind 'adaptive_backstepping'"):
        ControllerParams(kind="adaptive_backstepping", flow_compensation="estimate")


def _linear_model(s_true_over_model: float, m_true_over_model: float):
    """F = -c (Z - s V) per unit mass (Stokes drag, uniform flow V along x), B = b I."""
    c, v, b = 300.0, 0.025, 200.0

    def force(t, x, z, flow_scale=1.0):
        return np.array([-c * (z[0] - flow_scale * v), -c * z[1]])

    def true_accel(z, g):
        return np.array([-c * (z[0] - s_true_over_model * v), -c * z[1]]) + m_true_over_model * b * np.asarray(g)

    return force, true_accel, np.diag([b, b])


@pytest.mark.parametrize(("s_true", "m_true"), [(0.95, 1.0), (1.0, 0.9), (1.05, 1.1)])
def test_adapted_scales_converge_on_a_linear_plant_and_the_error_vanishes(s_true: float, m_true: float) -> None:
    """Exact state, a plant linear in both parameters: the Lyapunov design drives e and the estimates home."""
    force, true_accel, b = _linear_model(s_true, m_true)
    prm = ControllerParams(kind="adaptive_backstepping", gains=BacksteppingGains(20.0, 20.0), stale_timeout_s=1.0,
                           adaptive=AdaptiveParams(flow_scale_gain_s3_per_m2=2e4, magnetization_gain_s3_per_m2=2e4))
    ctl = BacksteppingController(prm, force, b)
    dt = 1e-4
    x, z = np.zeros(2), np.zeros(2)
    errors = []
    for k in range(int(6.0 / dt)):
        t = k * dt
        w = 2.0 * math.pi * 1.0  # a persistently exciting reference: a 1 mm circle at 1 Hz
        p_ref = 1e-3 * np.array([math.cos(w * t) - 1.0, math.sin(w * t)])
        v_ref = 1e-3 * w * np.array([-math.sin(w * t), math.cos(w * t)])
        a_ref = -1e-3 * w * w * np.array([math.cos(w * t), math.sin(w * t)])
        cmd = ctl.command_arrays(t, x, z, 0.0, p_ref, v_ref, a_ref)
        assert cmd.status == "ok"
        a = true_accel(z, cmd.gradient_T_per_m)
        x = x + dt * z
        z = z + dt * a
        errors.append(float(np.hypot(*(x - p_ref))))
    assert ctl.adapted is not None
    assert ctl.adapted.flow_scale == pytest.approx(s_true, abs=0.01)
    assert ctl.adapted.magnetization_scale == pytest.approx(m_true, abs=0.01)
    assert max(errors[-10000:]) < 0.02 * max(errors[:10000])


def test_shipped_adaptive_scenario_beats_the_same_gains_without_adaptation_and_estimates_the_flow_error() -> None:
    sc = load_scenario(shipped_scenarios()["sound_small_artery_adaptive"])
    plain = dataclasses.replace(sc, controller=dataclasses.replace(sc.controller, kind="backstepping"))
    adaptive, fixed = run_closed_loop(sc, 0), run_closed_loop(plain, 0)
    assert adaptive.path == "compiled"  # the adaptive law has its compiled form
    assert adaptive.metrics["tracking_error_max_m"] < 150e-6  # the paper's claim
    assert adaptive.metrics["tracking_error_max_m"] < 0.9 * fixed.metrics["tracking_error_max_m"]
    s_hat = adaptive.timeseries["flow_scale_hat"]
    t = adaptive.timeseries["t_s"]
    true_scale = 0.025 / 0.02625  # the model believes V_f 5 % too high
    assert abs(float(np.mean(s_hat[t >= 1.0])) - true_scale) < 0.03
    assert np.all(adaptive.timeseries["magnetization_scale_hat"] == 1.0)  # gain 0: not adapted


@pytest.mark.parametrize("sample_hold", ["none", "midpoint"])
@pytest.mark.parametrize("gains", [(1000.0, 0.0), (1000.0, 500.0)])
def test_compiled_adaptive_law_gives_the_python_laws_doubles(sample_hold, gains) -> None:
    """The model's F runs the compiled adaptive_command; a user's F (the same function, wrapped) the Python
    reading: the same commands, statuses and adapted scales, bit for bit, stale ticks included."""
    from vesselbot_ros.sim.closed_loop import build_stages

    sc = load_scenario(shipped_scenarios()["sound_small_artery_adaptive"])
    adaptive = dataclasses.replace(sc.controller.adaptive, flow_scale_gain_s3_per_m2=gains[0],
                                   magnetization_gain_s3_per_m2=gains[1])
    sc = dataclasses.replace(sc, controller=dataclasses.replace(sc.controller, adaptive=adaptive,
                                                                sample_hold=sample_hold))
    model = build_stages(sc).model
    compiled = BacksteppingController(sc.controller, model.F, model.input_matrix, sc.sim.dt_control_s)
    python = BacksteppingController(sc.controller, lambda t, x, z, s=1.0: model.F(t, x, z, s), model.input_matrix,
                                    sc.sim.dt_control_s)
    assert compiled.model_params is not None and python.model_params is None
    rng = np.random.default_rng(3)
    for k in range(300):
        t = k * 1e-3
        x = np.array([1e-3 * t, 0.0]) + rng.normal(0.0, 5e-5, 2)
        z = np.array([1e-3, 0.0]) + rng.normal(0.0, 5e-4, 2)
        age = 1.0 if k % 50 == 7 else 1e-3  # now and then a stale estimate: adaptation pauses
        ref = (np.array([1e-3 * t, 0.0]), np.array([1e-3, 0.0]), np.zeros(2))
        a = compiled.command_arrays(t, x, z, age, *ref)
        b = python.command_arrays(t, x, z, age, *ref)
        assert a.status == b.status
        assert a.gradient_T_per_m.tolist() == b.gradient_T_per_m.tolist() and a.u_m_per_s2.tolist() == b.u_m_per_s2.tolist()
        assert compiled.adapted == python.adapted, k
    assert compiled.adapted.flow_scale != 1.0
