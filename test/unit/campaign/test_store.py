"""Tests of the campaign folder: parts written atomically, resume bookkeeping, results table."""

from __future__ import annotations

import numpy as np
import pyarrow.parquet as pq
import pytest

from vesselbot_ros.campaign.store import CampaignStore
from vesselbot_ros.errors import VesselbotError


def _rec(rid: str, ok: bool = True, ts: bool = False) -> dict:
    return {
        "run_id": rid,
        "status": "ok" if ok else "error",
        "error": None if ok else "RuntimeError: boom",
        "metrics": {"tracking_error_max_m": 1e-4 * len(rid), "wall_contacts": 2} if ok else {},
        "timeseries": {"t_s": np.arange(3) * 1e-3, "in_contact": np.array([0, 1, 0], dtype=bool)} if ts else None,
        "run_time_s": 0.1,
        "worker": "h:1",
    }


@pytest.fixture
def store(tmp_path) -> CampaignStore:
    s = CampaignStore(tmp_path / "c")
    manifest = [{"index": i, "run_id": rid, "seed": i, "k.x": float(i), "keep_timeseries": i == 0}
                for i, rid in enumerate(["a", "bb", "ccc", "dddd"])]
    s.write_manifest(manifest, {"name": "c", "n_runs": 4, "varied_keys": ["k.x"], "grid_keys": []}, "name: c\n")
    return s


def test_records_round_trip_and_assemble_in_run_order(store) -> None:
    assert store.finished() == {}
    store.write_records([_rec("ccc"), _rec("a", ts=True)])
    store.write_records([_rec("bb", ok=False)])
    done = store.finished()
    assert set(done) == {"a", "bb", "ccc"}
    assert store.statuses() == {"a": "ok", "bb": "error", "ccc": "ok"}
    assert done["bb"]["error"] == "RuntimeError: boom" and done["bb"].get("tracking_error_max_m") is None
    assert not list(store.parts.glob(".*"))  # no temporary files left
    table = store.assemble()
    assert table.column_names[:6] == ["index", "run_id", "seed", "k.x", "status", "error"]
    rows = table.to_pylist()
    assert [r["run_id"] for r in rows] == ["a", "bb", "ccc"]  # run order, unfinished "dddd" absent
    assert rows[0]["tracking_error_max_m"] == pytest.approx(1e-4, rel=1e-12)
    assert rows[0]["timeseries"] == "timeseries/a.parquet"
    ts = pq.read_table(store.root / rows[0]["timeseries"])
    np.testing.assert_array_equal(ts.column("in_contact").to_numpy(zero_copy_only=False), [False, True, False])
    assert pq.read_table(store.root / "results.parquet").num_rows == 3
    assert store.results().num_rows == 3
    assert store.meta()["n_runs"] == 4


def test_an_unreadable_part_is_skipped_and_its_runs_run_again(store, capsys) -> None:
    store.write_records([_rec("a")])
    (store.parts / "part-broken.parquet").write_bytes(b"PAR1 truncated")
    assert set(store.finished()) == {"a"}
    assert "skipping unreadable" in capsys.readouterr().err


def test_not_a_campaign_folder(tmp_path) -> None:
    with pytest.raises(VesselbotError, match="not a campaign folder"):
        CampaignStore(tmp_path).meta()


def test_mixed_type_columns_are_stored_as_text_and_stale_temporaries_removed(tmp_path) -> None:
    s = CampaignStore(tmp_path / "m")
    s.parts.mkdir(parents=True)
    (s.parts / ".part-x.parquet.tmp123").write_bytes(b"half")
    s.write_manifest([{"index": 0, "run_id": "a", "seed": 0, "g": 1.5}, {"index": 1, "run_id": "b", "seed": 0, "g": "x"}],
                     {"name": "m", "n_runs": 2, "varied_keys": ["g"]}, "")
    assert not list(s.parts.glob(".*"))
    assert [r["g"] for r in s.manifest()] == ["1.5", "x"]


def test_a_retried_run_that_succeeds_wins_over_its_old_failure(store) -> None:
    store.write_records([_rec("zz", ok=False)])
    (failed,) = store.parts.glob("part-*.parquet")
    failed = failed.rename(store.parts / "part-m-failed.parquet")
    store.write_records([_rec("zz"), _rec("a")])
    (ok,) = [p for p in store.parts.glob("part-*.parquet") if p != failed]
    ok = ok.rename(store.parts / "part-a-ok.parquet")  # read before the failure
    assert store.finished()["zz"]["status"] == "ok"
    ok.rename(store.parts / "part-z-ok.parquet")  # read after it
    assert store.finished()["zz"]["status"] == "ok"
    assert store.statuses()["zz"] == "ok"
    assert [r["run_id"] for r in store.assemble().to_pylist()] == ["a"]  # "zz" is not in the manifest
