"""Tests of vesselbot_ros.physics.params."""

import dataclasses
import math
from pathlib import Path

import pytest

from vesselbot_ros.config import ConfigError, load_dataclass, load_yaml
from vesselbot_ros.physics.params import (
    BloodParams,
    DesignParams,
    FlowParams,
    InteractionParams,
    PhysicsParams,
    RobotParams,
    VesselParams,
    WallParams,
)

CONFIG = Path(__file__).resolve().parents[3] / "config"


def test_table3_mass_density_volume():
    r = RobotParams()
    rho = 0.8 * 7874 + 0.2 * 1500  # 6599.2 kg/m^3
    vol = 4 / 3 * math.pi * (250e-6) ** 3
    assert r.density_kg_per_m3 == pytest.approx(rho, rel=1e-12)
    assert r.volume_m3 == pytest.approx(vol, rel=1e-12)
    assert r.mass_kg == pytest.approx(rho * vol, rel=1e-12)
    assert r.mass_kg == pytest.approx(4.32e-7, rel=1e-2)


@pytest.mark.parametrize(
    ("factory", "match"),
    [
        (lambda: RobotParams(radius_m=-1e-4), r"radius_m must be > 0, got -0.0001"),
        (lambda: RobotParams(radius_m=float("nan")), r"radius_m must be finite"),
        (lambda: BloodParams(hematocrit=1.0), r"hematocrit must be in \[0.0, 1.0\)"),
        (lambda: BloodParams(hematocrit=-0.1), r"hematocrit"),
        (lambda: BloodParams(viscosity_model="bogus"), r"viscosity_model must be one of"),
        (lambda: InteractionParams(electrostatic_model="x"), r"electrostatic_model must be one of"),
        (lambda: WallParams(unloading_exponent=3.0), r"unloading_exponent must be in \[1.5, 2.5\]"),
        (lambda: FlowParams(pulsatility=float("nan")), r"pulsatility must be finite"),
        (lambda: DesignParams(sperm_number=2.0), r"sperm_number must be in \[3.4"),
    ],
)
def test_invalid_fields_raise_naming_the_field(factory, match):
    with pytest.raises(ConfigError, match=match):
        factory()


def test_lambda_at_least_one_is_rejected():
    with pytest.raises(ConfigError, match=r"robot.radius_m must give lambda = 2 r / D_min < 1"):
        PhysicsParams(robot=RobotParams(radius_m=1.4e-3), vessel=VesselParams(diameter_m=3e-3))
    # lambda < 1 at nominal D but >= 1 at the smallest pulsating diameter
    with pytest.raises(ConfigError, match="lambda"):
        PhysicsParams(robot=RobotParams(radius_m=1.45e-3))


def test_yaml_default_matches_dataclass_defaults():
    mapping = load_yaml(CONFIG / "physics_default.yaml")["physics"]
    loaded = load_dataclass(PhysicsParams, mapping, "physics")
    assert loaded == PhysicsParams()


def test_loader_names_dotted_key():
    with pytest.raises(ConfigError, match=r"physics.robot.radius_m must be > 0, got -1"):
        load_dataclass(PhysicsParams, {"robot": {"radius_m": -1}}, "physics")
    with pytest.raises(ConfigError, match=r"unknown key physics.blood.viscosity"):
        load_dataclass(PhysicsParams, {"blood": {"viscosity": 1}}, "physics")


def test_with_overrides_revalidates_and_is_pure():
    base = PhysicsParams()
    p = base.with_overrides({"flow.centreline_velocity_m_per_s": 0.02625, "interactions.electrostatic_model": "paper_printed"})
    assert p.flow.centreline_velocity_m_per_s == 0.02625
    assert p.interactions.electrostatic_model == "paper_printed"
    assert base.flow.centreline_velocity_m_per_s == 0.025
    with pytest.raises(ConfigError, match="unknown override key flow.bogus"):
        base.with_overrides({"flow.bogus": 1.0})
    with pytest.raises(ConfigError, match="robot.radius_m must be > 0"):
        base.with_overrides({"robot.radius_m": -1.0})
    assert dataclasses.replace(base, robot=RobotParams(radius_m=1e-4)).robot.radius_m == 1e-4


def test_params_are_hashable_for_caching():
    assert hash(PhysicsParams()) == hash(PhysicsParams())


def test_vdw_floor_brush_limited_default_and_explicit():
    it = InteractionParams()
    assert it.vdw_min_separation == "brush_limited"
    assert it.vdw_floor_m == pytest.approx(0.2 * 100e-9, rel=1e-15)
    assert InteractionParams(brush_length_m=50e-9, brush_compressed_fraction=0.3).vdw_floor_m == pytest.approx(15e-9)
    ex = InteractionParams(vdw_min_separation="explicit", vdw_min_separation_m=0.4e-9)
    assert ex.vdw_floor_m == 0.4e-9
    with pytest.raises(ConfigError, match="vdw_min_separation must be one of"):
        InteractionParams(vdw_min_separation="atomic")
    with pytest.raises(ConfigError, match=r"brush_compressed_fraction must be in \(0.0, 1.0\]"):
        InteractionParams(brush_compressed_fraction=0.0)


def test_flow_preset_and_inflow_fraction_are_validated_and_left_out_of_the_mapping_at_their_defaults():
    from vesselbot_ros.config import to_mapping

    assert set(to_mapping(FlowParams())) == {"centreline_velocity_m_per_s", "pulsatility", "angular_frequency_rad_per_s",
                                             "phase_rad", "diameter_pulsation"}
    f = FlowParams(preset="healthy_adult_cca", inflow_fraction=0.1)
    assert to_mapping(f)["preset"] == "healthy_adult_cca" and to_mapping(f)["inflow_fraction"] == 0.1
    assert f.inflow_velocity_m_per_s == 0.025 * 0.1
    assert FlowParams().inflow_velocity_m_per_s == 0.025  # exact at 1
    for bad, msg in [(-0.1, r"flow\.inflow_fraction must be in \[0\.0, 1\.0\], got -0\.1"),
                     (float("nan"), r"flow\.inflow_fraction must be finite, got nan")]:
        with pytest.raises(ConfigError, match=msg):
            load_dataclass(PhysicsParams, {"flow": {"inflow_fraction": bad}}, "")
    with pytest.raises(ConfigError, match=r"flow\.preset must be '' or a name of letters, digits and '_', got 'a b'"):
        load_dataclass(PhysicsParams, {"flow": {"preset": "a b"}}, "")
