"""Tests of the pure closed-loop runner, the plant integrator and the scenario loader."""

from __future__ import annotations

import dataclasses as dc
import json
from pathlib import Path

import numpy as np
import pytest

from vesselbot_ros.cli import main as cli_main
from vesselbot_ros.config import ConfigError, flatten, load_yaml, unflatten
from vesselbot_ros.control.bspline_reference import ReferenceParams
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.integrator import IntegratorParams
from vesselbot_ros.physics.params import FlowParams, PhysicsParams
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.plant import PlantSimulator
from vesselbot_ros.sim.scenario import ModelParams, Scenario, SimParams, load_scenario, scenario_from_mapping

ROOT = Path(__file__).resolve().parents[3]
PAPER = ROOT / "config" / "paper_small_artery.yaml"
SOUND = ROOT / "config" / "sound_small_artery.yaml"


def _short(s: Scenario, duration: float = 0.3) -> Scenario:
    return dc.replace(s, sim=dc.replace(s.sim, duration_s=duration),
                      reference=dc.replace(s.reference, duration_s=duration))


def test_both_configs_load_and_round_trip() -> None:
    for path in (PAPER, SOUND):
        s = load_scenario(path)
        assert scenario_from_mapping(s.to_mapping()) == s
        assert scenario_from_mapping(unflatten(flatten(s.to_mapping()))) == s
    paper = load_scenario(PAPER)
    assert paper.coil.slew_rate_T_per_m_per_s == 0.1
    assert paper.model_physics().flow.centreline_velocity_m_per_s == pytest.approx(1.05 * 0.025)


@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("controller.gains.k1", -5.0, r"controller.gains.k1 must be > 0, got -5.0"),
        ("sim.control_rate_Hz", 0, r"sim.control_rate_Hz must be > 0, got 0"),
        ("imager.frame_rate_Hz", 0.0, r"imager.frame_rate_Hz must be > 0, got 0.0"),
        ("observer.bogus", 1, r"unknown key observer.bogus"),
        ("coil.slew_rate", "fast", r"coil.slew_rate must be one of"),
        ("imager.frame_rate_Hz", 5.0, r"observer gains are unstable at imager.frame_rate_Hz=5.0"),
    ],
)
def test_bad_config_values_are_named(key: str, value: object, match: str) -> None:
    m = load_yaml(SOUND)
    flat = flatten(m)
    flat[key] = value
    with pytest.raises(ConfigError, match=match):
        scenario_from_mapping(unflatten(flat))


def test_same_seed_identical_other_seed_differs() -> None:
    s = _short(load_scenario(SOUND), 0.2)
    a = run_closed_loop(s, seed=3)
    b = run_closed_loop(s, seed=3)
    c = run_closed_loop(s, seed=4)
    for k, v in a.timeseries.items():
        np.testing.assert_array_equal(v, b.timeseries[k], err_msg=k)
    assert not np.array_equal(a.timeseries["meas_p"], c.timeseries["meas_p"])


def test_exact_noise_free_loop_converges() -> None:
    # steady flow, exact model, perfect measurements, reference starting at rest at X0
    phys = PhysicsParams(flow=FlowParams(pulsatility=0.0, diameter_pulsation=0.0))
    s = load_scenario(SOUND)
    s = dc.replace(
        s,
        physics=phys,
        model=ModelParams(),
        imager=dc.replace(s.imager, noise_sigma_m=0.0, outliers=()),
        reference=ReferenceParams(anchors_x_m=(0.0, 1e-3, 2e-3, 3e-3), anchors_z_m=(0.0, 0.1e-3, 0.0, 0.1e-3),
                                  duration_s=0.8, timing="rest_to_rest"),
        initial=dc.replace(s.initial, p0_m=(0.0, 0.2e-3)),  # 200 um initial error in z
        sim=SimParams(duration_s=1.6, metrics_after_s=1.2),
    )
    r = run_closed_loop(s)
    e = np.linalg.norm(r.timeseries["p_true"] - r.timeseries["p_ref"], axis=1)
    assert e[0] == pytest.approx(0.2e-3, rel=1e-9)
    # closed-loop roots -5.2, -9.8 1/s: by t = 1.6 s the error has decayed >100x
    assert e[-1] < 2e-6
    assert e[-1] < e[1200] < e[600]
    assert r.metrics["saturation_time_s"] == 0.0


