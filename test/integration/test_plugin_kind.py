"""A user's controller kind, kept outside the package, runs by name in simulate, campaign and run: the same numbers.

The plug-in (``test/plugins/vesselbot_test_plugin.py``) is named in a scenario
as ``module:Class`` and reaches every process through ``PYTHONPATH``, as a
user's would: the ``vesselbot simulate`` process, the Dask workers of a
separate scheduler, and the controller node's process of ``vesselbot run``.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import yaml

from vesselbot_ros.config import load_yaml
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario

pytest.importorskip("rclpy")

REPO = Path(__file__).resolve().parents[2]
PLUGINS = REPO / "test" / "plugins"
KIND = "vesselbot_test_plugin:IntegralController"
SEED = 3


@pytest.fixture
def plugin_scenario(tmp_path, monkeypatch) -> Path:
    """The sound scenario with the plug-in as its controller, 0.3 s; the plug-in on every child's PYTHONPATH."""
    monkeypatch.syspath_prepend(str(PLUGINS))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(PLUGINS), os.environ.get("PYTHONPATH")])))
    doc = load_yaml(REPO / "config" / "sound_small_artery.yaml")
    doc["name"] = "plugin_integral"
    doc["controller"] = {"kind": KIND, "ki_per_s3": 700.0}
    doc.setdefault("sim", {}).update(duration_s=0.3, metrics_after_s=0.1)
    path = tmp_path / "plugin_integral.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def _cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "vesselbot_ros.cli", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout)


def _same(key: str, got, want) -> None:
    if isinstance(want, float) and math.isnan(want):
        assert isinstance(got, float) and math.isnan(got), key
    else:
        assert got == want, f"{key}: {got!r} != {want!r}"


def test_plugin_controller_gives_the_same_numbers_in_simulate_campaign_and_run(plugin_scenario, tmp_path) -> None:
    scenario = load_scenario(plugin_scenario, seed=SEED)
    pure = run_closed_loop(scenario)
    assert pure.path == "per_tick" and type(scenario.controller).__name__ == "IntegralParams"
    numbers = {k: v for k, v in pure.metrics.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}
    assert "tracking_error_max_m" in numbers and numbers["tracking_error_max_m"] < 1e-3

    # 1. vesselbot simulate
    sim = _cli("simulate", "--config", str(plugin_scenario), "--seed", str(SEED), "--out", str(tmp_path / "sim"))
    assert sim.returncode == 0, sim.stderr
    got = json.loads((tmp_path / "sim" / "metrics.json").read_text())
    for k, v in numbers.items():
        _same(f"simulate {k}", got[k], v)

    # 2. vesselbot campaign on a separate Dask scheduler (its worker processes import the plug-in by name)
    spec = tmp_path / "campaign.yaml"
    spec.write_text(yaml.safe_dump({"name": "plugin", "base": str(plugin_scenario), "seeds": [SEED]}, sort_keys=False))
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster:
        camp = _cli("campaign", str(spec), "--out", str(tmp_path / "camp"), "--scheduler", cluster.scheduler_address)
    assert camp.returncode == 0, camp.stdout + camp.stderr
    rows = pq.read_table(tmp_path / "camp" / "results.parquet").to_pylist()
    assert len(rows) == 1 and rows[0]["status"] == "ok", rows
    compared = [k for k in numbers if k in rows[0]]
    assert "tracking_error_max_m" in compared and len(compared) >= 10
    for k in compared:
        _same(f"campaign {k}", rows[0][k], numbers[k])

    # 3. vesselbot run: the graph's controller node builds and calls the plug-in (lockstep, one process per node)
    out = tmp_path / "run.json"
    run = _cli("run", "--config", str(plugin_scenario), "--seed", str(SEED), "--no-record", "--quiet",
               "--metrics-json", str(out))
    assert run.returncode == 0, run.stdout + run.stderr
    ros = json.loads(out.read_text())
    for k, v in pure.metrics.items():
        assert k in ros["metrics"], k
        _same(f"run {k}", ros["metrics"][k], v)
    for key in ("p_true", "x_hat", "g_applied"):
        assert ros["final"][key] == [float(x) for x in pure.timeseries[key][-1]], key


def test_the_predictive_controller_in_a_lockstep_graph_equals_the_runner(tmp_path) -> None:
    """The built-in predictive kind (planned windows, coil replica) runs in the controller node bit for bit,
    switched on by ``vesselbot run --set`` (the one override path, as ``vesselbot simulate`` has it)."""
    sets = ["controller.kind=predictive", "controller.pieces=3", "sim.metrics_after_s=0.1"]
    config = REPO / "config" / "propulsion_insert_small_artery.yaml"
    scenario = load_scenario(config, sets=sets, duration=0.3, seed=2)
    assert scenario.controller.pieces == 3
    pure = run_closed_loop(scenario)
    assert pure.path == "compiled" and any(pure.timeseries["g_cmd"][:, 0] != 0.0)
    out = tmp_path / "run.json"
    run = _cli("run", "--config", str(config), "--duration", "0.3", "--seed", "2", *(a for s in sets for a in ("--set", s)),
               "--no-record", "--quiet", "--metrics-json", str(out))
    assert run.returncode == 0, run.stdout + run.stderr
    ros = json.loads(out.read_text())
    for k, v in pure.metrics.items():
        _same(f"run {k}", ros["metrics"][k], v)
    for key in ("p_true", "x_hat", "g_applied"):
        assert ros["final"][key] == [float(x) for x in pure.timeseries[key][-1]], key
