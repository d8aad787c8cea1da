"""The compiled closed loop against the per-tick loop: bit for bit, batches, user stages, bad input."""

from __future__ import annotations

import dataclasses as dc
import functools
import math
import os
import subprocess
import sys
from typing import Any

import numpy as np
import pytest

from vesselbot_ros.blas_free import mat2, mat2_apply, mat2_inverse
from vesselbot_ros.control.backstepping import ControlCommand
from vesselbot_ros.control.predictive import PredictiveParams
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.integrator import IntegratorParams
from vesselbot_ros.physics.kernel import I_D0_RATIO, I_V_F
from vesselbot_ros.scanner.imager_model import Dropout
from vesselbot_ros.scanner.sequence import SequenceParams
from vesselbot_ros.sim.closed_loop import SimResult, build_stages, run_closed_loop, run_many, run_stages
from vesselbot_ros.sim.fingerprint import fingerprint
from vesselbot_ros.sim.scenario import Scenario, load_scenario, shipped_scenarios

SEEDS = range(5)


def _assert_identical(a: SimResult, b: SimResult) -> None:
    assert sorted(a.timeseries) == sorted(b.timeseries)
    for k, v in a.timeseries.items():
        w = b.timeseries[k]
        assert v.dtype == w.dtype and v.shape == w.shape, k
        np.testing.assert_array_equal(v, w, err_msg=k)  # NaN == NaN here, nothing else is forgiven
    assert sorted(a.metrics) == sorted(b.metrics)
    for k, v in a.metrics.items():
        assert repr(v) == repr(b.metrics[k]), (k, v, b.metrics[k])  # repr round-trips every double
    assert fingerprint(a) == fingerprint(b)


def test_every_shipped_scenario_runs_compiled() -> None:
    """Every built-in stage has its compiled form (the adaptive law included): no shipped scenario runs per tick."""
    for name, path in shipped_scenarios().items():
        assert run_closed_loop(_short(load_scenario(path)), 0).path == "compiled", name