def test_plant_accuracy_through_wall_contact_against_half_step_reference() -> None:
    phys = PhysicsParams()

    def final(ig: IntegratorParams) -> np.ndarray:
        plant = PlantSimulator(phys, ig, 1e-3, (0.0, 1.15e-3), (0.0, 0.02))
        touched = False
        for _ in range(40):
            plant.step(np.array([0.0, 0.08]))
            touched |= plant.output().in_contact
        assert touched
        return plant.state

    # fixed-step RK4 cannot serve as reference here: the vdW force ~ 1/gap^2 near
    # contact makes it unstable at any practical step; use a 100x tighter tolerance
    # (a 5th-order method: equivalent to halving the step more than twice)
    ref = final(IntegratorParams(rtol=1e-8, atol_position_m=1e-11, atol_velocity_m_per_s=1e-9))
    ada = final(IntegratorParams())
    np.testing.assert_allclose(ada[:2], ref[:2], atol=1e-7)
    # velocity while pressed on the wall rings at the contact frequency: compare loosely
    np.testing.assert_allclose(ada[2:], ref[2:], atol=1e-3)


def test_plant_rejects_non_finite_gradient() -> None:
    plant = PlantSimulator(PhysicsParams(), IntegratorParams(), 1e-3, (0.0, 0.0))
    with pytest.raises(ModelInputError, match="applied gradient must be a finite"):
        plant.step([np.nan, 0.0])
    with pytest.raises(ModelInputError, match="dt_control_s must be finite and > 0"):
        PlantSimulator(PhysicsParams(), IntegratorParams(), 0.0, (0.0, 0.0))


def test_cli_writes_metrics_and_timeseries(tmp_path: Path) -> None:
    out = tmp_path / "o"
    rc = cli_main(["simulate", "--config", str(SOUND), "--out", str(out), "--seed", "1",
                   "--set", "sim.duration_s=0.1", "--set", "reference.duration_s=0.1"])
    assert rc == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["n_ticks"] == 100 and metrics["seed"] == 1
    ts = np.load(out / "timeseries.npz")
    assert ts["p_true"].shape == (100, 2)
    assert load_scenario(out / "scenario.yaml").sim.duration_s == 0.1


def test_cli_bad_config_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = cli_main(["simulate", "--config", str(SOUND), "--out", str(tmp_path), "--set", "controller.gains.k2=-1"])
    assert rc == 2
    assert "controller.gains.k2 must be > 0, got -1" in capsys.readouterr().err


# -- bad input to `simulate`: one line, exit 2, before any work (issue 14) ---------------------------------------


def test_control_rate_too_low_is_reported_under_its_own_key() -> None:
    with pytest.raises(ConfigError, match=r"^sim\.control_rate_Hz must give at least 2 control ticks"):
        load_scenario(SOUND, sets=["sim.control_rate_Hz=1e-9"])


@pytest.mark.parametrize("key_value", ["sim.control_rate_Hz=1e9", "sim.duration_s=1e6"])
def test_runs_that_do_not_fit_in_memory_are_refused_before_any_work(tmp_path: Path, capsys, key_value) -> None:
    out = tmp_path / "o"
    rc = cli_main(["simulate", "--config", str(SOUND), "--out", str(out), "--set", key_value,
                   "--set", "imager.frame_rate_Hz=1000"])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "sim.duration_s=" in err[0] and "sim.control_rate_Hz=" in err[0] and "GiB" in err[0]
    assert not out.exists()


