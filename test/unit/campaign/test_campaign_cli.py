"""Tests of ``vesselbot campaign``'s command line: ``--set`` is read and applied as every other command reads it."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import pytest

from vesselbot_ros.campaign import campaign_cli, engine
from vesselbot_ros.campaign.spec import load_campaign_spec
from vesselbot_ros.config import ConfigError
from vesselbot_ros.sim.scenario import load_scenario, scenario_from_mapping

ROOT = Path(__file__).resolve().parents[3]
SPEC = ROOT / "config" / "campaigns" / "vf_error_seeds.yaml"


class _Prepared(Exception):
    """Raised in place of the campaign's runs: the test reads the base they would start from."""


def _base_after(monkeypatch: pytest.MonkeyPatch, *sets: str) -> dict[str, Any]:
    seen: dict[str, Any] = {}

    def prepare(spec: Any, base: dict[str, Any]) -> None:
        seen["base"] = base
        raise _Prepared

    monkeypatch.setattr(engine, "prepare", prepare)
    parser = argparse.ArgumentParser()
    campaign_cli.register(parser)
    args = parser.parse_args([str(SPEC), *[a for s in sets for a in ("--set", s)]])
    with pytest.raises(_Prepared):
        campaign_cli.run(args)
    return seen["base"]


def test_set_gives_the_scenario_simulate_gives(monkeypatch) -> None:
    """``1e-4`` is a number (the one YAML reader; PyYAML's safe_load reads it as a string), ``{}`` replaces the
    mapping at its key, and a switched controller kind drops the old kind's keys: as ``simulate --set`` does."""
    sets = ("physics.robot.radius_m=1e-4", "model.overrides={}", "controller.kind=predictive")
    base = _base_after(monkeypatch, *sets)
    spec, _ = load_campaign_spec(SPEC)
    assert base["physics"]["robot"]["radius_m"] == 1e-4 and base["model"]["overrides"] == {}
    assert scenario_from_mapping(base) == load_scenario(ROOT / "config" / "sound_small_artery.yaml", sets=sets,
                                                        changes=spec.overrides)


@pytest.mark.parametrize("item, words", [("sim.duration_s", "KEY=VALUE"), ("sim.duration_s=[1, 2", "not valid YAML"),
                                         ("sim.duration_s=0.5=", "sim.duration_s"), ("sim.nonsense=1", "nonsense")])
def test_a_bad_set_is_one_error_naming_it(monkeypatch, item, words) -> None:
    with pytest.raises(ConfigError, match=words):
        _base_after(monkeypatch, item)
