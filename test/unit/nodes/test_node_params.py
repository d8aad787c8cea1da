"""Scenario <-> ROS parameters: exact round trip and the same validation as YAML."""

from __future__ import annotations

import dataclasses

import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.nodes.params import scenario_from_parameters, scenario_schema, scenario_to_parameters, write_params_file
from vesselbot_ros.scanner.imager_model import OutlierBurst
from vesselbot_ros.sim.scenario import Scenario, load_scenario


def test_every_parameter_is_a_ros_type():
    for name, spec in scenario_schema().items():
        v = spec.default
        ok = isinstance(v, (bool, int, float, str)) or (isinstance(v, list) and v and len({type(x) for x in v}) == 1)
        assert ok, f"{name}: {v!r} cannot be a ROS parameter"
        assert not spec.yaml_encoded or isinstance(v, str), name


def test_paper_scenario_round_trips_exactly(repo):
    s = load_scenario(repo / "config" / "paper_small_artery.yaml")
    params = scenario_to_parameters(s)
    # the 5 % model error and the outlier burst travel as YAML strings
    assert params["model.overrides"] == '{"flow": {"centreline_velocity_m_per_s": 0.02625}}'
    assert params["imager.outliers"].startswith("[{")
    assert scenario_from_parameters(params) == s


def test_missing_parameters_take_the_defaults():
    s = scenario_from_parameters({"seed": 7})
    assert s == dataclasses.replace(Scenario(), seed=7)


def test_list_of_records_from_a_yaml_string():
    s = scenario_from_parameters({"imager.outliers": "[{start_s: 0.25, duration_s: 0.01, magnitude_m: 0.002}]"})
    assert s.imager.outliers == (OutlierBurst(0.25, 0.01, 0.002),)


@pytest.mark.parametrize(
    ("name", "value", "match"),
    [
        ("imager.noise_sigma_m", -1.0, r"imager\.noise_sigma_m must be >= 0, got -1\.0"),
        ("coil.slew_rate", "fast", r"coil\.slew_rate must be one of"),
        ("sim.control_rate_Hz", "1000", r"sim\.control_rate_Hz must be a number"),
        ("imager.frame_rate_Hz", float("nan"), r"imager\.frame_rate_Hz must be finite"),
        ("imager.outliers", "[{start_s: 0.5", r"parameter imager\.outliers is not valid YAML: line 1 column 15"),
        ("controller.gains.k9", 1.0, r"unknown parameter 'controller\.gains\.k9'"),
    ],
)
def test_bad_values_name_the_parameter(name, value, match):
    with pytest.raises(ConfigError, match=match):
        scenario_from_parameters({name: value})


def test_params_file_is_a_ros_params_file(tmp_path):
    import yaml

    p = write_params_file(tmp_path / "p.yaml", {"seed": 3, "imager.outliers": "[]"})
    data = yaml.safe_load(p.read_text())
    assert data == {"/**": {"ros__parameters": {"seed": 3, "imager.outliers": "[]"}}}


# -- one YAML parser, one override path: property-based round trips (issue 14) -----------------------------------

from hypothesis import HealthCheck, given, reject, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


def _exp_floats(lo: float, hi: float) -> st.SearchStrategy[float]:
    """Floats spread over decades (``4e-19`` style values that JSON writes without a dot)."""
    import math

    return st.floats(math.log10(lo), math.log10(hi)).map(lambda e: float(f"{10 ** e:.6g}"))


