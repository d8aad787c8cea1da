"""`vesselbot bag info` exits non-zero on a bag whose metadata.yaml and MCAP disagree, naming the topic."""

from __future__ import annotations

import shutil

import pytest
import yaml

from vesselbot_ros.cli import main


def test_consistent_bag_exits_0(synthetic_bag, capsys):
    assert main(["bag", "info", str(synthetic_bag[0]), "--no-config"]) == 0
    assert "Metadata:   consistent with the MCAP" in capsys.readouterr().out


def test_metadata_count_off_by_one_exits_1_naming_the_topic(synthetic_bag, tmp_path, capsys):
    bag = tmp_path / "run1"
    shutil.copytree(synthetic_bag[0], bag)
    meta_path = bag / "metadata.yaml"
    meta = yaml.safe_load(meta_path.read_text())
    info = meta["rosbag2_bagfile_information"]
    for entry in info["topics_with_message_count"]:
        if entry["topic_metadata"]["name"] == "/vesselbot/gradient_command":
            entry["message_count"] += 1  # metadata claims the 1001st command the MCAP does not hold
    info["message_count"] += 1
    meta_path.write_text(yaml.safe_dump(meta, sort_keys=False))
    assert main(["bag", "info", str(bag), "--no-config"]) == 1
    out = capsys.readouterr().out
    assert "DOES NOT MATCH" in out
    assert "/vesselbot/gradient_command: metadata.yaml says 1001 messages, the MCAP holds 1000" in out


def test_a_bag_says_the_span_of_sim_time_it_covers_against_the_planned_run(synthetic_bag, tmp_path, capsys):
    from conftest import RUN_METADATA, write_synthetic_bag

    assert main(["bag", "info", str(synthetic_bag[0]), "--no-config"]) == 0  # its config does not say the duration
    assert ("Sim time:   covers 1.00 s of sim time (0.000 to 0.999 s); the run's planned duration is not recorded"
            in capsys.readouterr().out.splitlines())
    meta = dict(RUN_METADATA, config={"sim": {"duration_s": 1.0, "control_rate_Hz": 1000.0}})
    write_synthetic_bag(tmp_path / "full", 1000, run_metadata=meta)
    assert main(["bag", "info", str(tmp_path / "full"), "--no-config"]) == 0
    assert "Sim time:   covers 1.00 s of the 1.00 s run (complete)" in capsys.readouterr().out.splitlines()


def _bag_of_a_real_run(path):
    """A bag whose run metadata is what ``vesselbot run`` records (the scenario's whole config), 200 ticks of 2 s."""
    from conftest import write_synthetic_bag

    from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios

    sc = load_scenario(shipped_scenarios()["clinical_3t_small_artery"], seed=3)
    meta = {"scenario": sc.name, "seed": sc.seed, "mode": "lockstep", "config": sc.to_mapping(),
            "versions": {"vesselbot_ros": "test"}, "namespace": "/vesselbot", "compression": "none", "dims": 2,
            "command": ["vesselbot", "run", "--config", "clinical_3t_small_artery", "--seed", "3"]}
    write_synthetic_bag(path, 200, run_metadata=meta)
    return path


def test_info_is_short_by_default_and_the_whole_config_is_behind_full(tmp_path, capsys):
    """Issue 39: ``bag info`` printed the whole config (about 250 lines); now the run in a screenful, --full for all."""
    bag = _bag_of_a_real_run(tmp_path / "run1")
    assert main(["bag", "info", str(bag)]) == 0
    short = capsys.readouterr().out.splitlines()
    assert len(short) <= 30, short
    assert "Scenario:   clinical_3t_small_artery   seed: 3   mode: lockstep" in short
    assert "Loop:       2 s at 1000 Hz; controller backstepping, observer ekf, reference bspline" in short
    assert ("Hardware:   coil 45 mT/m, sequence multiplexed, dB/dt iec_normal_mode, imager mri at 1000 frames/s, "
            "noise 100 um") in short
    assert "Vessel:     straight, D = 3 mm, bead r = 250 um" in short
    assert "Command:    vesselbot run --config clinical_3t_small_artery --seed 3" in short
    assert "Duration:   0.199 s (log time)" in short
    assert "Sim time:   covers 0.20 s of the 2.00 s run (partial: its last tick is at sim t = 0.199 s)" in short
    assert any(ln.split()[:3] == ["/vesselbot/truth", "vesselbot_msgs/msg/PlantState", "200"] for ln in short)
    assert "Metadata:   consistent with the MCAP" in short
    assert short[-1] == ("More:       --full adds the files, start and end times, chunks, versions and the run's "
                         "whole config")
    assert not any(ln.startswith(("Config:", "Files:", "Start:", "Versions:")) for ln in short)

    assert main(["bag", "info", "--full", str(bag)]) == 0
    full = capsys.readouterr().out.splitlines()
    assert len(full) > 100 and "Config:" in full and '      "saturation_T_per_m": 0.045,' in full
    assert all(any(ln.startswith(k) for ln in full) for k in ("Files:", "Start:", "End:", "Chunks:", "Versions:"))
    assert set(short[:-1]) <= set(full) and not full[-1].startswith("More:")  # the short form, and more
    assert main(["bag", "info", "--full", "--no-config", str(bag)]) == 0
    assert "Config:" not in capsys.readouterr().out.splitlines()


def test_info_help_documents_full(capsys):
    with pytest.raises(SystemExit):
        main(["bag", "info", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--full" in text and "the run's whole config" in text


def test_a_bag_without_a_config_prints_no_settings(synthetic_bag, capsys):
    from vesselbot_ros.bag.info import run_settings

    assert run_settings(None) == [] and run_settings({"imager": {"outliers": []}}) == []
    assert run_settings({"sim": {"duration_s": 1.0}}) == ["Loop:       1 s"]
    assert main(["bag", "info", str(synthetic_bag[0])]) == 0
    out = capsys.readouterr().out.splitlines()
    assert not any(ln.startswith(("Loop:", "Hardware:", "Vessel:")) for ln in out)
