"""`vesselbot bag info` exits non-zero on a bag whose metadata.yaml and MCAP disagree, naming the topic."""

from __future__ import annotations

import shutil

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
