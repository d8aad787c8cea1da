"""A lockstep run over real ROS topics reproduces the pure runner bit for bit."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

pytest.importorskip("rclpy")

from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario

CONFIG = "config/paper_small_artery.yaml"


def _vesselbot_run(repo, tmp_path, *args, timeout=240, config=CONFIG):
    out = tmp_path / "metrics.json"
    cmd = [sys.executable, "-m", "vesselbot_ros.cli", "run", "--config", config, "--quiet", "--metrics-json", str(out), *args]
    proc = subprocess.run(cmd, cwd=repo, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return json.loads(out.read_text()), proc.stdout


def _assert_identical(pure, ros):
    """Every metric of the pure runner, and the final per-tick values, are equal (no tolerance)."""
    for key, v in pure.metrics.items():
        assert key in ros["metrics"], key
        w = ros["metrics"][key]
        if isinstance(v, float) and math.isnan(v):
            assert math.isnan(w), key
        else:
            assert w == v, f"{key}: ROS {w!r} != pure {v!r}"
    for key in ("p_true", "x_hat", "g_applied"):
        assert ros["final"][key] == [float(x) for x in pure.timeseries[key][-1]], key


@pytest.mark.parametrize("extra", [[], ["--single-process"]], ids=["processes", "single_process"])
def test_short_lockstep_run_equals_pure_runner(repo, tmp_path, extra):
    scenario = load_scenario(repo / CONFIG, duration=0.3, seed=3)
    pure = run_closed_loop(scenario)
    ros, stdout = _vesselbot_run(repo, tmp_path, "--duration", "0.3", "--seed", "3", "--no-record", *extra)
    assert ros["metrics"]["n_ticks"] == 300
    _assert_identical(pure, ros)
    assert "run finished: 300 ticks" in stdout


def test_ekf_scenario_lockstep_equals_pure_runner(repo, tmp_path):
    """The extended Kalman filter and the law compensating with its flow scale (which travels in the estimate)."""
    config = "config/sound_small_artery_ekf.yaml"
    scenario = load_scenario(repo / config, duration=0.3, seed=2)
    pure = run_closed_loop(scenario)
    assert pure.path == "compiled" and pure.timeseries["flow_scale_hat"][-1] != 1.0
    ros, _stdout = _vesselbot_run(repo, tmp_path, "--duration", "0.3", "--seed", "2", "--no-record", "--single-process",
                                 config=config)
    assert ros["metrics"]["n_ticks"] == 300
    _assert_identical(pure, ros)


def test_paper_scenario_recorded_equals_pure_runner(repo, tmp_path):
    """The full 2 s paper run (outliers at 0.5 s, wall contacts), recorded, once."""
    scenario = load_scenario(repo / CONFIG, seed=1)
    pure = run_closed_loop(scenario)
    bag = tmp_path / "bag"
    ros, stdout = _vesselbot_run(repo, tmp_path, "--seed", "1", "--record-dir", str(bag), "--single-process", timeout=400)
    _assert_identical(pure, ros)
    assert ros["metrics"]["outlier_frames"] == 20  # the scheduled burst reached the graph
    assert (bag / "metadata.yaml").is_file() and list(bag.glob("*.mcap"))
    meta = json.loads((bag / "run_metadata.json").read_text())
    assert meta["seed"] == 1 and meta["mode"] == "lockstep" and meta["config"]["name"] == "paper_small_artery"
    assert "run finished: 2000 ticks" in stdout
    from vesselbot_ros.bag.reader import open_bag

    info = open_bag(bag)
    assert info.consistent, info.problems
    assert info.run_metadata["seed"] == 1
    # no loss in lockstep: one message per tick on every per-tick topic
    for t in ("/clock", "/vesselbot/truth", "/vesselbot/measurement", "/vesselbot/estimate", "/vesselbot/reference",
              "/vesselbot/gradient_command", "/vesselbot/coil/applied", "/vesselbot/coil/state"):
        assert info.topic(t).count == 2000, (t, info.topic(t).count)
    # the paper's continuous sequence: one phase message for the whole run, CONTINUOUS on [0, inf)
    from vesselbot_ros.bag.reader import iter_messages
    from vesselbot_ros.graph_spec import topic

    phase = [m.decode() for m in iter_messages(info, topics=[topic("sequence_phase").name])]
    assert len(phase) == 1
    assert (phase[0].phase, phase[0].window_start, phase[0].window_end) == (phase[0].CONTINUOUS, 0.0, math.inf)
