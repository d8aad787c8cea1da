"""A campaign's folder: what was asked, what finished, the results table.

Layout of ``DIR`` (default ``out/campaigns/<name>/``)::

    campaign.json           name, spec file, code version, number of runs, varied keys
    spec.yaml               the spec as given (for the record)
    runs.parquet            the manifest: index, run_id, seed and the varied values of every run
    parts/part-*.parquet    finished runs, one file per completed chunk (written atomically)
    timeseries/<run_id>.parquet   full time series of the runs the spec keeps
    results.parquet         manifest joined with the finished runs, in run order
    summary.md, summary.csv summary table; figures/*.png: see vesselbot_ros.campaign.summary

Only ``parts/`` and ``timeseries/`` hold results; everything else is derived
and rewritten.  A part is written to a temporary name and renamed, after the
time series of its runs, so a campaign killed at any instant leaves either a
whole part or none: resuming reruns only the runs of the chunks in flight.
A part that cannot be read (a disk that filled up) is reported and its runs
run again.

Results table columns (``results.parquet``):

==========================  =====================================================
column                      meaning
==========================  =====================================================
index                       run position in the campaign order (grid x draws x seeds)
run_id                      content hash of scenario + seed + code version
seed                        imager noise seed
<dotted.scenario.key>       value of each varied key (grid and sampled)
status                      ``ok`` or ``error``
error                       ``"Type: message"`` of a failed run, else null
<metric>                    every numeric metric of ``run_closed_loop`` (SI units in the name)
run_time_s                  wall time of the run on its worker (s)
worker                      ``host:pid`` of the worker
timeseries                  ``timeseries/<run_id>.parquet`` when kept, else null
==========================  =====================================================
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from vesselbot_ros.errors import VesselbotError

__all__ = ["CampaignStore"]

_PART_COLUMNS = ("run_id", "status", "error", "run_time_s", "worker")


def _atomic_write_table(table: pa.Table, path: Path) -> None:
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    pq.write_table(table, tmp)
    os.replace(tmp, path)


def _rows_to_table(rows: Sequence[dict[str, Any]], first: Sequence[str] = ()) -> pa.Table:
    """A table from dict rows whose keys may differ (missing -> null), ``first`` columns first."""
    names: dict[str, None] = dict.fromkeys(first)
    for r in rows:
        names.update(dict.fromkeys(r))
    cols = {}
    for n in names:
        values = [r.get(n) for r in rows]
        try:
            cols[n] = pa.array(values)
        except (pa.ArrowInvalid, pa.ArrowTypeError):  # a grid of mixed types ([1, "a"]): store as text
            cols[n] = pa.array([None if v is None else str(v) for v in values], pa.string())
    return pa.table(cols)


class CampaignStore:
    """The folder of one campaign (see the module docstring)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.parts = self.root / "parts"
        self.timeseries = self.root / "timeseries"
        self.figures = self.root / "figures"

    # -- manifest ---------------------------------------------------------
    def write_manifest(self, rows: Sequence[dict[str, Any]], meta: dict[str, Any], spec_text: str) -> None:
        """Create the folder and write ``runs.parquet``, ``campaign.json`` and ``spec.yaml``.

        Args:
            rows: Per run: ``index``, ``run_id``, ``seed``, the varied values, ``keep_timeseries``.
            meta: JSON-able campaign metadata.
            spec_text: The spec file's text.
        """
        try:
            for d in (self.root, self.parts, self.timeseries):
                d.mkdir(parents=True, exist_ok=True)
                for tmp in d.glob(".*.tmp*"):  # left by a campaign killed while writing
                    tmp.unlink()
            _atomic_write_table(_rows_to_table(rows, ("index", "run_id", "seed")), self.root / "runs.parquet")
            (self.root / "campaign.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n", encoding="utf-8")
            (self.root / "spec.yaml").write_text(spec_text, encoding="utf-8")
        except OSError as exc:
            raise VesselbotError(f"cannot write the campaign folder {str(self.root)!r}: {exc}") from None

    def meta(self) -> dict[str, Any]:
        """``campaign.json``."""
        path = self.root / "campaign.json"
        if not path.is_file():
            raise VesselbotError(f"{str(self.root)!r} is not a campaign folder (no campaign.json)")
        try:
            return dict(json.loads(path.read_text(encoding="utf-8")))
        except (OSError, ValueError) as exc:
            raise VesselbotError(f"{str(path)!r} cannot be read: {exc}") from None

    def manifest(self) -> list[dict[str, Any]]:
        """Rows of ``runs.parquet``."""
        path = self.root / "runs.parquet"
        try:
            return list(pq.read_table(path).to_pylist())
        except (OSError, pa.ArrowException) as exc:
            raise VesselbotError(f"{str(path)!r} cannot be read: {exc}") from None

    # -- finished runs ----------------------------------------------------
    def finished(self) -> dict[str, dict[str, Any]]:
        """run_id -> stored row (status, error, metrics, ...) of every finished run."""
        out: dict[str, dict[str, Any]] = {}
        if not self.parts.is_dir():
            return out
        for part in sorted(self.parts.glob("part-*.parquet")):
            try:
                rows = pq.read_table(part).to_pylist()
            except (OSError, pa.ArrowException) as exc:
                print(f"vesselbot campaign: warning: skipping unreadable {part} ({exc}); its runs run again",
                      file=sys.stderr)
                continue
            for r in rows:
                # a run retried with --retry-failed has two records: a success wins over a failure
                if out.get(r["run_id"], {}).get("status") != "ok":
                    out[r["run_id"]] = r
        return out

    def write_records(self, records: Iterable[dict[str, Any]]) -> None:
        """Store the records of one finished chunk (time series first, then the part).

        Args:
            records: :func:`~vesselbot_ros.campaign.runner.run_chunk` records.
        """
        rows = []
        try:
            for rec in records:
                row = {k: rec.get(k) for k in _PART_COLUMNS}
                row.update(rec.get("metrics") or {})
                ts = rec.get("timeseries")
                if ts is not None:
                    self.timeseries.mkdir(parents=True, exist_ok=True)
                    _atomic_write_table(pa.table({k: np.asarray(v) for k, v in ts.items()}),
                                        self.timeseries / f"{rec['run_id']}.parquet")
                    row["timeseries"] = f"timeseries/{rec['run_id']}.parquet"
                rows.append(row)
            if not rows:
                return
            name = hashlib.sha256("".join(r["run_id"] for r in rows).encode()).hexdigest()[:20]
            self.parts.mkdir(parents=True, exist_ok=True)
            _atomic_write_table(_rows_to_table(rows, _PART_COLUMNS), self.parts / f"part-{name}.parquet")
        except OSError as exc:
            raise VesselbotError(f"cannot store finished runs in {str(self.root)!r}: {exc}") from None

    # -- results ----------------------------------------------------------
    def assemble(self) -> pa.Table:
        """Join the manifest with the finished runs; write and return ``results.parquet``.

        Only finished runs appear, in run order; ``campaign.json`` tells how many were asked.
        """
        done = self.finished()
        rows = []
        for m in self.manifest():
            r = done.get(m["run_id"])
            if r is None:
                continue
            row = {k: v for k, v in m.items() if k != "keep_timeseries"}
            # the manifest names the run (seed, varied values); the part adds what the run produced
            row.update({k: v for k, v in r.items() if k not in row})
            rows.append(row)
        meta = self.meta()
        first = ("index", "run_id", "seed", *meta.get("varied_keys", ()), "status", "error")
        table = _rows_to_table(rows, first) if rows else pa.table({k: pa.array([], pa.null()) for k in first})
        try:
            _atomic_write_table(table, self.root / "results.parquet")
        except OSError as exc:
            raise VesselbotError(f"cannot write {str(self.root / 'results.parquet')!r}: {exc}") from None
        return table

    def results(self) -> pa.Table:
        """The results table: assembled from the parts when they are here, else ``results.parquet``."""
        path = self.root / "results.parquet"
        if (self.root / "runs.parquet").is_file() and self.parts.is_dir():
            return self.assemble()
        try:
            return pq.read_table(path)
        except (OSError, pa.ArrowException) as exc:
            raise VesselbotError(f"{str(path)!r} cannot be read: {exc}") from None
