"""A policy trained in the environments runs as the ``policy`` controller kind in ``vesselbot run``: the same numbers.

A small deterministic policy (a PD law on the observation, in the layout of
:func:`vesselbot_ros.control.policy.observation_fields`) flies 0.3 s of the Straight tier's scenario three ways, seed 3:
an episode of ``vesselbot/Straight-v0`` (``privileged=True`` to read the true state back), the ROS-free runner with
``controller.kind=policy`` (``run_closed_loop``), and the lockstep ROS graph (``vesselbot run``, one process per node:
the controller node imports the policy through ``PYTHONPATH`` and calls it).  The recorded run's metrics equal the
runner's bit for bit, and its final true position, estimate and applied gradient equal the episode's.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from vesselbot_ros.control.policy import load_policy
from vesselbot_ros.envs.env import VesselbotEnv
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario

REPO = Path(__file__).resolve().parents[2]
CONFIG = "config/sound_small_artery.yaml"
SEED = 3
SETS = ["sim.duration_s=0.3", "sim.metrics_after_s=0.1"]

POLICY = '''
def act(obs):
    """PD on the estimate's error, plus a little of the gradient the coil applied (observation_fields' layout)."""
    d = (len(obs) - 1) // 6
    x, z, p, v = obs[0:d], obs[d:2 * d], obs[2 * d + 1:3 * d + 1], obs[3 * d + 1:4 * d + 1]
    return 40.0 * (p - x) + 2.0 * (v - z) + 0.1 * obs[5 * d + 1:6 * d + 1]
'''


@pytest.fixture
def policy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    """``vb_graph_policy:act``, importable here and in every child process (``PYTHONPATH``)."""
    (tmp_path / "vb_graph_policy.py").write_text(POLICY)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(tmp_path), os.environ.get("PYTHONPATH")])))
    sys.modules.pop("vb_graph_policy", None)
    return "vb_graph_policy:act"


def _same(key: str, got, want) -> None:  # type: ignore[no-untyped-def]
    if isinstance(want, float) and math.isnan(want):
        assert isinstance(got, float) and math.isnan(got), key
    else:
        assert got == want, f"{key}: {got!r} != {want!r}"


def test_a_policy_in_the_lockstep_graph_has_the_numbers_of_the_env_and_the_runner(policy: str, tmp_path: Path) -> None:
    sets = [*SETS, "controller.kind=policy", f"controller.policy={policy}"]
    # 1. the environment's episode (the agent's actions: the policy of the observation without the truth)
    env = VesselbotEnv(load_scenario(REPO / CONFIG, sets=SETS), privileged=True)
    f = dict(env.fields)
    act = load_policy(policy)
    obs, _ = env.reset(seed=SEED)
    rows = []
    for _k in range(env.loop.n_steps):
        rows.append(obs)
        obs, *_ = env.step(act(obs[:f["p_true_m"].start]))
    episode = np.array(rows)
    # 2. the ROS-free runner with the policy kind
    pure = run_closed_loop(load_scenario(REPO / CONFIG, sets=sets), SEED)
    assert pure.path == "per_tick"
    np.testing.assert_array_equal(pure.timeseries["p_true"], episode[:, f["p_true_m"]])
    np.testing.assert_array_equal(pure.timeseries["x_hat"], episode[:, f["x_hat_m"]])
    # 3. the ROS graph, lockstep, recorded
    out, bag = tmp_path / "run.json", tmp_path / "bag"
    proc = subprocess.run(
        [sys.executable, "-m", "vesselbot_ros.cli", "run", "--config", CONFIG, "--seed", str(SEED), "--quiet",
         "--record-dir", str(bag), "--metrics-json", str(out), "--wait-timeout", "120", "--run-timeout", "240",
         *(a for s in sets for a in ("--set", s))],
        cwd=REPO, capture_output=True, text=True, timeout=420)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    ros = json.loads(out.read_text())
    assert pure.metrics["status"] == "ok" and math.isfinite(pure.metrics["tracking_error_max_m"])
    for k, v in pure.metrics.items():
        assert k in ros["metrics"], k
        _same(f"run {k}", ros["metrics"][k], v)
    for key, field in (("p_true", "p_true_m"), ("x_hat", "x_hat_m")):
        assert ros["final"][key] == [float(x) for x in episode[-1, f[field]]], key
    # the gradient applied over the last tick: the runner's (the episode's next observation carries it)
    assert ros["final"]["g_applied"] == [float(x) for x in pure.timeseries["g_applied"][-1]]
    np.testing.assert_array_equal(pure.timeseries["g_applied"][-1], obs[f["g_applied_T_per_m"]])
