"""The design for a vessel tree: per outlet, bead and flow, a plan or the segment and the acceleration missing."""

from __future__ import annotations

import subprocess
import sys

import pytest

from vesselbot_ros.analysis.tree_design import TABLE3, flow_changes, tree_design
from vesselbot_ros.config import ConfigError
from vesselbot_ros.sim.scenario import load_scenario


def test_each_outlet_under_table3_flies_and_a_physiological_flow_names_what_is_missing() -> None:
    base = load_scenario("paper_iiic_network_lower")
    cells = tree_design(base, ["lower", "upper"], [250e-6], ["paper"], [TABLE3, "brachial_levenson_1981"])
    by = {(c.outlet, c.flow): c for c in cells}
    assert len(cells) == 4
    for outlet in ("lower", "upper"):
        ok = by[(outlet, TABLE3)]
        assert ok.status == "ok" and ok.margin_m_per_s2 >= 0.0 and ok.end_s > 0.0
        bad = by[(outlet, "brachial_levenson_1981")]
        assert bad.status.startswith("infeasible: segment") and bad.missing_m_per_s2 > 0.0
        assert f"{bad.missing_m_per_s2:.2f} m/s^2 missing" in bad.status


def test_flow_conditions_parse_and_refuse_in_one_line() -> None:
    assert flow_changes(TABLE3) == {}
    assert flow_changes("p@0.25") == {"physics.flow.preset": "p", "physics.flow.inflow_fraction": 0.25}
    for bad in ("p@x", "p@1.5", "p@nan"):
        with pytest.raises(ConfigError, match="inflow fraction"):
            flow_changes(bad)
    with pytest.raises(ConfigError, match="network scenario"):
        tree_design(load_scenario("sound_small_artery"), ["x"], [250e-6], ["paper"], [TABLE3])


@pytest.mark.parametrize(("args", "says"), [
    (["--outlets", "nowhere"], "--outlets: 'nowhere' is not an outlet"),
    (["--flows", "no_such_preset"], "--flows: 'no_such_preset' is not a flow preset"),
    (["--config", "sound_small_artery"], "needs a network or tree scenario"),
])
def test_the_command_refuses_a_bad_argument_in_one_line_exit_2(tmp_path, args, says) -> None:
    cmd = [sys.executable, "-m", "vesselbot_ros.cli", "tree-design", "--config", "paper_iiic_network_lower",
           "--out", str(tmp_path / "o"), "--no-progress", *args]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and says in lines[0], r.stderr
