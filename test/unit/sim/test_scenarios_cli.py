"""`vesselbot scenarios`: every shipped scenario with its whole description (wrapped, indented), the default
marked, a scenario the loader refuses marked with the loader's one line; works from any directory."""

from __future__ import annotations

import shutil

from vesselbot_ros import cli
from vesselbot_ros.sim import scenario as scenario_mod
from vesselbot_ros.sim.scenario import shipped_scenarios


def _entries(out: str) -> dict[str, list[str]]:
    """``{name line: [its indented lines]}`` of the command's output."""
    entries: dict[str, list[str]] = {}
    for ln in out.splitlines():
        if ln.startswith(" "):
            entries[list(entries)[-1]].append(ln)
        else:
            entries[ln] = []
    return entries


def test_each_shipped_scenario_with_its_whole_description_wrapped_and_indented(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("COLUMNS", "80")
    assert cli.main(["scenarios"]) == 0
    entries = _entries(capsys.readouterr().out)
    names = [e.split()[0] for e in entries]
    assert names == sorted(shipped_scenarios())
    assert {"paper_small_artery", "sound_small_artery", "sound_small_artery_ekf", "sound_small_artery_adaptive",
            "clinical_3t_small_artery", "paper_iiic_network_upper", "folio_2017_tro"} <= set(names)
    assert "sound_small_artery (default)" in entries and "paper_small_artery" in entries
    for lines in entries.values():
        assert lines and all(ln.startswith("    ") and len(ln) <= 79 for ln in lines), lines
    def described(lines: list[str]) -> list[str]:  # the description's lines, not a mark ("    ! ..." and its "      ")
        return [ln for ln in lines if not ln.startswith(("    !", "     "))]

    text = {e.split()[0]: " ".join(ln.strip() for ln in described(lines)) for e, lines in entries.items()}
    # not cut at the first full stop: the whole description, the shared sources legend left out
    assert text["folio_2017_tro"].startswith("Folio and Ferreira, IEEE Trans. Robotics 2017 (hal-01446482)")
    assert text["folio_2017_tro"].endswith("(the coil cannot hold the bead's weight).")
    assert "s_hat' = gamma dF/ds . e2, projected" in text["sound_small_artery_adaptive"]
    assert "PRINTED" in text["paper_small_artery"] and not any("Sources:" in t for t in text.values())
    assert text["clinical_3t_small_artery"].endswith("docs/graph.md, docs/reproduction.md.")
    # every shipped scenario loads and passes the run's resource check: none is marked
    assert not any("cannot be flown" in t for t in text.values())


def test_a_scenario_the_loader_refuses_is_marked_with_its_one_line_reason(tmp_path, capsys, monkeypatch):
    shipped = shipped_scenarios()
    good = tmp_path / "sound_small_artery.yaml"
    shutil.copy(shipped["sound_small_artery"], good)
    latency = tmp_path / "latency.yaml"  # refused by the scenario loader
    latency.write_text("# A multiplexed sequence with an imager latency too.  Second sentence.\n"
                       f"base: {shipped['clinical_3t_small_artery']}\nname: latency\n"
                       "imager:\n  latency_s: 0.01\n")
    endless = tmp_path / "endless.yaml"  # loads, but refused by the resource check simulate runs first
    endless.write_text(f"# A run of a billion seconds.\nbase: {shipped['sound_small_artery']}\nname: endless\n"
                       "sim:\n  duration_s: 1.0e9\n")
    monkeypatch.setattr(scenario_mod, "shipped_scenarios",
                        lambda: {"endless": endless, "latency": latency, "sound_small_artery": good})
    monkeypatch.setenv("COLUMNS", "200")
    assert cli.main(["scenarios"]) == 0
    entries = _entries(capsys.readouterr().out)
    assert list(entries) == ["endless", "latency", "sound_small_artery (default)"]
    assert entries["latency"][0].startswith("    ! cannot be flown as shipped: imager.latency_s must be 0 with "
                                            "sequence.mode 'multiplexed'")
    assert entries["latency"][1:] == ["    A multiplexed sequence with an imager latency too. Second sentence."]
    assert entries["endless"][0].startswith("    ! cannot be flown as shipped: sim.duration_s=1000000000.0 s")
    assert not any("cannot be flown" in ln for ln in entries["sound_small_artery (default)"])


def test_describe_is_the_whole_comment_block_without_the_legend(tmp_path):
    from vesselbot_ros.sim.scenarios_cli import describe

    path = tmp_path / "s.yaml"
    path.write_text("# Steered in turn (Tamaz et al., the paper's ref. [23]), e.g. at 3 T.  Second\n"
                    "# sentence.  Sources: \"T3\" = Table III, \"ours\" = not in the paper.\nname: s\n")
    assert describe(path) == "Steered in turn (Tamaz et al., the paper's ref. [23]), e.g. at 3 T. Second sentence."
    for name, p in shipped_scenarios().items():
        text = describe(p)
        assert text.endswith((".", ")")) and "Sources:" not in text, (name, text)


def test_a_coil_that_cannot_hold_the_bead_against_its_weight_is_marked_and_one_that_can_is_not(capsys):
    from vesselbot_ros.analysis.plan import available_accel
    from vesselbot_ros.scanner.hardware import hover_shortfall, weight_accel
    from vesselbot_ros.sim.scenario import load_scenario, resolve_config_path
    from vesselbot_ros.sim.scenarios_cli import hover_note

    clinical = load_scenario("clinical_3t_small_artery")
    a_avail, a_weight = hover_shortfall(clinical.physics, clinical.coil.saturation_T_per_m, clinical.sequence)
    assert a_avail == available_accel(clinical)[0] < a_weight == weight_accel(clinical.physics)
    assert 8.0 < a_weight < 8.5  # Table III's bead: g (1 - rho_f / rho) with its iron fraction
    note = hover_note(resolve_config_path("clinical_3t_small_artery"))
    assert note is not None and f"at most {a_avail:.2f} m/s^2" in note and f"pulls {a_weight:.2f} m/s^2" in note
    sound = load_scenario("sound_small_artery")
    assert hover_shortfall(sound.physics, sound.coil.saturation_T_per_m, sound.sequence) is None
    assert hover_note(resolve_config_path("sound_small_artery")) is None
    assert cli.main(["scenarios"]) == 0
    out = capsys.readouterr().out
    block = out.split("clinical_3t_small_artery\n", 1)[1].split("\n", 1)[0]
    assert block.strip().startswith("! cannot hover on its coil")
    assert "sound_small_artery (default)\n    !" not in out
