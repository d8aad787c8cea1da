"""Tests of the campaign engine: chunking, progress, resume bookkeeping, execution on a Dask client."""

from __future__ import annotations

import io
import itertools
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
from vesselbot_ros.campaign.runner import resolve_mapping, run_id
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
