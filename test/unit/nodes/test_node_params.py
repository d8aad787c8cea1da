"""Scenario <-> ROS parameters: exact round trip and the same validation as YAML."""

from __future__ import annotations

import dataclasses

import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.imager_model import OutlierBurst
from vesselbot_ros.nodes.params import scenario_from_parameters, scenario_schema, scenario_to_parameters, write_params_file
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
        ("imager.outliers", "[{start_s: 0.5", r"imager\.outliers must be a YAML string"),
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
