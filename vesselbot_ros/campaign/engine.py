"""Run a campaign on Dask: a local cluster by default, any scheduler on request.

* :func:`prepare` turns a spec into content-addressed :class:`RunTask` s.
* :func:`dask_client` opens a ``LocalCluster`` sized to the machine (one
  single-threaded worker process per core: the closed loop holds the GIL) or
  connects to ``tcp://HOST:PORT``; the workers there need the same
  vesselbot_ros installed (a worker with other code records every run as an
  error rather than producing numbers under a wrong address).
* :func:`execute` skips the runs already in the folder, cuts the rest into
  chunks (one Dask task each, :func:`~vesselbot_ros.campaign.runner.run_chunk`),
  stores each chunk as it completes and draws the progress bar.

Chunk size: 0 (automatic) cuts the runs into shrinking chunks (guided
self-scheduling): each chunk takes about 1/(2 w) of the runs still unassigned
(w workers), at most 32 and at least 1.  The first chunks are large, so Dask's
cost per task (a few ms of scheduling and serialisation, and the client
writing a part) stays far below 5 % of the runs it carries
(``bench/bench_campaign.py`` measures it); the last chunks are single runs, so
a worker that the machine slows down, or a run that lasts longer than the
others, leaves the other workers idle for one run at most.  A fixed
``chunk_size`` gives equal chunks.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TextIO

from vesselbot_ros.campaign.runner import RunTask, code_version, resolve_mapping, run_chunk, run_id
from vesselbot_ros.campaign.spec import CampaignSpec, expand_points
from vesselbot_ros.campaign.store import CampaignStore
from vesselbot_ros.config import ConfigError
from vesselbot_ros.errors import VesselbotError

__all__ = ["Prepared", "prepare", "local_worker_count", "dask_client", "chunk_sizes", "Outcome", "pending", "execute", "Progress"]


@dataclasses.dataclass(frozen=True)
class Prepared:
    """A campaign's runs and their manifest rows."""

    tasks: list[RunTask]
    manifest: list[dict[str, Any]]
    code: str


def _column_value(v: Any) -> Any:
    return v if isinstance(v, (bool, int, float, str)) or v is None else str(v)


def prepare(spec: CampaignSpec, base_mapping: dict[str, Any]) -> Prepared:
    """Every run of ``spec``: scenario resolved (defaults filled in) and hashed.

    A run whose drawn values make an invalid scenario keeps its raw mapping;
    its worker records the validation error.
    """
    code = code_version()
    tasks, manifest = [], []
    for p in expand_points(spec, base_mapping):
        try:
            mapping = resolve_mapping(p.mapping)
        except ConfigError:
            mapping = p.mapping
        rid = run_id(mapping, code)
        tasks.append(RunTask(p.index, rid, p.seed, mapping, p.keep_timeseries))
        manifest.append({"index": p.index, "run_id": rid, "seed": p.seed,
                         **{k: _column_value(v) for k, v in p.values.items()}, "keep_timeseries": p.keep_timeseries})
    return Prepared(tasks, manifest, code)


