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


def test_a_description_is_a_whole_sentence_not_cut_at_an_abbreviation(tmp_path):
    from vesselbot_ros.sim.scenarios_cli import describe

    path = tmp_path / "s.yaml"
    path.write_text("# Steered in turn (Tamaz et al., the paper's ref. [23]), e.g. at 3 T. Second sentence.\n"
                    "name: s\n")
    assert describe(str(path)) == "Steered in turn (Tamaz et al., the paper's ref. [23]), e.g. at 3 T."
    for name, p in shipped_scenarios().items():
        text = describe(str(p))
        assert text.endswith(".") and not text.endswith(("ref.", "al.")), (name, text)