class ForeignObserver:
    """A user's observer: wraps the built-in one (same numbers), but it is not a type the compiled loop knows."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.model = inner.model

    def update(self, t_s: float, measurement: Any, applied: Any) -> Any:
        return self.inner.update(t_s, measurement, applied)


def test_a_stage_the_compiled_loop_lacks_runs_per_tick_and_says_so() -> None:
    scenario = _short(load_scenario(shipped_scenarios()["sound_small_artery_ekf"]))
    st = build_stages(scenario, 0)
    res = run_stages(scenario, st._replace(observer=ForeignObserver(st.observer)), 0)
    assert res.path == "per_tick"
    _assert_identical(res, run_closed_loop(scenario, 0, path="per_tick"))
    st = build_stages(scenario, 0)
    with pytest.raises(ModelInputError, match=r"path='compiled' needs the built-in stages.*observer"):
        run_stages(scenario, st._replace(observer=ForeignObserver(st.observer)), 0, path="compiled")


@pytest.mark.parametrize("name", sorted(shipped_scenarios()))
def test_compiled_equals_per_tick_on_every_column_metric_and_statistic(name: str) -> None:
    scenario = load_scenario(shipped_scenarios()[name])
    for seed in SEEDS:
        compiled = run_closed_loop(scenario, seed)
        per_tick = run_closed_loop(scenario, seed, path="per_tick")
        assert (compiled.path, per_tick.path) == ("compiled", "per_tick")
        _assert_identical(compiled, per_tick)
        # the run statistics are part of the metrics; make sure they are not trivially zero
        assert compiled.metrics["plant_rhs_evals"] > 0 and compiled.metrics["observer_rhs_evals"] > 0


def _short(s: Scenario, duration: float = 0.25) -> Scenario:
    return dc.replace(s, sim=dc.replace(s.sim, duration_s=duration, metrics_after_s=0.4 * duration))


@functools.lru_cache(maxsize=1)
def _wall_plan() -> Scenario:
    """The clinical 3 T plan (it falls to the lower wall and rides it), flown with the wall-contact options."""
    from vesselbot_ros.analysis.plan import PlanOptions, make_plan, plan_scenario

    base = load_scenario(shipped_scenarios()["clinical_3t_small_artery"])
    planned = plan_scenario(base, make_plan(base, PlanOptions(height="wall")).reference)
    return _short(dc.replace(
        planned, controller=dc.replace(planned.controller, wall_contact="carried"),
        observer=dc.replace(planned.observer, ekf=dc.replace(planned.observer.ekf, wall_projection="lumen"))), 0.3)


def _variants() -> dict[str, Scenario]:
    """Branches the shipped scenarios do not take: forces, per-axis saturation, hold, 50 Hz + latency + dropouts + gate
    + delay compensation, fixed-step RK4, flow-synchronised reference; the extended Kalman filter with latency (delay
    compensation, history re-prediction), track restarts, a frozen flow scale; the scanner's multiplexed sequence with
    duty compensation, ramp-to-zero and per-axis coils; flow compensation with observer (25)."""
    sound = _short(load_scenario(shipped_scenarios()["sound_small_artery"]))
    paper = _short(load_scenario(shipped_scenarios()["paper_small_artery"]))
    ekf = _short(load_scenario(shipped_scenarios()["sound_small_artery_ekf"]), 0.4)
    # the same options in a 3-D tree (issue 40: every kind in every geometry): the filter with its wall constraint,
    # the flow-compensating law at the middle of the hold, the adaptive law
    tree = _short(load_scenario(shipped_scenarios()["paper_iiic_network_upper_3d"]), 0.3)
    tree_ekf = dc.replace(tree, observer=dc.replace(tree.observer, kind="ekf",
                                                    ekf=dc.replace(ekf.observer.ekf, wall_projection="lumen")),
                          controller=dc.replace(ekf.controller))
    # window edges on the tick grid (scenario rule), latency off it
    mux = SequenceParams(mode="multiplexed", tracking_window_s=0.010, dead_time_s=0.002, propulsion_window_s=0.023,
                         latency_s=0.0071, start_s=0.003)
    return {
        "ekf_50Hz_latency_delay": dc.replace(
            ekf, imager=dc.replace(ekf.imager, frame_rate_Hz=50.0, latency_s=0.03, dropout_probability=0.2,
                                   outliers=(dc.replace(ekf.imager.outliers[0], start_s=0.1, duration_s=0.05),))),
        "ekf_track_restart": dc.replace(
            ekf, imager=dc.replace(ekf.imager, frame_rate_Hz=200.0, latency_s=0.01,
                                   outliers=(dc.replace(ekf.imager.outliers[0], start_s=0.1, duration_s=0.25,
                                                        magnitude_m=2e-3),)),
            observer=dc.replace(ekf.observer, ekf=dc.replace(ekf.observer.ekf, max_consecutive_rejections=5))),
        "ekf_frozen_scale_short_history": dc.replace(
            ekf, imager=dc.replace(ekf.imager, frame_rate_Hz=100.0, latency_s=0.05),
            observer=dc.replace(ekf.observer, ekf=dc.replace(ekf.observer.ekf, history_s=0.03,
                                                               estimate_flow_scale=False))),
        "scanner_ekf_duty_ramp_per_axis": dc.replace(
            ekf, sequence=mux, controller=dc.replace(ekf.controller, duty_compensation="sequence"),
            coil=dc.replace(ekf.coil, on_reject="ramp_to_zero", saturation_norm="per_axis"),
            imager=dc.replace(ekf.imager, dropouts=(Dropout(start_s=0.1, duration_s=0.05),))),
        # observer (25) sees one frame per sequence period: 40 frames/s here (mux's 27 are unstable for its gains,
        # refused by the scenario loader), with a latency longer than the period
        "scanner_high_gain": dc.replace(
            sound, sequence=dc.replace(mux, tracking_window_s=0.006, dead_time_s=0.002, propulsion_window_s=0.015,
                                       start_s=0.0, latency_s=0.02),
            controller=dc.replace(sound.controller, duty_compensation="sequence", stale_timeout_s=0.5)),
        "flow_compensation_high_gain": dc.replace(
            sound, controller=dc.replace(sound.controller, flow_compensation="estimate", sample_hold="midpoint")),
        "forces_per_axis_hold": dc.replace(
            paper, sim=dc.replace(paper.sim, record_forces=True), coil=dc.replace(paper.coil, saturation_norm="per_axis"),
            controller=dc.replace(paper.controller, stale_action="hold", stale_timeout_s=0.015),
            imager=dc.replace(paper.imager, frame_rate_Hz=50.0, dropouts=(Dropout(start_s=0.05, duration_s=0.05),))),
        "mri_50Hz_latency_gate_delay": dc.replace(
            sound, imager=dc.replace(sound.imager, frame_rate_Hz=50.0, latency_s=0.03, dropout_probability=0.2,
                                     outliers=(dc.replace(sound.imager.outliers[0], start_s=0.1, duration_s=0.05),)),
            observer=dc.replace(sound.observer, delay_compensation=True, innovation_gate_m=5e-4)),
        "planned_wall_carried_projected": _wall_plan(),
        # the predictive controller's run also holds the wall in the filter's covariance (wall_constraint_sigma_m)
        "planned_wall_predictive_projected": dc.replace(_wall_plan(), controller=PredictiveParams(), observer=dc.replace(
            _wall_plan().observer, ekf=dc.replace(_wall_plan().observer.ekf, wall_constraint_sigma_m=5e-6))),
        "tree_ekf_latency_delay_lumen": dc.replace(
            tree_ekf, imager=dc.replace(tree.imager, frame_rate_Hz=100.0, latency_s=0.02,
                                        outliers=(dc.replace(ekf.imager.outliers[0], start_s=0.1, duration_s=0.05),))),
        "tree_scanner_ekf_duty": dc.replace(
            tree_ekf, sequence=mux, controller=dc.replace(ekf.controller, duty_compensation="sequence")),
        "tree_adaptive": dc.replace(tree, controller=dc.replace(tree.controller, kind="adaptive_backstepping")),
        "rk4_flow_sync": dc.replace(
            sound, sim=dc.replace(sound.sim, integrator=IntegratorParams(method="rk4", fixed_step_s=2e-4)),
            reference=dc.replace(sound.reference, timing="flow_synchronised", duration_s=0.25)),
    }


@pytest.mark.parametrize("variant", sorted(_variants()))
def test_compiled_equals_per_tick_on_other_branches(variant: str) -> None:
    scenario = _variants()[variant]
    for seed in (0, 1):
        _assert_identical(run_closed_loop(scenario, seed), run_closed_loop(scenario, seed, path="per_tick"))
    res = run_closed_loop(scenario, 0)
    ts = res.timeseries
    if variant == "forces_per_axis_hold":
        assert ts["forces"].shape == (res.metrics["n_ticks"], 8, 2)
        assert np.any(ts["cmd_status"] == 1)  # stale -> hold during the dropout
    if variant == "mri_50Hz_latency_gate_delay":
        assert np.any(ts["meas_rejected"]) and np.count_nonzero(np.isfinite(ts["meas_t_acq_s"])) < 20
    if variant.startswith("tree_"):
        assert ts["p_true"].shape[1] == 3
    if variant == "tree_adaptive":
        assert np.any(ts["flow_scale_hat"] != 1.0)
    if variant.startswith(("ekf_", "scanner_ekf", "tree_ekf", "tree_scanner_ekf")):  # the filter's branches are taken
        assert np.any(ts["flow_scale_hat"] != 1.0) or "frozen" in variant
        assert np.any(ts["meas_t_acq_s"][np.isfinite(ts["meas_t_acq_s"])] < ts["t_s"][np.isfinite(ts["meas_t_acq_s"])])
    if variant.startswith("scanner_"):
        assert set(np.unique(ts["sequence_phase"])) == {1, 2, 3}
        assert np.all(ts["g_applied"][ts["sequence_phase"] == 1] == 0.0)  # no propulsion while imaging
    if variant.startswith("planned_wall"):  # it lands on the wall and rides it; the carried law drops the vertical
        assert np.any(ts["in_contact"]) and res.metrics["tracking_error_max_m"] < 1e-3
    if variant == "ekf_track_restart":
        st = build_stages(scenario, 0)
        run_stages(scenario, st, 0, path="per_tick")
        assert st.observer.track_resets > 0


def test_batch_rows_equal_single_runs() -> None:
    variants = _variants()
    scenarios = [variants["mri_50Hz_latency_gate_delay"], variants["forces_per_axis_hold"],
                 variants["scanner_ekf_duty_ramp_per_axis"]]
    rows = run_many(scenarios, [3, 0, 7], workers=2, keep_timeseries=True)
    assert [(r.metrics["scenario"], r.metrics["seed"]) for r in rows] == [
        (s.name, seed) for s in scenarios for seed in (3, 0, 7)]
    for row, (s, seed) in zip(rows, [(s, seed) for s in scenarios for seed in (3, 0, 7)]):
        assert row.path == "compiled"
        _assert_identical(row, run_closed_loop(s, seed))
    lean = run_many(scenarios[0], [3, 0], workers=1)
    assert lean[0].timeseries == {} and lean[1].timeseries == {}
    assert [repr(r.metrics) for r in lean] == [repr(r.metrics) for r in rows[:2]]
    assert run_many(scenarios[0])[0].metrics["seed"] == scenarios[0].seed


class PlainPythonLaw:
    """A user's controller: eq. (24) written out in Python floats, F from the model (no project stage code).

    Implements the options the shipped scenarios use: ``F`` at the tick (as printed) or at the middle of the hold
    (``sample_hold: midpoint``), and ``F`` with the observer's blood-velocity scale (``flow_compensation: estimate``).
    """

    def __init__(self, scenario: Scenario) -> None:
        model = build_stages(scenario).model
        self.F = model.F
        self.b_inv = mat2_inverse(mat2(model.input_matrix))
        self.k1, self.k2 = scenario.controller.gains.k1, scenario.controller.gains.k2
        self.timeout = scenario.controller.stale_timeout_s
        self.half = 0.5 * scenario.sim.dt_control_s if scenario.controller.sample_hold == "midpoint" else 0.0
        self.compensate = scenario.controller.flow_compensation == "estimate"
        self.calls = 0

    def command(self, t_s: float, estimate: Any, ref: Any) -> ControlCommand:
        self.calls += 1
        if not estimate.time_since_measurement_s <= self.timeout:
            return ControlCommand(np.zeros(2), np.zeros(2), "stale")
        x, z = estimate.x_hat, estimate.z_hat
        scale = estimate.flow_scale if self.compensate else 1.0
        s, c, h = self.k1 + self.k2, 1.0 + self.k1 * self.k2, self.half
        if h > 0.0:  # F at the middle of the hold, along the acceleration (24) asks for
            a = [float(ref.a[i]) + s * float(ref.v[i]) + c * float(ref.p[i]) - c * float(x[i]) - s * float(z[i]) - 0.0
                 for i in range(2)]
            xm = np.array([float(x[i]) + h * float(z[i]) + 0.5 * h * h * a[i] for i in range(2)])
            zm = np.array([float(z[i]) + h * a[i] for i in range(2)])
            f = self.F(t_s + h, xm, zm, scale)
            u = [a[i] - float(f[i]) for i in range(2)]
        else:
            f = self.F(t_s, x, z, scale)
            u = [float(ref.a[i]) + s * float(ref.v[i]) + c * float(ref.p[i]) - c * float(x[i]) - s * float(z[i])
                 - float(f[i]) for i in range(2)]
        g = mat2_apply(self.b_inv, u[0], u[1])
        if not (math.isfinite(g[0]) and math.isfinite(g[1])):
            return ControlCommand(np.zeros(2), np.zeros(2), "nonfinite")
        return ControlCommand(np.array(g), np.array(u), "ok")


@pytest.mark.parametrize("name", ["paper_small_artery", "sound_small_artery_ekf"])
def test_user_python_controller_runs_per_tick_and_gives_the_built_in_numbers(name: str) -> None:
    # paper: law (24) as printed (F at the tick) with observer (25); EKF: F at mid-hold with the filter's flow scale
    scenario = load_scenario(shipped_scenarios()[name])
    for seed in (0, 1):
        law = PlainPythonLaw(scenario)
        user = run_closed_loop(scenario, seed, stages={"controller": law})
        assert user.path == "per_tick" and law.calls == scenario.sim.n_ticks
        builtin = run_closed_loop(scenario, seed)
        assert builtin.path == "compiled"
        _assert_identical(user, builtin)
        if name == "sound_small_artery_ekf":
            assert np.ptp(user.timeseries["flow_scale_hat"]) > 0.01  # the law really read a moving flow scale
    with pytest.raises(ModelInputError, match="path='compiled' needs the built-in stages"):
        run_closed_loop(scenario, 0, stages={"controller": PlainPythonLaw(scenario)}, path="compiled")
    with pytest.raises(ModelInputError, match="unknown stage name"):
        run_closed_loop(scenario, 0, stages={"planner": object()})


def test_non_finite_state_inside_the_loop_ends_with_the_per_tick_error() -> None:
    # a NaN permanent-deformation ratio: harmless until the first wall contact ends (tick 94 here), then NaN
    scenario = _short(load_scenario(shipped_scenarios()["paper_small_artery"]), 0.3)
    messages = []
    for path in ("compiled", "per_tick"):
        st = build_stages(scenario, 0)
        bad = st.plant.p.copy()
        bad[I_D0_RATIO] = np.nan
        st.plant.p = bad
        message = r"tick \d\d+: plant integration failed on \[0\.\d+, 0\.\d+\] \(code 2: non-finite state\): state \[nan"
        with pytest.raises(ModelInputError, match=message) as exc:
            run_stages(scenario, st, 0, path=path)
        messages.append(str(exc.value))
    assert messages[0] == messages[1]


@pytest.mark.parametrize("name", ["sound_small_artery", "paper_iiic_network_upper_3d"])
def test_collapsing_step_size_inside_the_loop_ends_with_the_per_tick_error(name: str) -> None:
    """A plant integrator that cannot make progress (10^9 steps asked in one tick) stops with code 1, not a hang
    (in the plane and in a 3-D tree: the error names the six states there)."""
    scenario = _short(load_scenario(shipped_scenarios()[name]), 0.01)
    messages = []
    for path in ("compiled", "per_tick"):
        st = build_stages(scenario, 0)
        st.plant.integrator = dc.replace(st.plant.integrator, method="dopri5", max_step_s=1e-12, min_step_s=1e-13)
        with pytest.raises(ModelInputError, match=r"^tick 0: plant integration failed on \[0\.0, 0\.001\] \(code 1: step size "
                                                  r"collapsed\): state \[") as exc:
            run_stages(scenario, st, 0, path=path)
        messages.append(str(exc.value))
    assert messages[0] == messages[1]
    assert messages[0].split("state [")[1].count(",") == 2 * scenario.dims - 1


def test_failing_filter_and_unusable_flow_scale_end_with_the_per_tick_error() -> None:
    scenario = _short(load_scenario(shipped_scenarios()["sound_small_artery_ekf"]), 0.05)
    for breakage, pattern in (
        ("nan_model", r"observer: prediction failed on \[0\.0, 0\.001\] \(code 2\), state \[[-0-9.e]+, [-0-9.e]+, 0\.0, 0\.0, 1\.0\]$"),
        ("negative_scale", r"controller: flow scale must be finite and > 0, got -1\.0$"),
    ):
        messages = []
        for path in ("compiled", "per_tick"):
            st = build_stages(scenario, 0)
            if breakage == "nan_model":  # the filter's model (its V_f): the first prediction is non-finite
                bad = st.observer.ekf.geom.copy()  # a planar model's geometry: its packed parameters
                bad[I_V_F] = np.nan
                bad.setflags(write=False)  # read-only as the model's own: the same compiled types (a writable one
                st.observer.ekf.geom = bad  # compiled the whole loop again for this test, 25 s in a fresh clone)
            else:  # a flow-scale estimate the compensating law must refuse
                st.observer.ekf.y[4] = -1.0
            with pytest.raises(ModelInputError, match=pattern) as exc:
                run_stages(scenario, st, 0, path=path)
            messages.append(str(exc.value))
        assert messages[0] == messages[1]


def test_non_finite_measurement_is_rejected_the_same_way() -> None:
    sc = _short(load_scenario(shipped_scenarios()["sound_small_artery"]), 0.05)
    burst = dc.replace(sc.imager.outliers[0], start_s=0.01)
    object.__setattr__(burst, "magnitude_m", math.inf)  # past validation: an imager gone mad
    sc = dc.replace(sc, imager=dc.replace(sc.imager, outliers=(burst,)))
    a, b = run_closed_loop(sc, 0), run_closed_loop(sc, 0, path="per_tick")
    _assert_identical(a, b)
    assert np.count_nonzero(a.timeseries["meas_rejected"]) == 20 and np.all(np.isfinite(a.timeseries["x_hat"]))


ALLOCATIONS = """
import sys
import numpy as np
from numba.core.runtime import rtsys
from vesselbot_ros.sim import compiled_loop
from vesselbot_ros.sim.closed_loop import build_stages
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios
sc = load_scenario(shipped_scenarios()[sys.argv[1]])
prepare, run = compiled_loop.prepare, compiled_loop.run_kernel  # one kernel, planar or a 3-D tree
for n in (50, 500):
    inp = prepare(build_stages(sc, 0), n, sc.sim.dt_control_s, False)
    run(inp, np.random.default_rng(0))
    a = rtsys.get_allocation_stats()
    run(inp, np.random.default_rng(0))
    b = rtsys.get_allocation_stats()
    print(b.alloc - a.alloc, b.mi_alloc - a.mi_alloc)
