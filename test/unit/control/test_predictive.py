"""The predictive controller kind: hardware limits, zero outside propulsion, both loops bit-identical, bad input."""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.predictive import PredictiveController, PredictiveParams, _hypotheses, predictive_params
from vesselbot_ros.physics.kernel import I_R, diameter_at
from vesselbot_ros.scanner.actuator_limits import CoilLimiter
from vesselbot_ros.scanner.hardware import effective_coil_limits
from vesselbot_ros.scanner.sequence import PHASE_CODES
from vesselbot_ros.sim import kinds
from vesselbot_ros.sim.closed_loop import build_stages, run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario, scenario_with, shipped_scenarios

PROPULSION = PHASE_CODES["propulsion"]


def _insert(duration: float = 0.25, **controller) -> object:
    return load_scenario(shipped_scenarios()["propulsion_insert_small_artery"], duration=duration,
                         sets=["controller=" + repr({"kind": "predictive", **controller}).replace("'", '"')])


def test_it_is_a_registered_compiled_controller_kind() -> None:
    k = kinds.find("controller", "predictive")
    assert k.compiled and k.source == "built-in" and k.params is PredictiveParams
    sc = _insert()
    assert isinstance(build_stages(sc).controller, PredictiveController)


@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 50), pieces=st.integers(1, 3), reg=st.sampled_from([0.01, 0.1, 1.0]))
def test_commands_are_zero_outside_propulsion_and_the_coil_keeps_every_limit(seed: int, pieces: int, reg: float) -> None:
    """Through the real limiter: the command is exactly zero outside propulsion windows, the applied gradient
    stays in the saturation disc, moves at most the (dB/dt-lowered) slew per tick, and is zero outside them."""
    sc = _insert(pieces=pieces, regularization=reg)
    r = run_closed_loop(sc, seed)
    ts = r.timeseries
    outside = ts["sequence_phase"] != PROPULSION
    assert np.all(ts["g_cmd"][outside] == 0.0) and np.all(ts["g_applied"][outside] == 0.0)
    assert np.all(np.isfinite(ts["g_cmd"]))
    lim = effective_coil_limits(sc.coil, sc.dbdt)
    assert np.all(np.hypot(*ts["g_applied"].T) <= lim.saturation_T_per_m * (1.0 + 1e-12))
    step = np.abs(np.diff(np.vstack([np.zeros(2), ts["g_applied"]]), axis=0))
    assert np.all(step <= lim.slew_rate_T_per_m_per_s * sc.sim.dt_control_s * (1.0 + 1e-9))
    assert np.any(ts["g_cmd"][~outside] != 0.0)  # it does propel


def test_compiled_and_per_tick_loops_are_bit_identical() -> None:
    sc = _insert(0.4)
    fast, slow = run_closed_loop(sc, 3), run_closed_loop(sc, 3, path="per_tick")
    assert (fast.path, slow.path) == ("compiled", "per_tick")
    assert fast.metrics == slow.metrics
    for col in ("p_true", "x_hat", "g_cmd", "u_cmd", "g_applied", "cmd_status", "flow_scale_hat"):
        assert np.array_equal(fast.timeseries[col], slow.timeseries[col]), col


def test_it_tracks_about_as_well_as_law_24_with_its_gains_near_the_drag_rate() -> None:
    """On the 400 mT/m insert with its 60 ms windows: within 1.5x of law (24) with k1 = k2 = 150 (no worse by far)."""
    law = load_scenario(shipped_scenarios()["propulsion_insert_small_artery"], duration=1.5)
    pred = _insert(1.5)
    a, b = run_closed_loop(law, 0).metrics, run_closed_loop(pred, 0).metrics
    assert b["tracking_error_max_m"] < 1.5 * a["tracking_error_max_m"], (a["tracking_error_max_m"], b["tracking_error_max_m"])


def test_a_stale_estimate_commands_zero_and_a_bad_flow_scale_is_an_error() -> None:
    sc = _insert()
    c = build_stages(sc).controller

    class Est:
        x_hat = np.array([1e-3, 0.0])
        z_hat = np.zeros(2)
        time_since_measurement_s = math.inf
        flow_scale = 1.0

    class Ref:
        p = np.array([1e-3, 0.0])
        v = np.zeros(2)
        a = np.zeros(2)

    cmd = c.command(0.021, Est(), Ref())
    assert cmd.status == "stale" and np.all(cmd.gradient_T_per_m == 0.0)
    Est.time_since_measurement_s = 0.0
    Est.flow_scale = math.nan
    with pytest.raises(Exception, match="flow scale must be finite and > 0"):
        c.command(0.022, Est(), Ref())


