"""Tests of the campaign spec: strict loading, key checks, distributions, run expansion."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from vesselbot_ros.campaign.spec import (
    Distribution,
    campaign_spec_from_mapping,
    check_scenario_key,
    expand_points,
    load_campaign_spec,
)
from vesselbot_ros.cli import main as cli_main
from vesselbot_ros.config import ConfigError
from vesselbot_ros.sim.scenario import load_scenario, scenario_from_mapping

ROOT = Path(__file__).resolve().parents[3]
SOUND = ROOT / "config" / "sound_small_artery.yaml"


def _write(tmp_path: Path, **doc) -> Path:
    doc.setdefault("name", "t")
    doc.setdefault("base", str(SOUND))
    p = tmp_path / "spec.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


def test_shipped_examples_load_and_expand() -> None:
    spec, base = load_campaign_spec(ROOT / "config" / "campaigns" / "vf_error_seeds.yaml")
    points = expand_points(spec, base)
    assert len(points) == 400
    assert [p.seed for p in points[:3]] == [0, 1, 2]
    assert [p.values["variant"] for p in points[::100]] == ["bs24_printed_hold", "bs24_midpoint", "adaptive_bs",
                                                             "ekf_flow_estimate"]
    assert sum(p.keep_timeseries for p in points) == 4  # seed 0 of each controller
    # the adaptive and EKF variants are exactly the shipped scenarios (but for name and seed)
    for index, name in ((200, "sound_small_artery_adaptive"), (300, "sound_small_artery_ekf")):
        variant = scenario_from_mapping(points[index].mapping)
        shipped = load_scenario(ROOT / "config" / f"{name}.yaml")
        assert dataclasses.replace(variant, name=shipped.name, seed=shipped.seed) == shipped
    assert base["model"]["overrides"]["flow"]["centreline_velocity_m_per_s"] == pytest.approx(1.05 * 0.025, rel=0, abs=1e-12)

    spec, base = load_campaign_spec(ROOT / "config" / "campaigns" / "table2_ranges.yaml")
    points = expand_points(spec, base)
    assert len(points) == 100
    assert [p.seed for p in points] == list(range(100))  # paired: draw i with seed i
    eps = np.array([p.values["physics.blood.relative_permittivity"] for p in points])
    assert eps.min() >= 45.0 and eps.max() < 77.0
    # the plant varies, the controller's model stays nominal
    m = points[5].mapping
    assert m["physics"]["blood"]["relative_permittivity"] == points[5].values["physics.blood.relative_permittivity"]
    assert m["model"]["overrides"]["blood"]["relative_permittivity"] == 70.0


def test_expansion_order_is_grid_then_draws_then_seeds(tmp_path) -> None:
    p = _write(tmp_path, seeds=[3, 4], grid={"controller.sample_hold": ["none", "midpoint"]},
               samples={"count": 2, "rng_seed": 7, "params": {"imager.noise_sigma_m": {
                   "distribution": "uniform", "low": 50e-6, "high": 150e-6}}},
               keep_timeseries={"runs": [5]})
    spec, base = load_campaign_spec(p)
    pts = expand_points(spec, base)
    assert [p.index for p in pts] == list(range(8))
    assert [p.seed for p in pts] == [3, 4] * 4
    assert [p.values["controller.sample_hold"] for p in pts] == ["none"] * 4 + ["midpoint"] * 4
    sig = [p.values["imager.noise_sigma_m"] for p in pts]
    assert sig[0] == sig[1] and sig[2] == sig[3] and sig[0] != sig[2]
    assert sig[:4] == sig[4:]  # the same draws for every grid point
    assert [p.keep_timeseries for p in pts] == [i == 5 for i in range(8)]
    assert pts[2].mapping["imager"]["noise_sigma_m"] == sig[2]
    assert pts[2].mapping["seed"] == 3
    # deterministic: same spec, same draws
    assert [p.values for p in expand_points(spec, base)] == [p.values for p in pts]


def test_variants_are_the_outer_axis_and_set_their_keys_together(tmp_path) -> None:
    p = _write(tmp_path, seeds=[0, 1], grid={"imager.noise_sigma_m": [50e-6, 100e-6]},
               variants={"a": {}, "b": {"controller.gains.k1": 150.0, "controller.gains.k2": 150.0}})
    spec, base = load_campaign_spec(p)
    assert spec.varied_keys() == ("variant", "imager.noise_sigma_m")
    assert spec.group_keys() == ("variant", "imager.noise_sigma_m")
    pts = expand_points(spec, base)
    assert [p.values["variant"] for p in pts] == ["a"] * 4 + ["b"] * 4
    assert [p.values["imager.noise_sigma_m"] for p in pts] == [50e-6, 50e-6, 100e-6, 100e-6] * 2
    assert {p.mapping["controller"]["gains"]["k1"] for p in pts[:4]} == {base["controller"]["gains"]["k1"]}
    assert {(p.mapping["controller"]["gains"]["k1"], p.mapping["controller"]["gains"]["k2"]) for p in pts[4:]} == {(150.0, 150.0)}
    # without variants there is no variant column
    spec, _ = load_campaign_spec(_write(tmp_path, grid={"imager.noise_sigma_m": [50e-6]}))
    assert spec.varied_keys() == ("imager.noise_sigma_m",)


@pytest.mark.parametrize(
    ("doc", "match"),
    [
        ({"bogus": 1}, r"unknown key bogus"),
        ({"variants": {"a": {"controller.gains.bogus": 1.0}}}, r"variants\.a\.controller\.gains\.bogus: unknown scenario key"),
        ({"variants": {"a": {"controller.gains.k1": -1.0}}}, r"variants\.a gives an invalid scenario: .*k1 must be > 0"),
        ({"variants": {"a b": {}}}, r"variants: name must be"),
        ({"variants": {"a": [1]}}, r"variants\.a must be a mapping"),
        ({"variants": {"a": {"imager.noise_sigma_m": 1e-5}}, "grid": {"imager.noise_sigma_m": [1e-5]}},
         r"variants\.a\.imager\.noise_sigma_m is also varied"),
        ({"grid": {"physics.blood.bogus_Pa": [1.0]}}, r"grid\.physics\.blood\.bogus_Pa: unknown scenario key"),
        ({"grid": {"physics.blood": [1.0]}}, r"names a section"),
        ({"grid": {"seed": [1, 2]}}, r"set by the campaign"),
        ({"grid": {"physics.robot.radius_m": []}}, r"grid\.physics\.robot\.radius_m must be a non-empty list"),
        ({"grid": {"physics.robot.radius_m": [250e-6, -1.0]}}, r"grid\.physics\.robot\.radius_m\[1\] = -1\.0 .*must be > 0"),
        ({"overrides": {"sim.duration_s": -2}}, r"sim\.duration_s must be > 0, got -2"),
        ({"seeds": [1, 1]}, r"seeds must not repeat"),
        ({"seeds": {"start": 0, "count": 0}}, r"count must be >= 1"),
        ({"samples": {"count": 2, "params": {"physics.robot.radius_m": {"distribution": "uniform", "low": 1e-4}}}},
         r"samples\.params\.physics\.robot\.radius_m\.high is required"),
        ({"samples": {"count": 2, "params": {"physics.robot.radius_m": {"distribution": "uniform", "low": 2e-4, "high": 1e-4}}}},
         r"high must be > low"),
        ({"samples": {"count": 2, "params": {"physics.robot.radius_m": {"distribution": "log_uniform", "low": 0.0, "high": 1e-4}}}},
         r"low must be > 0"),
        ({"samples": {"count": 2, "params": {"physics.robot.radius_m": {"distribution": "normal", "mean": 1e-4, "std": 1e-5, "low": 0.0}}}},
         r"low does not apply"),
        ({"samples": {"count": 2, "params": {"physics.robot.radius_m": {"distribution": "gamma", "low": 0.0, "high": 1.0}}}},
         r"distribution must be one of"),
        ({"samples": {"count": 2, "params": {"physics.robot.radius_m": {"distribution": "uniform", "low": -2e-4, "high": -1e-4}}}},
         r"samples\.params\.physics\.robot\.radius_m: value -0\.00015.* \(centre of the distribution\) .*must be > 0"),
        ({"samples": {"count": 3, "paired_with_seeds": True, "params": {"imager.noise_sigma_m": {
            "distribution": "uniform", "low": 1e-5, "high": 2e-5}}}, "seeds": [0, 1]}, r"as many seeds as samples\.count \(3\)"),
        ({"grid": {"imager.noise_sigma_m": [1e-5]}, "samples": {"count": 1, "params": {"imager.noise_sigma_m": {
            "distribution": "uniform", "low": 1e-5, "high": 2e-5}}}}, r"both vary 'imager\.noise_sigma_m'"),
        ({"chunk_size": -1}, r"chunk_size must be >= 0"),
        ({"base": "nowhere.yaml"}, r"base: config file .*nowhere\.yaml' does not exist"),
    ],
)
def test_bad_specs_name_key_and_value(tmp_path, doc, match) -> None:
    with pytest.raises(ConfigError, match=match):
        load_campaign_spec(_write(tmp_path, **doc))


def test_bad_spec_is_one_line_and_exit_2(tmp_path, capsys) -> None:
    p = _write(tmp_path, grid={"physics.blood.bogus_Pa": [1.0]})
    assert cli_main(["campaign", str(p), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown scenario key 'physics.blood.bogus_Pa'" in err[0]
    assert not (tmp_path / "out").exists()
    assert cli_main(["campaign", "report"]) == 2
    assert cli_main(["campaign", "report", str(tmp_path / "nothing")]) == 2
    assert "not a campaign folder" in capsys.readouterr().err


def test_scenario_keys_inside_free_form_mappings_are_accepted() -> None:
    check_scenario_key("model.overrides.flow.centreline_velocity_m_per_s")
    check_scenario_key("sim.integrator.rtol")
    with pytest.raises(ConfigError, match="is a value, not a section"):
        check_scenario_key("sim.duration_s.x")


def test_distributions_draw_in_range_with_the_right_moments() -> None:
    rng = np.random.default_rng(0)
    u = Distribution("uniform", low=2.0, high=3.0).draw(rng, 20000)
    assert u.min() >= 2.0 and u.max() < 3.0
    assert np.mean(u) == pytest.approx(2.5, abs=0.01)
    lu = Distribution("log_uniform", low=1e-3, high=1e-1).draw(rng, 20000)
    assert lu.min() >= 1e-3 and lu.max() < 1e-1
    assert np.median(np.log10(lu)) == pytest.approx(-2.0, abs=0.03)  # uniform in the log
    n = Distribution("normal", mean=5.0, std=0.5).draw(rng, 20000)
    assert np.mean(n) == pytest.approx(5.0, abs=0.02) and np.std(n) == pytest.approx(0.5, rel=0.03)
    assert Distribution("log_uniform", low=1.0, high=100.0).centre() == pytest.approx(10.0, rel=1e-12)
    assert math.isfinite(Distribution("normal", mean=1.0, std=2.0).centre())


def test_spec_from_mapping_accepts_seed_list_or_range() -> None:
    a = campaign_spec_from_mapping({"name": "a", "base": "x.yaml", "seeds": {"start": 5, "count": 3}})
    b = campaign_spec_from_mapping({"name": "b", "base": "x.yaml", "seeds": [5, 6, 7]})
    assert a.seed_list() == b.seed_list() == (5, 6, 7)


def test_a_variant_switches_a_stage_to_a_users_kind_and_grids_its_keys(tmp_path, monkeypatch) -> None:
    """A variant naming another controller kind drops the base's backstepping keys; its own keys are checked."""
    monkeypatch.syspath_prepend(str(ROOT / "test" / "plugins"))
    kind = "vesselbot_test_plugin:IntegralController"
    spec, base = load_campaign_spec(_write(tmp_path, seeds=[0], variants={
        "law24": {}, "pid": {"controller.kind": kind, "controller.ki_per_s3": 300.0}}))
    points = expand_points(spec, base)
    pid = next(p for p in points if p.values["variant"] == "pid")
    assert pid.mapping["controller"] == {"kind": kind, "ki_per_s3": 300.0}
    assert scenario_from_mapping(pid.mapping).controller.ki_per_s3 == 300.0
    law = next(p for p in points if p.values["variant"] == "law24")
    assert "gains" in law.mapping["controller"]
    with pytest.raises(ConfigError, match=r"variants\.pid gives an invalid scenario: unknown key controller\.kx"):
        load_campaign_spec(_write(tmp_path, variants={"pid": {"controller.kind": kind, "controller.kx": 1.0}}))
    with pytest.raises(ConfigError, match=r"unknown scenario key 'controler\.kind'"):  # outside the sections: static
        campaign_spec_from_mapping({"name": "t", "base": str(SOUND), "grid": {"controler.kind": ["a"]}})


