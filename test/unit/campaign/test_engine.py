"""Tests of the campaign engine: chunking, progress, resume bookkeeping, execution on a Dask client, the run budget."""

from __future__ import annotations

import io
import itertools
import re
from pathlib import Path

import pytest
import yaml

from vesselbot_ros.campaign.engine import (
    FIRST_CHUNK,
    MIN_TASK_S,
    TASK_S,
    ChunkSizer,
    Progress,
    chunk_sizes,
    execute,
    pending,
    prepare,
)
from vesselbot_ros.campaign.runner import resolve_mapping, run_chunk, run_id
from vesselbot_ros.campaign.spec import expand_points, load_campaign_spec
from vesselbot_ros.campaign.store import CampaignStore

ROOT = Path(__file__).resolve().parents[3]


def test_chunks_shrink_towards_the_end() -> None:
    assert chunk_sizes(0, 2) == []
    assert chunk_sizes(1, 2) == [1]
    # before any run time is known: small chunks (the first wave)
    assert chunk_sizes(40, 2) == [4, 4, 4, 4, 4, 4, 4, 3, 3, 2, 1, 1, 1, 1]
    # 6 ms runs: at most TASK_S (166 runs), shrinking by 1/(2w), never below MIN_TASK_S (8 runs)
    big = chunk_sizes(1000, 2, run_s=0.006)
    assert sum(big) == 1000 and big[0] == int(TASK_S / 0.006) and max(big) == big[0]
    assert all(a >= b for a, b in itertools.pairwise(big))
    assert min(big[:-1]) == int(MIN_TASK_S / 0.006)
    assert len(big) < 1000 / 50  # most runs travel in large chunks
    # 1 s runs: one run per task; 10 ms runs on 2 workers: 40 runs go as 10, 8, 6, 5, 5, 5, 1
    assert chunk_sizes(16, 2, run_s=1.0) == [1] * 16
    assert chunk_sizes(40, 2, run_s=0.01) == [10, 8, 6, 5, 5, 5, 1]
    assert chunk_sizes(10, 2, fixed=4) == [4, 4, 2]
    assert chunk_sizes(10, 2, fixed=4, run_s=0.001) == [4, 4, 2]


def test_chunk_sizer_learns_the_run_time_from_finished_runs() -> None:
    sizer = ChunkSizer(2)
    assert sizer.run_s is None and sizer.next(1000) == FIRST_CHUNK
    sizer.observe([0.5, 0.004, 0.004, 0.005, 0.004])  # a worker's first run (cache load) does not count much
    assert sizer.run_s == 0.004
    assert sizer.next(10_000) == int(TASK_S / 0.004)
    assert sizer.next(3) == 3 and sizer.next(0) == 0


def test_progress_line_shows_runs_failures_and_eta() -> None:
    out = io.StringIO()
    p = Progress("campaign x", total=10, already=4, stream=out)
    assert "4/10 runs (4 from before), 0 failed" in p.line() and "ETA -" in p.line()
    p.update(ok=2, failed=1)
    line = out.getvalue().strip().splitlines()[-1]
    assert "7/10 runs (4 from before), 1 failed" in line and "ETA" in line
    p.update(ok=3)
    assert out.getvalue().strip().splitlines()[-1].endswith("done")
    quiet = io.StringIO()
    Progress("q", 3, 0, stream=quiet, enabled=False).update(ok=3)
    assert quiet.getvalue() == ""


