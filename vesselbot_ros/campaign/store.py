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
status                      ``ok``, ``error``, ``timeout`` (stopped at the campaign's run budget), or a run that
                            completed but cannot be trusted: ``rejected_commands`` (the coil rejected controller
                            commands and ramped to zero), ``diverged``
error                       ``"Type: message"`` of a failed or timed-out run, the warning line of an untrusted
                            one, else null
<metric>                    every numeric metric of ``run_closed_loop`` (SI units in the name)
run_time_s                  wall time of the run on its worker (s)
worker                      ``host:pid`` of the worker
timeseries                  ``timeseries/<run_id>.parquet`` when kept, else null
==========================  =====================================================
"""

from __future__ import annotations

import hashlib
import json
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from vesselbot_ros.atomic_io import atomic_path, write_text
from vesselbot_ros.errors import VesselbotError

__all__ = ["CampaignStore"]

_PART_COLUMNS = ("run_id", "status", "error", "run_time_s", "worker")


def _atomic_write_table(table: pa.Table, path: Path) -> None:
    with atomic_path(path) as tmp:  # whole or not at all; the temporary file never stays
        pq.write_table(table, tmp)


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
            write_text(self.root / "campaign.json", json.dumps(meta, indent=2, sort_keys=True) + "\n")
            write_text(self.root / "spec.yaml", spec_text)
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
    def _parts(self, columns: Sequence[str] | None = None) -> list[pa.Table]:
        """Every readable part (only ``columns`` of it, when given), in file-name order."""
        out: list[pa.Table] = []
        if not self.parts.is_dir():
            return out
        for part in sorted(self.parts.glob("part-*.parquet")):
            try:
                out.append(pq.read_table(part, columns=list(columns) if columns is not None else None))
            except (OSError, pa.ArrowException) as exc:
                print(f"vesselbot campaign: warning: skipping unreadable {part} ({exc}); its runs run again",
                      file=sys.stderr)
        return out

    def _finished_table(self, columns: Sequence[str] | None = None) -> pa.Table | None:
        """One row per finished run (a success wins over a failure of the same run), or None if none."""
        tables = self._parts(columns)
        if not tables:
            return None
        table = pa.concat_tables(tables, promote_options="default")
        # a run retried with --retry-failed has two records: keep its first success, else its first record
        chosen: dict[str, int] = {}
        ok: set[str] = set()
        for i, (rid, status) in enumerate(zip(table.column("run_id").to_pylist(), table.column("status").to_pylist())):
            if rid in ok:
                continue
            if status == "ok":
                ok.add(rid)
                chosen[rid] = i
            elif rid not in chosen:
                chosen[rid] = i
        if len(chosen) == table.num_rows:
            return table
        return table.take(pa.array(sorted(chosen.values()), pa.int64()))

    def statuses(self) -> dict[str, str]:
        """run_id -> ``ok`` / ``error`` / ``timeout`` of every finished run (reads only those two columns)."""
        table = self._finished_table(("run_id", "status"))
        if table is None:
            return {}
        return dict(zip(table.column("run_id").to_pylist(), table.column("status").to_pylist()))

    def finished(self) -> dict[str, dict[str, Any]]:
        """run_id -> stored row (status, error, metrics, ...) of every finished run."""
        table = self._finished_table()
        if table is None:
            return {}
        return {r["run_id"]: r for r in table.to_pylist()}

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
            name = hashlib.sha256("".join(str(r["run_id"]) for r in rows).encode()).hexdigest()[:20]
            self.parts.mkdir(parents=True, exist_ok=True)
            _atomic_write_table(_rows_to_table(rows, _PART_COLUMNS), self.parts / f"part-{name}.parquet")
        except OSError as exc:
            raise VesselbotError(f"cannot store finished runs in {str(self.root)!r}: {exc}") from None

    # -- results ----------------------------------------------------------
    def assemble(self) -> pa.Table:
        """Join the manifest with the finished runs; write and return ``results.parquet``.

        Only finished runs appear, in run order; ``campaign.json`` tells how many were asked.
        The join is columnar (pyarrow), so it costs little per run.
        """
        meta = self.meta()
        first = ("index", "run_id", "seed", *meta.get("varied_keys", ()), "status", "error")
        path = self.root / "runs.parquet"
        try:
            manifest = pq.read_table(path)
        except (OSError, pa.ArrowException) as exc:
            raise VesselbotError(f"{str(path)!r} cannot be read: {exc}") from None
        done = self._finished_table()
        rows_of = {} if done is None else {rid: i for i, rid in enumerate(done.column("run_id").to_pylist())}
        take_m, take_d = [], []
        for i, rid in enumerate(manifest.column("run_id").to_pylist()):
            j = rows_of.get(rid)
            if j is not None:
                take_m.append(i)
                take_d.append(j)
        if not take_m or done is None:
            table = pa.table({k: pa.array([], pa.null()) for k in first})
        else:
            # the manifest names the run (seed, varied values); the part adds what the run produced
            m = manifest.take(pa.array(take_m, pa.int64()))
            d = done.take(pa.array(take_d, pa.int64()))
            cols = {n: m.column(n) for n in m.column_names if n != "keep_timeseries"}
            cols.update({n: d.column(n) for n in d.column_names if n not in cols})
            order = [n for n in first if n in cols] + [n for n in cols if n not in first]
            table = pa.table({n: cols[n] for n in order})
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