def test_a_campaign_of_a_billion_runs_is_refused_before_its_runs_are_listed(tmp_path: Path) -> None:
    """``seeds: {count: 1e9}`` (and 1e9 x a grid): the old loader listed the seeds, then a billion runs."""
    from vesselbot_ros.testing import cli_under_memory_limit

    spec = tmp_path / "big.yaml"
    spec.write_text(yaml.safe_dump({"name": "big", "base": str(SOUND), "seeds": {"start": 0, "count": 10**9}}))
    proc = cli_under_memory_limit(["campaign", str(spec), "--out", str(tmp_path / "out")], timeout=60)
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr and "MemoryError" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "seeds=1000000000 seeds (1e+09 runs): the campaign's list of runs and their results needs about" in lines[0]
    assert "TiB of memory" in lines[0] and not (tmp_path / "out").exists()
    grid = {"name": "g", "base": str(SOUND), "seeds": [0, 1], "grid": {"imager.noise_sigma_m": [1e-5 * (i + 1) for i in range(4)]},
            "samples": {"count": 10**9, "params": {"physics.robot.radius_m": {"distribution": "uniform", "low": 1e-4,
                                                                                         "high": 2e-4}}}}
    with pytest.raises(ConfigError, match=r"^samples\.count=1000000000 samples\.count \(8e\+09 runs\): "):
        campaign_spec_from_mapping(grid)
    assert campaign_spec_from_mapping(dict(grid, samples={**grid["samples"], "count": 3})).n_runs() == 24