def test_prepare_then_execute_then_nothing_pending(tmp_path) -> None:
    from distributed import Client, LocalCluster

    spec_path = tmp_path / "s.yaml"
    spec_path.write_text(yaml.safe_dump({
        "name": "tiny", "base": str(ROOT / "config" / "sound_small_artery.yaml"),
        "overrides": {"sim.duration_s": 0.05, "sim.metrics_after_s": 0.0},
        "seeds": [0, 1, 2],
        "samples": {"count": 2, "rng_seed": 3, "params": {"physics.robot.radius_m": {
            "distribution": "normal", "mean": 250e-6, "std": 300e-6}}},
    }))
    spec, base = load_campaign_spec(spec_path)
    prep = prepare(spec, base)
    assert len(prep.tasks) == 6 and len({t.run_id for t in prep.tasks}) == 6
    store = CampaignStore(tmp_path / "out")
    store.write_manifest(prep.manifest, {"name": "tiny", "n_runs": 6, "varied_keys": list(spec.varied_keys())}, "")
    todo = pending(prep.tasks, store)
    assert len(todo) == 6
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster, \
            Client(cluster) as client:
        out = execute(todo[:4], store, client, prep.code, chunk_size=3)
    assert (out.n_ran, out.n_workers, out.n_tasks) == (4, 1, 2)
    assert out.busy_s > 0 and out.wall_s > 0
    assert len(list(store.parts.glob("part-*.parquet"))) == 2  # 3 + 1
    assert [t.index for t in pending(prep.tasks, store)] == [4, 5]
    rows = store.assemble().to_pylist()
    assert [r["index"] for r in rows] == [0, 1, 2, 3]
    radius = [r["physics.robot.radius_m"] for r in rows]
    # a negative draw fails with the key and value named, the others run
    for r, rad in zip(rows, radius):
        assert (r["status"] == "ok") == (rad > 0), r
        if rad <= 0:
            assert r["error"].startswith("ConfigError: physics.robot.radius_m must be > 0")
    assert {r["status"] for r in rows} == {"ok", "error"}
    failed = {r["run_id"] for r in rows if r["status"] == "error"}
    assert {t.run_id for t in pending(prep.tasks, store, retry_failed=True)} == failed | {t.run_id for t in prep.tasks[4:]}
    # the rest with automatic chunks (sized as they are submitted): every run stored once, nothing left
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        out = execute(pending(prep.tasks, store), store, client, prep.code)
    assert out.n_ran == 2 and out.n_workers == 2 and 1 <= out.n_tasks <= 2
    assert pending(prep.tasks, store) == []
    assert [r["index"] for r in store.assemble().to_pylist()] == list(range(6))


@pytest.mark.parametrize("n", [1, 7])
def test_prepare_is_deterministic(n) -> None:
    spec, base = load_campaign_spec(ROOT / "config" / "campaigns" / "table2_ranges.yaml")
    a, b = prepare(spec, base), prepare(spec, base)
    assert [t.run_id for t in a.tasks][:n] == [t.run_id for t in b.tasks][:n]
    assert a.manifest[:n] == b.manifest[:n]


@pytest.mark.parametrize("name", ["vf_error_seeds", "table2_ranges"])
def test_prepare_gives_each_run_the_address_of_its_resolved_scenario(name) -> None:
    # prepare resolves once per variant x grid point and hashes once per scenario; the ids must be
    # those of resolving and hashing every run on its own
    spec, base = load_campaign_spec(ROOT / "config" / "campaigns" / f"{name}.yaml")
    prep = prepare(spec, base)
    points = expand_points(spec, base)
    for p in points[::13]:
        task = prep.tasks[p.index]
        assert task.run_id == run_id(resolve_mapping(p.mapping), prep.code), p.index
        assert task.seed == p.seed and task.index == p.index
        assert {**task.mapping, "seed": p.seed} == resolve_mapping(p.mapping)
    # the runs of one scenario share its mapping (a chunk carries it once) and its key
    same = [t for t in prep.tasks if t.mapping is prep.tasks[0].mapping]
    assert len(same) == (1 if spec.samples.paired_with_seeds else len(spec.seed_list()))
    assert len({t.scenario_key for t in same}) == 1
    assert len({t.scenario_key for t in prep.tasks}) == len(prep.tasks) // len(same)


_CALLS: list[int] = []


def _recording_chunk_fn(*args):  # the in-process cluster calls it in this process
    _CALLS.append(len(args))
    return run_chunk(*args)


def _children_alive() -> list:
    import psutil

    return [c for c in psutil.Process().children() if c.status() != psutil.STATUS_ZOMBIE]


