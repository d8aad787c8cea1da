"""`vesselbot scenarios`: one line per shipped scenario, the default marked; works from any directory."""

from __future__ import annotations

from vesselbot_ros import cli
from vesselbot_ros.sim.scenario import shipped_scenarios


def test_one_line_per_shipped_scenario_with_its_description(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["scenarios"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [ln.split()[0] for ln in lines] == sorted(shipped_scenarios())
    assert {"paper_small_artery", "sound_small_artery", "sound_small_artery_ekf", "sound_small_artery_adaptive",
            "clinical_3t_small_artery", "paper_iiic_network_upper"} <= set(shipped_scenarios())
    by_name = {ln.split()[0]: ln for ln in lines}
    assert by_name["sound_small_artery"].endswith("(default)")
    assert "PRINTED" in by_name["paper_small_artery"] and "(default)" not in by_name["paper_small_artery"]
