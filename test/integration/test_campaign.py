"""`vesselbot campaign` end to end: local default vs an explicit scheduler, kill and resume, failing runs.

Each campaign is a handful of 0.2-0.3 s runs of the sound scenario so the
whole file stays well under a minute of run time; every wait is bounded.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import yaml

from _runs import children

REPO = Path(__file__).resolve().parents[2]
NONDETERMINISTIC = {"run_time_s", "worker"}


def _spec(tmp: Path, name: str, **doc) -> Path:
    doc = {"name": name, "base": str(REPO / "config" / "sound_small_artery.yaml"),
           "overrides": {"sim.duration_s": 0.2, "sim.metrics_after_s": 0.1}, **doc}
    p = tmp / f"{name}.yaml"
    p.write_text(yaml.safe_dump(doc, sort_keys=False))
    return p


def _campaign(*args: str, timeout: float = 240) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "vesselbot_ros.cli", "campaign", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=timeout)


def _rows(out: Path) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in NONDETERMINISTIC}
            for r in pq.read_table(out / "results.parquet").to_pylist()]


def _wait_gone(pids: list[int], timeout: float) -> list[int]:
    deadline = time.monotonic() + timeout
    alive = list(pids)
    while alive and time.monotonic() < deadline:
        alive = [p for p in alive if Path(f"/proc/{p}").exists()
                 and Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"]
        time.sleep(0.1)
    return alive


def test_local_default_and_explicit_scheduler_give_identical_results(tmp_path) -> None:
    spec = _spec(tmp_path, "same", seeds=[0, 1], grid={"controller.sample_hold": ["none", "midpoint"]},
                 samples={"count": 2, "rng_seed": 5, "params": {
                     "physics.blood.relative_permittivity": {"distribution": "uniform", "low": 45.0, "high": 77.0}}},
                 keep_timeseries={"runs": [0]})
    local = _campaign(str(spec), "--out", str(tmp_path / "local"))
    assert local.returncode == 0, local.stderr
    assert "on a local cluster of" in local.stderr and "8/8 runs, 0 failed" in local.stderr
    assert "| controller.sample_hold=none | tracking error max (um) | 4 / 0 |" in local.stdout

    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster:
        remote = _campaign(str(spec), "--out", str(tmp_path / "remote"), "--scheduler", cluster.scheduler_address)
    assert remote.returncode == 0, remote.stderr
    assert f"on {cluster.scheduler_address}" in remote.stderr

    a, b = _rows(tmp_path / "local"), _rows(tmp_path / "remote")
    assert len(a) == 8 and all(r["status"] == "ok" for r in a)
    assert a == b  # every metric, every sampled value, every run id: bit for bit
    assert len({r["physics.blood.relative_permittivity"] for r in a}) == 2
    for out in ("local", "remote"):
        d = tmp_path / out
        assert (d / "summary.md").read_text().startswith("campaign same: 8 of 8 runs finished, 8 ok, 0 failed")
        figs = {p.name for p in (d / "figures").glob("*.png")}
        assert {"tracking_error_distribution.png", "tracking_error_vs_controller.sample_hold.png",
                "tracking_error_vs_physics.blood.relative_permittivity.png"} <= figs
        ts = pq.read_table(d / a[0]["timeseries"])
        assert ts.num_rows == 200 and "p_true_x" in ts.column_names
    assert pq.read_table(tmp_path / "local" / a[0]["timeseries"]).equals(pq.read_table(tmp_path / "remote" / a[0]["timeseries"]))

    # the report redraws from the folder alone
    (tmp_path / "local" / "summary.md").unlink()
    for p in (tmp_path / "local" / "figures").glob("*.png"):
        p.unlink()
    rep = _campaign("report", str(tmp_path / "local"))
    assert rep.returncode == 0, rep.stderr
    assert (tmp_path / "local" / "summary.md").read_text() == rep.stdout.split("-> ")[0]
    assert len(list((tmp_path / "local" / "figures").glob("*.png"))) == len(figs)


def test_killed_campaign_resumes_without_rerunning_finished_runs(tmp_path) -> None:
    spec = _spec(tmp_path, "resume", seeds={"start": 0, "count": 16}, chunk_size=1,
                 overrides={"sim.duration_s": 0.3, "sim.metrics_after_s": 0.1})
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "vesselbot_ros.cli", "campaign", str(spec), "--out", str(out),
                             "--workers", "1"], cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while len(list((out / "parts").glob("part-*.parquet"))) < 3:
            assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
            assert time.monotonic() < deadline, "no run finished within 120 s"
            time.sleep(0.05)
        workers = list(children(proc.pid))
        assert workers, "the local cluster's worker process is a child of the campaign"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    # no worker outlives the killed campaign
    assert _wait_gone(workers, 20) == []
    parts_before = {p.name: p.stat().st_mtime_ns for p in (out / "parts").glob("part-*.parquet")}
    done_before = len(parts_before)
    assert 3 <= done_before < 16
    assert not (out / "results.parquet").exists()

    again = _campaign(str(spec), "--out", str(out))
    assert again.returncode == 0, again.stderr
    assert f"16 runs, {done_before} already in" in again.stderr
    assert f"running {16 - done_before} on" in again.stderr
    assert f"ran {16 - done_before} runs (0 failed)" in again.stdout
    after = {p.name: p.stat().st_mtime_ns for p in (out / "parts").glob("part-*.parquet")}
    assert {k: after[k] for k in parts_before} == parts_before  # finished runs untouched
    rows = _rows(out)
    assert [r["seed"] for r in rows] == list(range(16)) and all(r["status"] == "ok" for r in rows)

    third = _campaign(str(spec), "--out", str(out))
    assert third.returncode == 0 and "nothing to run; 16 run(s) were already done" in third.stdout
    assert _rows(out) == rows


def test_failing_runs_are_recorded_and_do_not_stop_the_campaign(tmp_path) -> None:
    # a normal draw of the robot radius (250 +/- 300 um) goes negative for some runs
    spec = _spec(tmp_path, "fails", seeds=[0], samples={"count": 6, "rng_seed": 3, "params": {
        "physics.robot.radius_m": {"distribution": "normal", "mean": 250.0e-6, "std": 300.0e-6}}})
    res = _campaign(str(spec), "--out", str(tmp_path / "out"), "--workers", "1")
    assert res.returncode == 0, res.stderr
    rows = _rows(tmp_path / "out")
    assert len(rows) == 6
    bad = [r for r in rows if r["status"] == "error"]
    good = [r for r in rows if r["status"] == "ok"]
    assert bad and good
    for r in bad:
        assert r["physics.robot.radius_m"] <= 0
        assert r["error"].startswith("ConfigError: physics.robot.radius_m must be > 0, got -")
        assert r["tracking_error_max_m"] is None
    assert all(r["tracking_error_max_m"] > 0 for r in good)
    assert f"{len(bad)} run(s) failed" in res.stderr
    assert f"| all | tracking error max (um) | {len(good)} / {len(bad)} |" in res.stdout
    # failed runs count as finished; --retry-failed runs them again (and they fail again: deterministic)
    again = _campaign(str(spec), "--out", str(tmp_path / "out"), "--workers", "1", "--retry-failed")
    assert f"running {len(bad)} on" in again.stderr
    assert _rows(tmp_path / "out") == rows


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity"), reason="Linux only")
def test_unreachable_scheduler_is_one_line_and_exit_2(tmp_path) -> None:
    spec = _spec(tmp_path, "nowhere", seeds=[0])
    res = _campaign(str(spec), "--out", str(tmp_path / "out"), "--scheduler", "tcp://127.0.0.1:9", timeout=120)
    assert res.returncode == 2
    lines = [ln for ln in res.stderr.splitlines() if "error:" in ln]
    assert len(lines) == 1 and "cannot connect to the Dask scheduler 'tcp://127.0.0.1:9'" in lines[0]


def test_a_3d_tree_campaign_gives_the_pure_loops_numbers(tmp_path) -> None:
    """The shipped 3-D trees' campaign, shortened: every row is run_closed_loop's run of its variant and seed,
    bit for bit, and a kept time series has the three axes."""
    from vesselbot_ros.sim.closed_loop import run_closed_loop
    from vesselbot_ros.sim.scenario import load_scenario

    doc = yaml.safe_load((REPO / "config" / "campaigns" / "trees_3d.yaml").read_text())
    doc["base"] = str(REPO / "config" / "paper_iiic_network_upper_3d.yaml")
    doc["seeds"] = [1]
    doc["overrides"] = {"sim.duration_s": 0.3, "sim.metrics_after_s": 0.1}
    for v in doc["variants"].values():
        v.pop("sim.duration_s", None)
    doc["keep_timeseries"] = {"runs": [0]}
    spec = tmp_path / "trees.yaml"
    spec.write_text(yaml.safe_dump(doc, sort_keys=False))
    out = _campaign(str(spec), "--out", str(tmp_path / "out"))
    assert out.returncode == 0, out.stderr
    rows = _rows(tmp_path / "out")
    assert len(rows) == 3 and all(r["status"] == "ok" for r in rows)
    for r in rows:
        sets = {**doc["overrides"], **doc["variants"][r["variant"]]}
        sc = load_scenario(doc["base"], sets=[f"{k}={json.dumps(v)}" for k, v in sets.items()])
        m = run_closed_loop(sc, r["seed"]).metrics
        for k in ("tracking_error_max_m", "estimation_error_max_m", "plant_steps", "outside_lumen_time_s"):
            assert r[k] == m[k], (r["variant"], r["seed"], k)
    ts = pq.read_table(tmp_path / "out" / rows[0]["timeseries"])
    assert {"p_true_x", "p_true_y", "p_true_z"} <= set(ts.column_names) and ts.num_rows == 300


PLUGINS = REPO / "test" / "plugins"


def _with_controller(tmp: Path, controller: dict) -> Path:
    """The sound scenario with its controller section replaced (a campaign varies values, not sections)."""
    doc = yaml.safe_load((REPO / "config" / "sound_small_artery.yaml").read_text())
    doc["controller"] = controller
    p = tmp / "base.yaml"
    p.write_text(yaml.safe_dump(doc, sort_keys=False))
    return p


def test_a_campaign_whose_controller_sends_nan_says_so_and_exits_1(tmp_path, monkeypatch) -> None:
    """Issue 38: every run on NaN commands is 'rejected_commands', never 'ok'; one warning line; exit 1."""
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(PLUGINS), os.environ.get("PYTHONPATH")])))
    spec = _spec(tmp_path, "nan", seeds=[0, 1], base=str(_with_controller(
        tmp_path, {"kind": "vesselbot_hostile_plugin:NaNFrom", "start_s": 0.1})))
    res = _campaign(str(spec), "--out", str(tmp_path / "out"), "--workers", "1")
    assert res.returncode == 1, res.stderr
    rows = _rows(tmp_path / "out")
    assert len(rows) == 2 and {r["status"] for r in rows} == {"rejected_commands"}
    for r in rows:  # the ticks from 0.1 s of a 0.2 s run at 1 kHz
        assert r["error"].startswith("100 of 200 controller commands rejected (non-finite) "
                                     "from t = 0.100 s; the coil ramped to zero"), r["error"]
    warnings = [ln for ln in res.stderr.splitlines() if "cannot be trusted" in ln]
    assert len(warnings) == 1 and "2 of 2 run(s)" in warnings[0] and "2 on rejected controller commands" in warnings[0]
    assert "Traceback" not in res.stderr


def test_a_campaign_whose_controller_cannot_be_built_records_one_line_per_run(tmp_path, monkeypatch) -> None:
    """Issue 38: a plug-in whose constructor raises is one line in each run's 'error', never a traceback or 'ok'."""
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(PLUGINS), os.environ.get("PYTHONPATH")])))
    spec = _spec(tmp_path, "broken", seeds=[0], base=str(_with_controller(
        tmp_path, {"kind": "vesselbot_hostile_plugin:BrokenConstructor"})))
    res = _campaign(str(spec), "--out", str(tmp_path / "out"), "--workers", "1")
    assert res.returncode == 1, res.stderr  # every run failed
    assert "Traceback" not in res.stderr and "Warning" not in res.stderr, res.stderr
    assert "1 run(s) failed" in res.stderr
    rows = _rows(tmp_path / "out")
    assert len(rows) == 1 and rows[0]["status"] == "error"
    assert "'vesselbot_hostile_plugin:BrokenConstructor' could not be built: its constructor raised" in rows[0]["error"]
    assert "\n" not in rows[0]["error"]  # one line
