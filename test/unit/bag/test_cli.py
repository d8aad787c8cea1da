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
    assert main(["bag", "info", "--full", str(synthetic_bag[0])]) == 0  # --full: the run's config too
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


def test_report_cli_writes_beside_the_bag_by_default_and_leaves_the_bag_folder_as_it_was(synthetic_bag, tmp_path,
                                                                                          capsys):
    dst = tmp_path / "r"
    shutil.copytree(synthetic_bag[0], dst)
    before = sorted(p.name for p in dst.iterdir())
    assert main(["report", str(dst)]) == 0
    out = capsys.readouterr().out
    assert (tmp_path / "r.report" / "metrics.json").is_file()
    assert sorted(p.name for p in dst.iterdir()) == before  # nothing added to the bag
    assert f"report written to {tmp_path / 'r.report'}: " in out  # says where
    assert "tracking error after 0.6 s" in out


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
    earlier = tmp_path / "run1.reestimate_observer"  # beside the bag
    earlier.mkdir()
    (earlier / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    argv = ["replay", str(bag), "--into", "observer"] + (["--out", str(earlier)] if use_out else [])
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "already holds a bag (metadata.yaml) from an earlier `replay --into observer`" in err[0]
    assert "it is not overwritten: pass --out DIR" in err[0]
    assert f"--out {tmp_path / 'run1.reestimate_observer_2'}" in err[0]


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


def test_report_on_a_full_disk_leaves_the_earlier_report_and_no_empty_file(synthetic_bag, tmp_path):
    from vesselbot_ros.testing import cli_on_a_full_disk

    bag = tmp_path / "run1"
    shutil.copytree(synthetic_bag[0], bag)
    rep = tmp_path / "run1.report"
    rep.mkdir()
    old = {"fig9a_trajectory.png": "an earlier figure", "metrics.json": '{"old": 1}\n'}
    for name, text in old.items():
        (rep / name).write_text(text)
    # the disk fills once the bag is read, before the figures are written
    child = cli_on_a_full_disk(["report", str(bag)], fill_after="vesselbot_ros.bag.report:read_timeseries")
    err = child.stderr.strip().splitlines()
    assert child.returncode == 2, child.stderr
    assert len(err) == 1 and err[0].startswith("vesselbot report: error: cannot write ")
    assert f"{rep / 'fig9a_trajectory.png'} (File too large: the disk is full" in err[0]
    assert {p.name: p.read_text() for p in rep.iterdir()} == old  # no 0-byte figure, no temporary file


def test_replay_into_on_a_full_disk_is_one_line_naming_the_folder_and_leaves_nothing(synthetic_bag, tmp_path):
    from vesselbot_ros.testing import cli_on_a_full_disk

    bag = tmp_path / "run1"
    shutil.copytree(synthetic_bag[0], bag)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    child = cli_on_a_full_disk(["replay", str(bag), "--into", "observer"])
    err = child.stderr.strip().splitlines()
    assert child.returncode == 2, child.stderr
    assert err == [f"vesselbot replay: error: bag directory {tmp_path / 'run1.reestimate_observer'} is not writable: "
                   "File too large"]
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before  # no .write_probe_NNN, no empty folder


def test_a_repaired_partial_bag_says_how_much_of_the_run_it_covers(tmp_path, capsys):
    """A recorder killed at 0.83 s of a 2 s run: repair, info and report each say it covers 0.83 s of 2.00 s."""
    from conftest import RUN_METADATA, write_synthetic_bag

    meta = dict(RUN_METADATA, config={**RUN_METADATA["config"], "sim": {"duration_s": 2.0, "control_rate_Hz": 1000.0}})
    live = tmp_path / "live" / "run1"
    writer, _ = write_synthetic_bag(live, 830, flush_every=10, finish=False, run_metadata=meta)
    writer.flush()
    killed = tmp_path / "run1"
    killed.mkdir()
    (killed / "run1.mcap").write_bytes(writer.mcap_path.read_bytes())  # what a SIGKILL leaves: chunks, no summary
    (killed / "run_metadata.json").write_bytes((live / "run_metadata.json").read_bytes())
    writer.finish()
    line = "covers 0.83 s of the 2.00 s run (partial: its last tick is at sim t = 0.829 s)"
    assert main(["bag", "repair", str(killed)]) == 0
    assert f"  sim time: {line}" in capsys.readouterr().out.splitlines()
    assert main(["bag", "info", str(killed), "--no-config"]) == 0
    assert f"Sim time:   {line}" in capsys.readouterr().out.splitlines()
    assert main(["bag", "info", str(killed), "--json"]) == 0
    cov = json.loads(capsys.readouterr().out)["coverage"]
    assert cov["partial"] is True and cov["planned_duration_s"] == 2.0
    assert cov["sim_time_covered_s"] == pytest.approx(0.83, abs=1e-9)
    assert main(["report", str(killed), "--out", str(tmp_path / "rep")]) == 0
    assert f"  the bag {line}" in capsys.readouterr().out.splitlines()
    metrics = json.loads((tmp_path / "rep" / "metrics.json").read_text())
    assert metrics["partial"] is True and metrics["coverage"] == line