@pytest.mark.parametrize("key, value, match", [
    ("pieces", 0, r"controller\.pieces must be in \[1, 8\], got 0"),
    ("iterations", 50, r"controller\.iterations must be in \[1, 20\], got 50"),
    ("regularization", -1.0, r"controller\.regularization must be > 0"),
    ("velocity_weight_s", -1.0, r"controller\.velocity_weight_s must be finite and >= 0"),
    ("max_horizon_ticks", 10, r"controller\.max_horizon_ticks must cover a propulsion window and its coast"),
    ("wall_contact", "glued", r"controller\.wall_contact must be one of"),
    ("spread_m", -1e-5, r"controller\.spread_m must be in \[0(\.0)?, 0\.001\], got -1e-05"),
    ("spread_m", math.nan, r"controller\.spread_m must be a number"),
])
def test_bad_parameters_are_one_line_naming_the_key(key: str, value: object, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        build_stages(_insert(**{key: value}))


def test_the_coil_replica_is_the_coil() -> None:
    """Fed the same commands, the controller's replica and the scenario's coil stage apply the same gradients."""
    sc = _insert(0.1)
    r = run_closed_loop(sc, 1, path="per_tick")
    st_ = build_stages(sc, 1)
    coil = st_.coil
    for k, t in enumerate(r.timeseries["t_s"]):
        out = coil.apply(float(t), r.timeseries["g_cmd"][k])
        assert np.array_equal(out.applied, r.timeseries["g_applied"][k])
    assert isinstance(getattr(coil, "inner", coil), CoilLimiter)


def test_wall_contact_carried_plans_no_vertical_gradient_where_the_reference_rests_on_the_lower_wall() -> None:
    """The insert's plan rests on the lower wall: with ``wall_contact: carried`` every command there is axial only
    (exactly zero vertically), elsewhere both components are planned; compiled and per-tick loops agree bit for bit;
    without the option the plan lifts the bead off the wall (worse tracking on the same seed)."""
    plan = Path(__file__).resolve().parents[3] / "config" / "plans" / "propulsion_insert.yaml"
    base = load_scenario(plan, sets=["controller.kind=predictive", "sim.duration_s=0.6"])
    carried = scenario_with(base, {"controller.wall_contact": "carried"})
    fast, slow = run_closed_loop(carried, 1), run_closed_loop(carried, 1, path="per_tick")
    assert fast.metrics == slow.metrics and np.array_equal(fast.timeseries["g_cmd"], slow.timeseries["g_cmd"])
    ts = fast.timeseries
    model = build_stages(carried).controller.geom  # a straight vessel: the packed model
    on_wall = ts["p_ref"][:, 1] <= model[I_R] - 0.5 * np.array([diameter_at(t, model) for t in ts["t_s"]])
    propelled = ts["sequence_phase"] == PROPULSION
    assert np.any(on_wall & propelled) and np.any(~on_wall & propelled)
    assert np.all(ts["g_cmd"][on_wall, 1] == 0.0)
    assert np.any(ts["g_cmd"][on_wall & propelled, 0] != 0.0)
    assert np.any(run_closed_loop(base, 1).timeseries["g_cmd"][on_wall & propelled, 1] != 0.0)
    whole = {k: run_closed_loop(scenario_with(sc, {"sim.duration_s": 1.1}), 1).metrics["tracking_error_max_m"]
             for k, sc in (("carried", carried), ("lifted", base))}
    assert whole["carried"] < 0.7 * whole["lifted"]


_INSERT_SPREAD = functools.cache(lambda: _insert(spread_m=1e-4))


@settings(max_examples=30, deadline=None)
@example(est=[0.0] * 4, vr=[0.0, 2.2250738585e-313], spread=0.0009952058468490873)  # the expectation's own rounding
@given(est=st.lists(st.floats(-1e-2, 1e-2), min_size=4, max_size=4),
       vr=st.lists(st.floats(-0.05, 0.05), min_size=2, max_size=2), spread=st.floats(1e-6, 1e-3))
def test_a_spreads_hypotheses_straddle_the_estimate_along_the_reference(est: list[float], vr: list[float],
                                                                        spread: float) -> None:
    """The two hypotheses: the estimate moved ``spread_m`` forward and back along the reference's velocity (their
    mean is the estimate, to rounding), the estimated velocity kept; a reference at rest moves neither."""
    sc = _INSERT_SPREAD()  # loaded once (a scenario load per example cost most of the test's time)
    params = dataclasses.replace(sc.controller, spread_m=spread)
    prm = predictive_params(params, effective_coil_limits(sc.coil, sc.dbdt), sc.sequence, sc.sim.dt_control_s)
    e, v, hyp = np.array(est), np.array(vr), np.empty(8)
    _hypotheses(prm, e, v, hyp)
    ahead, back = hyp[:4], hyp[4:]
    assert np.array_equal(ahead[2:], e[2:]) and np.array_equal(back[2:], e[2:])
    if not np.any(v):
        assert np.array_equal(ahead, e) and np.array_equal(back, e)
        return
    u = v / np.abs(v).max()  # the direction, exact to rounding also for a subnormal velocity (spread * v is not)
    u = u / math.hypot(*u)
    np.testing.assert_allclose(ahead[:2] - e[:2], spread * u, rtol=1e-9, atol=1e-18)
    np.testing.assert_allclose(back[:2] - e[:2], -spread * u, rtol=1e-9, atol=1e-18)


def test_a_spread_runs_compiled_as_per_tick_and_a_vanishing_one_plans_as_the_estimate_alone() -> None:
    """With a spread both loops give the same bits (on the wall, carried); in the free lumen, where the model is
    smooth, a spread of a nanometre plans what the estimate alone plans (the sum of two equal costs has its minimum
    where one has), and a tenth of a millimetre plans otherwise."""
    plan = Path(__file__).resolve().parents[3] / "config" / "plans" / "propulsion_insert.yaml"
    base = load_scenario(plan, sets=["controller.kind=predictive", "controller.wall_contact=carried",
                                     "controller.spread_m=1e-4", "sim.duration_s=0.3"])
    fast, slow = run_closed_loop(base, 2), run_closed_loop(base, 2, path="per_tick")
    assert fast.metrics == slow.metrics and np.array_equal(fast.timeseries["g_cmd"], slow.timeseries["g_cmd"])
    free = _insert(0.3)
    alone, tiny, wide = (run_closed_loop(scenario_with(free, {"controller.spread_m": s}), 2).timeseries["g_cmd"]
                         for s in (0.0, 1e-9, 1e-4))
    sat = effective_coil_limits(free.coil, free.dbdt).saturation_T_per_m
    assert np.max(np.abs(tiny - alone)) < 1e-4 * sat  # measured 1.4e-5: the loops part by rounding only
    assert np.max(np.abs(wide - alone)) > 1e-3 * sat  # measured 7.6e-3