def local_worker_count() -> int:
    """Cores this process may use (the affinity mask, not the machine's total)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, n_workers: int | None = None) -> Iterator[Any]:
    """A ``distributed.Client``: on ``scheduler`` if given, else on a new ``LocalCluster``.

    Args:
        scheduler: Address of an existing scheduler (``tcp://HOST:PORT``).
        n_workers: Worker processes of the local cluster (default: one per usable core).

    Raises:
        VesselbotError: the scheduler cannot be reached, or the local cluster does not start.
    """
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise VesselbotError(f"cannot connect to the Dask scheduler {scheduler!r}: {exc}") from None
        try:
            yield client
        finally:
            client.close()
        return
    n = n_workers or local_worker_count()
    try:
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                               silence_logs=logging.ERROR)
    except (OSError, TimeoutError, RuntimeError) as exc:
        raise VesselbotError(f"cannot start a local Dask cluster of {n} workers: {exc}") from None
    client = Client(cluster)
    try:
        yield client
    finally:
        client.close()
        cluster.close()


def chunk_sizes(n_runs: int, n_workers: int, fixed: int = 0) -> list[int]:
    """Sizes of the chunks that ``n_runs`` runs are cut into (see the module docstring).

    Args:
        n_runs: Runs to cut.
        n_workers: Worker threads.
        fixed: Runs per chunk; 0 = guided (shrinking) chunks.
    """
    sizes = []
    left = n_runs
    while left > 0:
        size = fixed if fixed > 0 else max(1, min(32, math.ceil(left / (2 * max(1, n_workers)))))
        size = min(size, left)
        sizes.append(size)
        left -= size
    return sizes


class Progress:
    """A one-line progress bar on ``stream``: runs done, failures, elapsed time, ETA.

    On a terminal the line is redrawn in place; otherwise a line is printed at
    every 10 % and at the end, so logs stay short.
    """

    def __init__(self, name: str, total: int, already: int, stream: TextIO | None = None, enabled: bool = True) -> None:
        self.name, self.total, self.already = name, total, already
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.done = self.failed = 0
        self.t0 = time.monotonic()
        self._last_decile = -1

    def line(self) -> str:
        """The current progress line."""
        n = self.already + self.done
        frac = n / self.total if self.total else 1.0
        bar = "#" * int(round(30 * frac))
        elapsed = time.monotonic() - self.t0
        remaining = self.total - n
        if self.done and remaining:
            eta = f"ETA {remaining * elapsed / self.done:.0f} s"
        elif remaining:
            eta = "ETA -"
        else:
            eta = "done"
        extra = f" ({self.already} from before)" if self.already else ""
        return (f"{self.name} [{bar:<30}] {n}/{self.total} runs{extra}, {self.failed} failed, "
                f"{elapsed:.0f} s, {eta}")

    def update(self, ok: int = 0, failed: int = 0, force: bool = False) -> None:
        """Count finished runs and redraw."""
        self.done += ok + failed
        self.failed += failed
        if not self.enabled:
            return
        if self.tty:
            self.stream.write("\r" + self.line() + "\033[K")
            self.stream.flush()
            return
        n = self.already + self.done
        decile = int(10 * n / self.total) if self.total else 10
        if force or decile != self._last_decile:
            self._last_decile = decile
            print(self.line(), file=self.stream, flush=True)

    def close(self) -> None:
        """Finish the line."""
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()


@dataclasses.dataclass(frozen=True)
class Outcome:
    """What :func:`execute` did.

    Attributes:
        n_ran: Runs executed now.
        n_failed: Runs executed now that failed.
        wall_s: Wall time of the execution (s), cluster start excluded.
        busy_s: Sum of the runs' own wall times on the workers (s).
        n_workers: Worker threads used.
        n_tasks: Dask tasks (chunks) used.
    """

    n_ran: int
    n_failed: int
    wall_s: float
    busy_s: float
    n_workers: int
    n_tasks: int


def _chunk_failed(chunk: Sequence[RunTask], exc: BaseException) -> list[dict[str, Any]]:
    return [{"run_id": t.run_id, "status": "error", "error": f"{type(exc).__name__}: {exc}", "metrics": {},
             "timeseries": None, "run_time_s": 0.0, "worker": None} for t in chunk]


def pending(tasks: Sequence[RunTask], store: CampaignStore, retry_failed: bool = False) -> list[RunTask]:
    """The distinct runs of ``tasks`` that ``store`` does not hold yet (nor as failed, unless ``retry_failed``)."""
    done = store.finished()
    finished = {rid for rid, r in done.items() if r.get("status") == "ok" or not retry_failed}
    return [t for t in {t.run_id: t for t in tasks}.values() if t.run_id not in finished]


def execute(
    todo: Sequence[RunTask],
    store: CampaignStore,
    client: Any,
    code: str,
    *,
    chunk_size: int = 0,
    progress: Progress | None = None,
    chunk_fn: Callable[..., list[dict[str, Any]]] = run_chunk,
) -> Outcome:
    """Run ``todo`` (see :func:`pending`) on ``client`` and store every chunk as it completes.

    Args:
        todo: The runs to execute.
        store: The campaign folder.
        client: A ``distributed.Client``.
        code: The client's code version (checked by every worker).
        chunk_size: Runs per task, 0 = shrinking chunks (:func:`chunk_sizes`).
        progress: Progress bar to update.
        chunk_fn: The function a task runs on a chunk (:func:`run_chunk`).

    Raises:
        VesselbotError: the cluster failed (lost scheduler, ...); stored runs are kept.
    """
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    if todo and not client.nthreads():
        try:
            client.wait_for_workers(1, timeout=60)
        except TimeoutError:
            raise VesselbotError(f"the Dask scheduler {client.scheduler.address} has no workers (waited 60 s)") from None
    n_workers = max(1, sum(client.nthreads().values()))
    chunks, i = [], 0
    for size in chunk_sizes(len(todo), n_workers, chunk_size):
        chunks.append(todo[i:i + size])
        i += size
    t0 = time.perf_counter()
    futures = {client.submit(chunk_fn, c, code, key=f"vesselbot-chunk-{c[0].run_id}-{len(c)}", pure=False): c
               for c in chunks}
    n_failed = 0
    busy = 0.0
    try:
        for fut in as_completed(list(futures)):
            chunk = futures.pop(fut)
            try:
                records = fut.result()
            except KilledWorker as exc:  # a run that kills its worker process, after Dask's retries
                records = _chunk_failed(chunk, exc)
            except Exception as exc:  # noqa: BLE001 - lost scheduler etc.: not a property of the runs
                raise VesselbotError(
                    f"the Dask cluster failed ({type(exc).__name__}: {exc}); finished runs are saved in "
                    f"{str(store.root)!r}, run the same command again to resume"
                ) from None
            store.write_records(records)
            bad = sum(1 for r in records if r["status"] != "ok")
            n_failed += bad
            busy += sum(float(r.get("run_time_s") or 0.0) for r in records)
            if progress is not None:
                progress.update(ok=len(records) - bad, failed=bad)
    finally:
        if futures:
            client.cancel(list(futures))
        if progress is not None:
            progress.close()
    return Outcome(len(todo), n_failed, time.perf_counter() - t0, busy, n_workers, len(chunks))
