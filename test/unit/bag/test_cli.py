"""`vesselbot bag info|repair`, `replay` and `report` through the real CLI entry point."""

from __future__ import annotations

import json
import shutil

import pytest

from vesselbot_ros.cli import main


@pytest.fixture
def truncated(synthetic_bag, tmp_path):
    dst = tmp_path / "run1"
    shutil.copytree(synthetic_bag[0], dst)
    mcap = dst / "run1.mcap"
    mcap.write_bytes(mcap.read_bytes()[:30000])
    return dst


def test_bag_info_prints_topics_counts_times_config_and_seed(synthetic_bag, capsys):
    assert main(["bag", "info", str(synthetic_bag[0])]) == 0
    out = capsys.readouterr().out
    assert "seed: 7" in out and "Scenario:   synthetic" in out
    assert "/vesselbot/truth" in out and "vesselbot_msgs/msg/PlantState" in out and " 1000" in out
    assert "Metadata:   consistent with the MCAP" in out
    assert '"magnitude_m": 0.001' in out  # the run's config
    assert main(["bag", "info", "--json", str(synthetic_bag[0])]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["seed"] == 7 and doc["consistent"] is True
    assert {t["name"]: t["count"] for t in doc["topics"]}["/clock"] == 1000


@pytest.mark.parametrize("argv", [["bag", "info"], ["replay"], ["report"]])
def test_truncated_bag_is_one_clear_error_line_for_every_command(truncated, capsys, argv):
    assert main([*argv, str(truncated)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "run1.mcap is truncated" in err[0] and "vesselbot bag repair" in err[0]


def test_bag_repair_cli_then_info_succeeds(tmp_path, capsys):
    from conftest import write_synthetic_bag

    truncated = tmp_path / "run1"
    bag, _ = write_synthetic_bag(truncated, 300, flush_every=100, finish=False)
    bag.flush()
    data = bag.mcap_path.read_bytes()
    bag.finish()
    (truncated / "metadata.yaml").unlink()
    bag.mcap_path.write_bytes(data)  # what a SIGKILL leaves: chunks, no summary, no metadata.yaml
    assert main(["bag", "repair", str(truncated)]) == 0
    out = capsys.readouterr().out
    assert "rebuilt metadata.yaml" in out and "run1.mcap.damaged" in out
    assert main(["bag", "info", str(truncated)]) == 0
    assert main(["bag", "repair", str(truncated)]) == 0
    assert "nothing to do" in capsys.readouterr().out


def test_report_cli_writes_into_the_bag_by_default(synthetic_bag, tmp_path, capsys):
    dst = tmp_path / "r"
    shutil.copytree(synthetic_bag[0], dst)
    assert main(["report", str(dst)]) == 0
    assert (dst / "report" / "metrics.json").is_file()
    assert "tracking error after 0.6 s" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["bag", "info"], ["bag", "repair", "--force"]])
def test_closed_stdout_pipe_ends_without_traceback(synthetic_bag, tmp_path, argv):
    # `vesselbot bag repair DIR | head -3`: the reader has gone when we write
    import subprocess
    import sys

    bag = tmp_path / "run1"
    shutil.copytree(synthetic_bag[0], bag)
    proc = subprocess.Popen([sys.executable, "-m", "vesselbot_ros.cli", *argv, str(bag)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # before the child has imported anything, let alone printed
    _, err = proc.communicate(timeout=120)
    assert b"Traceback" not in err and b"BrokenPipeError" not in err, err.decode()


@pytest.mark.parametrize("use_out", [False, True])
def test_replay_into_a_second_time_suggests_out(synthetic_bag, tmp_path, capsys, use_out):
    bag = tmp_path / "run1"
    shutil.copytree(synthetic_bag[0], bag)
    earlier = bag / "reestimate_observer"
    earlier.mkdir()
    (earlier / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    argv = ["replay", str(bag), "--into", "observer"] + (["--out", str(earlier)] if use_out else [])
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "already holds a bag (metadata.yaml) from an earlier `replay --into observer`" in err[0]
    assert "it is not overwritten: pass --out DIR" in err[0]
    assert f"--out {bag / 'reestimate_observer_2'}" in err[0]


@pytest.mark.parametrize("start", ["nan", "inf", "-1"])
def test_replay_bad_start_is_one_line(synthetic_bag, capsys, start):
    assert main(["replay", str(synthetic_bag[0]), f"--start={start}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--start must be a finite time >= 0 s" in err[0]


def test_report_of_a_run_shorter_than_the_window_says_so(synthetic_bag, tmp_path, capsys):
    assert main(["report", str(synthetic_bag[0]), "--out", str(tmp_path / "r"), "--after", "5"]) == 0
    out = capsys.readouterr().out
    assert "ends before the metrics window starts (sim.metrics_after_s = 5 s)" in out
    assert main(["report", str(synthetic_bag[0]), "--out", str(tmp_path / "r"), "--after", "nan"]) == 2
    assert "--after must be a finite time >= 0 s" in capsys.readouterr().err