def test_resource_check_is_a_scenario_layer_function(tmp_path: Path) -> None:
    from vesselbot_ros.sim.scenario import check_resources, estimate_resources

    s = load_scenario(SOUND)
    est = check_resources(s, bag_dir=tmp_path / "not" / "yet")
    assert est.n_ticks == s.sim.n_ticks and est == estimate_resources(s)
    with pytest.raises(ConfigError, match=r"time series need about .* more than the 1\.0 KiB"):
        check_resources(s, memory_budget_bytes=1024)
    big = load_scenario(SOUND, sets=["sim.duration_s=1e5", "reference.duration_s=2"])
    with pytest.raises(ConfigError, match=r"recording it to .* needs .* free \(.* of bag .*\), but only .* is free on "
                                          r".*--no-record"):
        check_resources(big, bag_dir=tmp_path, memory_budget_bytes=2**62)


def test_set_takes_exponent_floats_without_a_dot(tmp_path: Path) -> None:
    out = tmp_path / "o"
    rc = cli_main(["simulate", "--config", str(SOUND), "--out", str(out), "--set", "imager.noise_sigma_m=1e-4",
                   "--duration", "0.05", "--set", "reference.duration_s=0.05"])
    assert rc == 0
    s = load_scenario(out / "scenario.yaml")
    assert s.imager.noise_sigma_m == 1e-4 and s.sim.duration_s == 0.05


def test_short_run_says_the_metrics_cover_the_whole_run(tmp_path: Path, capsys) -> None:
    out = tmp_path / "o"
    rc = cli_main(["simulate", "--config", str(SOUND), "--out", str(out), "--duration", "0.1",
                   "--set", "reference.duration_s=0.1"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "ends before the metrics window starts (sim.metrics_after_s = 0.6 s)" in text
    m = json.loads((out / "metrics.json").read_text())
    assert m["after_s"] == 0.0 and np.isfinite(m["tracking_error_max_m"])


@pytest.mark.parametrize("name", ["sound_small_artery", "clinical_3t_small_artery", "sound_small_artery_ekf",
                                  "sound_small_artery_adaptive", "paper_iiic_network_upper"])
def test_stages_built_one_at_a_time_run_the_same_loop_as_build_stages(name: str) -> None:
    """A node builds only its own stage (build_stage); the six together give build_stages' run, double for double."""
    from vesselbot_ros.sim.closed_loop import REPLACEABLE, Stages, build_stage, build_stages, run_stages

    s = _short(load_scenario(name), 0.05)
    whole = run_stages(s, build_stages(s, 2), 2, path="per_tick")
    one = {n: build_stage(s, n, 2) for n in REPLACEABLE}
    each = run_stages(s, Stages(**one, model=one["observer"].model), 2, path="per_tick")
    assert whole.timeseries.keys() == each.timeseries.keys()
    for key, col in whole.timeseries.items():
        np.testing.assert_array_equal(each.timeseries[key], col, err_msg=key)
    assert json.dumps(each.metrics, sort_keys=True, default=str) == json.dumps(whole.metrics, sort_keys=True, default=str)


def test_warm_up_of_each_stage_leaves_a_later_run_unchanged_and_names_unknown_stages() -> None:
    from vesselbot_ros.sim.closed_loop import Stages, build_stage, warm_up

    s = _short(load_scenario("clinical_3t_small_artery"), 0.05)  # its first frame reaches the observer at 0.04 s
    before = run_closed_loop(s, 1, path="per_tick")
    for stage in Stages._fields:
        warm_up(s, [stage])
    warm_up(s)
    after = run_closed_loop(s, 1, path="per_tick")
    for key, col in before.timeseries.items():
        np.testing.assert_array_equal(after.timeseries[key], col, err_msg=key)
    with pytest.raises(ModelInputError, match="unknown stage"):
        warm_up(s, ["plant", "coil_driver"])
    with pytest.raises(ModelInputError, match="unknown stage"):
        build_stage(s, "driver")