"""


@pytest.mark.parametrize("name", ["sound_small_artery", "paper_iiic_network_upper", "paper_iiic_network_upper_3d"])
def test_the_compiled_loop_allocates_nothing_per_tick(name: str) -> None:
    # numba's runtime counts its allocations when NUMBA_NRT_STATS=1: a run of 500 ticks makes exactly as many
    # as a run of 50 (the scratch arrays allocated once before the first tick), so no tick allocates

    out = subprocess.run([sys.executable, "-c", ALLOCATIONS, name], capture_output=True, text=True, timeout=600, check=True,
                         env=dict(os.environ, NUMBA_NRT_STATS="1"))
    short, long = out.stdout.split("\n")[:2]
    assert short == long, out.stdout
    # once per run: the scratch (about 40 arrays) and the arrays numba unboxes from the arguments (a tree's wall
    # and flow field come in twice, in the plant's and in the model's geometry: 111 in all for the III-C tree)
    assert 0 < int(short.split()[0]) < 150


def test_the_controllers_commands_given_from_outside_fly_the_same_run() -> None:
    """loop_kernel's external commands (the stepping form's command source): a run's own g_cmd given as commands
    gives its plant, imager and observer bits (u_cmd is NaN: a bare gradient), and a command of the wrong shape is
    refused."""
    from vesselbot_ros.sim import compiled_loop
    from vesselbot_ros.sim.closed_loop import prepared

    for name in ("sound_small_artery_ekf", "clinical_3t_small_artery", "paper_iiic_network_upper_3d"):
        sc = _short(load_scenario(shipped_scenarios()[name]), 0.2)
        ref = run_closed_loop(sc, 2).timeseries
        cols, _ps, _ms = compiled_loop.run_kernel(prepared(sc), np.random.default_rng(2), ref["g_cmd"])
        for k in ("p_true", "v_true", "meas_p", "x_hat", "z_hat", "g_cmd", "g_applied", "cmd_rejected"):
            np.testing.assert_array_equal(cols[k], ref[k], err_msg=f"{name}: {k}")
        assert np.isnan(cols["u_cmd"]).all()
        with pytest.raises(ModelInputError, match=r"commands: shape \(3, 2\), expected"):
            compiled_loop.run_kernel(prepared(sc), np.random.default_rng(2), np.zeros((3, 2)))