def test_a_run_over_the_budget_is_a_timeout_and_the_others_complete(tmp_path, monkeypatch) -> None:
    """A run that crawls (here: spins forever, as a collapsed adaptive step holds the compiled loop) is stopped
    at the campaign's run budget and recorded as ``timeout``; the other runs give run_closed_loop's numbers."""
    import time

    from distributed import Client, LocalCluster

    from vesselbot_ros.campaign import runner
    from vesselbot_ros.campaign.spec import campaign_spec_from_mapping
    from vesselbot_ros.campaign.summary import write_report
    from vesselbot_ros.config import load_yaml
    from vesselbot_ros.sim import closed_loop

    monkeypatch.setattr(runner, "IDLE_EXIT_S", 1.0)  # the run processes forked here end 1 s after their last chunk
    base = load_yaml(ROOT / "config" / "sound_small_artery.yaml")
    spec = campaign_spec_from_mapping({"name": "budget", "base": "-", "seeds": [0, 1, 2, 3, 4],
                                       "overrides": {"sim.duration_s": 0.05, "sim.metrics_after_s": 0.0},
                                       "run_timeout_s": 1.0})
    assert spec.run_timeout_s == 1.0
    from vesselbot_ros.sim.scenario import overridden

    prep = prepare(spec, overridden(base, spec.overrides))
    before = {c.pid for c in _children_alive()}  # run processes of other tests' threads, if any still run
    # no budget: every run here, in the worker thread, called as chunk_fn(tasks, code): the numbers to compare with
    # (this also loads the compiled loop in this process, which the run processes are forked from)
    store0 = CampaignStore(tmp_path / "plain")
    store0.write_manifest(prep.manifest, {"name": "plain", "n_runs": 5, "varied_keys": []}, "")
    _CALLS.clear()
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        plain = execute(prep.tasks, store0, client, prep.code, chunk_size=2, chunk_fn=_recording_chunk_fn)
    assert _CALLS == [2, 2, 2] and plain.n_failed == plain.n_timeout == 0
    expected = {r["seed"]: r for r in store0.assemble().to_pylist()}

    original = closed_loop.run_closed_loop

    def crawl_at_seed_2(scenario, seed=None, **kw):
        while seed == 2:
            pass
        return original(scenario, seed, **kw)

    monkeypatch.setattr(closed_loop, "run_closed_loop", crawl_at_seed_2)
    store = CampaignStore(tmp_path / "out")
    store.write_manifest(prep.manifest, {"name": "budget", "n_runs": 5, "varied_keys": [], "run_timeout_s": 1.0}, "")
    _CALLS.clear()
    t0 = time.monotonic()
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        out = execute(prep.tasks, store, client, prep.code, chunk_size=2, chunk_fn=_recording_chunk_fn,
                      run_timeout_s=spec.run_timeout_s)
    wall = time.monotonic() - t0
    assert wall < 60.0  # the crawl never ends by itself: only the budget (1 s) stopped it
    assert _CALLS == [3, 3, 3]  # chunk_fn(tasks, code, run_timeout_s)
    assert (out.n_ran, out.n_failed, out.n_timeout) == (5, 1, 1)
    rows = {r["seed"]: r for r in store.assemble().to_pylist()}
    assert rows[2]["status"] == "timeout" and "over the budget of 1 s of wall time" in rows[2]["error"]
    assert rows[2]["run_time_s"] >= 1.0
    for seed in (0, 1, 3, 4):  # the others ran, in run processes, to the same numbers as without a budget
        assert rows[seed]["status"] == "ok" and rows[seed]["error"] is None
        for k, v in expected[seed].items():
            if k not in ("run_time_s", "worker") and isinstance(v, float):
                assert rows[seed][k] == v or (v != v and rows[seed][k] != rows[seed][k]), (seed, k)
    # a timed-out run is done (not pending) unless failed runs are retried
    assert pending(prep.tasks, store) == []
    assert [t.seed for t in pending(prep.tasks, store, retry_failed=True)] == [2]
    _, text = write_report(list(rows.values()), {"name": "budget", "n_runs": 5, "run_timeout_s": 1.0}, tmp_path / "out")
    assert "5 of 5 runs finished, 4 ok, 0 failed, 1 over the run budget of 1 s" in text
    # the run processes end with the worker threads that forked them, or idle, whichever comes first
    deadline = time.monotonic() + 10.0
    while {c.pid for c in _children_alive()} - before and time.monotonic() < deadline:
        time.sleep(0.1)
    assert {c.pid for c in _children_alive()} - before == set()


def test_the_run_budget_must_be_positive(tmp_path) -> None:
    from vesselbot_ros.campaign.spec import campaign_spec_from_mapping
    from vesselbot_ros.config import ConfigError

    for bad, msg in ((0, "run_timeout_s must be > 0, got 0.0"), ("1 s", "run_timeout_s must be a number, got '1 s'"),
                     (float("inf"), "run_timeout_s must be finite, got inf")):
        with pytest.raises(ConfigError, match=re.escape(msg)):
            campaign_spec_from_mapping({"name": "x", "base": "-", "run_timeout_s": bad})
    assert campaign_spec_from_mapping({"name": "x", "base": "-"}).run_timeout_s is None
    with pytest.raises(ConfigError, match=re.escape("run_timeout_s must be > 0, got -1.0")):
        execute([], CampaignStore(tmp_path), None, "code", run_timeout_s=-1.0)
