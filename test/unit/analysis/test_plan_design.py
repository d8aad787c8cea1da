"""The bead design grid on a scanner: which bead the coil can fly along a path, with what floor."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from vesselbot_ros.analysis.plan_design import MATERIALS, bead_scenario, design_grid
from vesselbot_ros.analysis.scanner_study import preset_changes
from vesselbot_ros.cli import main
from vesselbot_ros.config import ConfigError
from vesselbot_ros.sim.scenario import load_scenario


@pytest.fixture(scope="module")
def clinical():
    return load_scenario("clinical_3t_small_artery", sets=[f"{k}={v}" for k, v in preset_changes("clinical_3t").items()])


def test_a_bead_is_swapped_in_and_the_start_kept_inside_the_lumen_it_leaves(clinical):
    big = bead_scenario(clinical, 500e-6, "permendur")
    r = big.physics.robot
    assert (r.radius_m, r.magnetic_ratio, r.magnetization_A_per_m) == (500e-6, 1.0, MATERIALS["permendur"].magnetization_A_per_m)
    half = 0.5 * 3e-3 * 0.9 - 500e-6 - 50e-6  # the narrowest lumen, 50 um of margin
    assert abs(big.initial.p0_m[1]) <= half + 1e-15 and all(abs(z) <= half + 1e-15 for z in big.reference.anchors_z_m)
    with pytest.raises(ConfigError, match="material must be one of"):
        bead_scenario(clinical, 250e-6, "unobtainium")
    with pytest.raises(ConfigError, match="does not fit the vessel"):
        bead_scenario(clinical, 1.4e-3, "iron")


def test_the_paper_bead_flies_on_the_wall_and_a_weak_one_is_refused_with_the_acceleration_missing(clinical):
    cells = {c.material: c for c in design_grid(clinical, [250e-6], ["paper", "magnetite_50"])}
    assert cells["paper"].status == "ok" and cells["paper"].where == "lower wall"
    assert cells["paper"].margin_m_per_s2 > 0.0 and 50e-6 < cells["paper"].coast_floor_m < 300e-6
    weak = cells["magnetite_50"]
    assert weak.status.startswith("infeasible: segment") and weak.missing_m_per_s2 > 0.0
    assert math.isnan(weak.coast_floor_m)


def test_the_command_writes_the_grid_and_the_map(tmp_path, capsys):
    assert main(["plan-design", "--radii-um", "250", "--materials", "paper,magnetite_50", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "lowest coast floor: r = 250 um paper" in out
    rows = list(csv.DictReader((tmp_path / "design.csv").open()))
    assert [r["material"] for r in rows] == ["paper", "magnetite_50"]
    assert (tmp_path / "design.png").stat().st_size > 5000 and "| paper | 250 | yes |" in (tmp_path / "design.md").read_text()
    assert main(["plan-design", "--materials", "kryptonite", "--out", str(tmp_path)]) == 2
    assert "kryptonite" in capsys.readouterr().err


def test_the_docs_quote_the_stored_design_grid():
    root = Path(__file__).resolve().parents[3]
    table = (root / "docs" / "plan_study" / "design.md").read_text()
    assert "<!-- BEGIN plan_design -->\n" + table + "<!-- END plan_design -->" in (root / "docs" / "reproduction.md").read_text()