@st.composite
def scenarios(draw: st.DrawFn) -> tuple[Scenario, dict[str, object]]:
    """A valid scenario from a shipped config with generated values, and the dotted overrides that made it."""
    from pathlib import Path

    from vesselbot_ros.config import apply_overrides, load_yaml
    from vesselbot_ros.sim.scenario import scenario_from_mapping

    base = draw(st.sampled_from(["paper_small_artery", "sound_small_artery"]))
    sets: dict[str, object] = {
        "seed": draw(st.integers(0, 2**31 - 1)),
        "imager.noise_sigma_m": draw(_exp_floats(1e-9, 1e-3)),
        "controller.gains.k1": draw(_exp_floats(0.1, 100.0)),
        "coil.saturation_T_per_m": draw(_exp_floats(1e-3, 10.0)),
        "sim.duration_s": draw(_exp_floats(0.01, 3.0)),
    }
    overrides: dict[str, object] = {}
    if draw(st.booleans()):
        overrides.setdefault("interactions", {})["hamaker_constant_J"] = draw(_exp_floats(1e-22, 1e-16))
    if draw(st.booleans()):
        overrides.setdefault("flow", {})["centreline_velocity_m_per_s"] = draw(_exp_floats(1e-4, 0.1))
    if draw(st.booleans()):
        overrides.setdefault("robot", {})["magnetization_A_per_m"] = draw(_exp_floats(1e4, 2e6))
    sets["model.overrides"] = overrides
    if draw(st.booleans()):
        sets["imager.outliers"] = [{"start_s": draw(_exp_floats(1e-3, 1.0)), "duration_s": draw(_exp_floats(1e-4, 0.1)),
                                    "magnitude_m": draw(_exp_floats(1e-7, 1e-2))}]
    mapping = load_yaml(Path(__file__).resolve().parents[3] / "config" / f"{base}.yaml")
    try:
        return scenario_from_mapping(apply_overrides(mapping, sets)), sets
    except ConfigError:
        reject()


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(scenarios())
def test_generated_scenarios_round_trip_through_parameters_yaml_and_set(tmp_path_factory, drawn):
    import json

    import yaml

    from vesselbot_ros.config import parse_yaml_text
    from vesselbot_ros.sim.scenario import load_scenario, scenario_from_mapping

    s, sets = drawn
    # ROS parameters (what `run` hands its nodes): the YAML strings are JSON, e.g. 4e-19
    assert scenario_from_parameters(scenario_to_parameters(s)) == s
    # through a params file as ROS reads it back (PyYAML's dump, our loader)
    assert scenario_from_mapping(parse_yaml_text(yaml.safe_dump(s.to_mapping()))) == s
    # the scenario.yaml that `simulate` writes, loaded as a --config
    f = tmp_path_factory.mktemp("rt") / "s.yaml"
    f.write_text(yaml.safe_dump(s.to_mapping()))
    assert load_scenario(f) == s
    # --set KEY=VALUE with VALUE as a user types it (JSON/Python repr, 1e-4 without a dot)
    base = f.with_name("base.yaml")
    base.write_text(yaml.safe_dump(dataclasses.replace(s, seed=0, model=dataclasses.replace(
        s.model, overrides={"flow": {"pulsatility": 1.0}})).to_mapping()))
    argv = [f"{k}={json.dumps(v)}" for k, v in sets.items()]
    assert load_scenario(base, sets=argv) == s


def test_set_of_a_mapping_replaces_it(repo):
    s = load_scenario(repo / "config" / "paper_small_artery.yaml", sets=["model.overrides={}"])
    assert s.model.overrides == {} and s.model_physics() == s.physics
    s = load_scenario(repo / "config" / "paper_small_artery.yaml",
                      sets=["model.overrides={interactions: {hamaker_constant_J: 4e-19}}"])
    assert s.model.overrides == {"interactions": {"hamaker_constant_J": 4e-19}}


def test_duration_and_seed_go_through_the_same_path(repo):
    s = load_scenario(repo / "config" / "paper_small_artery.yaml", sets=["sim.duration_s=1", "seed=4"],
                      duration=0.5, seed=9)
    assert (s.sim.duration_s, s.seed) == (0.5, 9)


def test_a_users_kind_declares_its_own_section_and_round_trips(repo, monkeypatch):
    """The schema follows the kinds the parameters name: a node builds a user's controller from its parameters."""
    from vesselbot_ros.nodes.params import kind_parameters

    monkeypatch.syspath_prepend(str(repo / "test" / "plugins"))
    kind = "vesselbot_test_plugin:IntegralController"
    assert kind_parameters()["controller.kind"] == "backstepping" and "physics.kind" in kind_parameters()
    schema = scenario_schema({"controller.kind": kind})
    assert {n for n in schema if n.startswith("controller.")} == {
        "controller.kind", "controller.kp_per_s2", "controller.kd_per_s", "controller.ki_per_s3"}
    assert schema["controller.kind"].default == kind and "controller.gains.k1" in scenario_schema()
    s = load_scenario(repo / "config" / "sound_small_artery.yaml", sets=[f"controller.kind={kind}", "controller.ki_per_s3=5"])
    params = scenario_to_parameters(s)
    assert params["controller.kind"] == kind and params["controller.ki_per_s3"] == 5.0
    assert scenario_from_parameters(params) == s
    with pytest.raises(ConfigError, match=r"unknown parameter 'controller\.gains\.k1'"):
        scenario_from_parameters({"controller.kind": kind, "controller.gains.k1": 1.0})
    with pytest.raises(ConfigError, match=r"controller\.kind: unknown controller kind 'pid'"):
        scenario_from_parameters({"controller.kind": "pid"})
