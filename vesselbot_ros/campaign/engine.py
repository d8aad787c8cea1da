"""Run a campaign on Dask: a local cluster by default, any scheduler on request.

* :func:`prepare` turns a spec into content-addressed :class:`RunTask` s.
* :func:`dask_client` opens a ``LocalCluster`` sized to the machine (one
  worker process with one thread per core: the compiled loop releases the
  GIL) or connects to ``tcp://HOST:PORT``; the workers there need the same
  vesselbot_ros installed (a worker with other code records every run as an
  error rather than producing numbers under a wrong address).
* :func:`execute` skips the runs already in the folder, cuts the rest into
  chunks (one Dask task each, :func:`~vesselbot_ros.campaign.runner.run_chunk`),
  stores each chunk as it completes and draws the progress bar.

Chunk size: 0 (automatic) sizes each chunk when it is submitted
(:class:`ChunkSizer`, guided self-scheduling): about 1/(2 w) of the runs still
unassigned (w worker threads), at most :data:`TASK_S` and at least
:data:`MIN_TASK_S` of runs at the median run time measured so far.  The first
chunks are large, so Dask's cost per task (a few ms of scheduling and
serialisation, and the client writing a part) stays near 1 % of the runs it
carries (``bench/bench_campaign.py`` measures the run phase against
``run_many``); the last ones are short, so a worker that the machine slows
down, or a run that lasts longer than the others, leaves the other workers
idle for a short time only.  A fixed ``chunk_size`` gives equal chunks.

Run budget: with ``run_timeout_s`` each run has that much wall time on its
worker; a run over it is stopped (its process killed:
:class:`~vesselbot_ros.campaign.runner.RunProcess`) and recorded with status
``timeout``, and the campaign goes on.  Without one, the runs run in the
worker threads themselves, as before.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import logging
import math
import os
import statistics
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TextIO

from vesselbot_ros.campaign.runner import TIMEOUT_STATUS, RunTask, SeedHasher, code_version, resolve_with_code, run_chunk
from vesselbot_ros.campaign.spec import CampaignSpec, expand_points, group_mapping
from vesselbot_ros.campaign.store import CampaignStore
from vesselbot_ros.config import ConfigError, check_positive
from vesselbot_ros.errors import RunError
from vesselbot_ros.sim.scenario import overridden

__all__ = ["Prepared", "prepare", "local_worker_count", "dask_client", "ChunkSizer", "chunk_sizes", "Outcome", "pending", "execute",
           "Progress"]


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

    The work is done once per scenario, not once per run: each variant x grid
    point is resolved (validated, defaults filled in) once, a draw's values are
    set into that resolved mapping, and the runs of one scenario over its seeds
    share one mapping object and one serialisation for their ids
    (:class:`~vesselbot_ros.campaign.runner.SeedHasher`).  The ids are those
    of :func:`~vesselbot_ros.campaign.runner.run_id` on each run's resolved
    mapping.  A variant x grid point that does not validate keeps its raw
    mappings, and a draw is not validated here: the worker that builds such a
    scenario records its error for each of its runs.
    """
    code = code_version()
    tasks, manifest = [], []
    groups: dict[int, tuple[dict[str, Any], str] | None] = {}
    scenarios: dict[int, tuple[dict[str, Any], SeedHasher]] = {}
    for p in expand_points(spec, base_mapping):
        hit = scenarios.get(p.point)
        if hit is None:
            if p.group not in groups:
                try:
                    groups[p.group] = resolve_with_code(group_mapping(spec, base_mapping, p.values), code)
                except ConfigError:
                    groups[p.group] = None
            group = groups[p.group]
            if group is None:
                mapping, id_code = p.mapping, code
            else:
                resolved, id_code = group
                mapping = overridden(resolved, p.draw) if p.draw else resolved
            hit = scenarios[p.point] = (mapping, SeedHasher(mapping, id_code))
        mapping, hasher = hit
        tasks.append(RunTask(p.index, hasher(p.seed), p.seed, mapping, p.keep_timeseries, hasher.key))
        manifest.append({"index": p.index, "run_id": tasks[-1].run_id, "seed": p.seed,
                         **{k: _column_value(v) for k, v in p.values.items()}, "keep_timeseries": p.keep_timeseries})
    return Prepared(tasks, manifest, code)


def local_worker_count() -> int:
    """Cores this process may use (the affinity mask, not the machine's total)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, n_workers: int | None = None,
                closing: list[threading.Thread] | None = None) -> Iterator[Any]:
    """A ``distributed.Client``: on ``scheduler`` if given, else on a new ``LocalCluster``.

    The local cluster is one worker process with one thread per usable core,
    as :func:`~vesselbot_ros.sim.closed_loop.run_many` runs: the compiled loop
    releases the GIL, so threads run in parallel, and one process starts, imports
    the loop and loads its compiled code once instead of once per core (about
    1 s of CPU each on start).  The process keeps the client safe from a run
    that crashes compiled code: Dask records its chunks as failed
    (``KilledWorker``).  No dashboard: nobody looks at it during a campaign,
    and it costs start-up time.

    Args:
        scheduler: Address of an existing scheduler (``tcp://HOST:PORT``).
        n_workers: Parallel runs (threads) of the local cluster (default: one per usable core).
        closing: If given, a block that ends without an exception closes the
            cluster in a thread appended here (the worker processes take about
            0.5 s to exit, which the caller can spend on its report; join the
            thread before exiting).  Otherwise, and on an exception, it closes
            before the block returns.

    Raises:
        RunError: the scheduler cannot be reached, or the local cluster does not start.
    """
    # deferred: distributed takes ~0.5 s to import; planning a campaign (and one with nothing left to run) never needs it
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise RunError(f"cannot connect to the Dask scheduler {scheduler!r}: {exc}") from None
        try:
            yield client
        finally:
            client.close()
        return
    n = n_workers or local_worker_count()
    try:
        # the workers' own log lines at CRITICAL only: a run's failure is its row's 'error' and the campaign's one line;
        # at ERROR a worker whose heartbeat met the scheduler already closing printed a traceback on a loaded machine
        cluster = LocalCluster(n_workers=1, threads_per_worker=n, processes=True, dashboard_address=None,
                               silence_logs=logging.CRITICAL)
    except (OSError, TimeoutError, RuntimeError) as exc:
        raise RunError(f"cannot start a local Dask cluster of {n} workers: {exc}") from None
    client = Client(cluster)

    def close() -> None:
        client.close()
        cluster.close()

    try:
        yield client
    except BaseException:
        close()
        raise
    if closing is None:
        close()
    else:
        closing.append(threading.Thread(target=close, name="vesselbot-cluster-close"))
        closing[-1].start()


#: Target wall time of one Dask task (s): long enough that the fixed cost of a task (a few ms of
#: scheduling and serialisation, and the client writing its part) stays near 1 %, short enough that
#: a killed campaign loses little and the progress bar moves.
TASK_S = 1.0
#: Shortest task worth sending (s): the last, shrinking chunks stop at this many runs' worth.
MIN_TASK_S = 0.05
#: Runs per chunk before any run time is known (the first wave of tasks).
FIRST_CHUNK = 4
#: Tasks kept submitted per worker thread, so a worker never waits for the client between two chunks.
IN_FLIGHT = 2


class ChunkSizer:
    """Sizes of the chunks a campaign's runs are cut into, from the runs left and the measured run time.

    A fixed size gives equal chunks.  Otherwise (guided self-scheduling) each
    chunk takes about 1/(2 w) of the runs still unassigned (w workers), but at
    most :data:`TASK_S` and at least :data:`MIN_TASK_S` of runs (the median run
    time seen so far; :data:`FIRST_CHUNK` runs before the first chunk returns),
    and at least one run.  The first chunks are large, so the cost per task
    stays small against the runs it carries; the last ones are short, so a
    worker that the machine slows down, or a run that lasts longer than the
    others, leaves the other workers idle for a short time only.
    """

    def __init__(self, n_workers: int, fixed: int = 0, run_s: float | None = None) -> None:
        self.n_workers = max(1, n_workers)
        self.fixed = fixed
        self._times: collections.deque[float] = collections.deque(maxlen=512)
        self._run_s = run_s

    @property
    def run_s(self) -> float | None:
        """The run time (s) the sizes are based on: given, or the median of the observed ones."""
        if self._times:
            return float(statistics.median(self._times))
        return self._run_s

    def observe(self, run_times_s: Sequence[float]) -> None:
        """Record the wall times (s) of finished runs."""
        self._times.extend(float(t) for t in run_times_s)

    def next(self, left: int) -> int:
        """Runs in the next chunk, ``left`` runs being unassigned (0 when none)."""
        if left <= 0:
            return 0
        if self.fixed > 0:
            return min(self.fixed, left)
        guided = math.ceil(left / (2 * self.n_workers))
        run_s = self.run_s
        if run_s is None:
            return max(1, min(guided, FIRST_CHUNK))
        run_s = max(run_s, 1e-6)
        most = max(1, int(TASK_S / run_s))
        least = max(1, int(MIN_TASK_S / run_s))
        return min(left, max(least, min(guided, most)))


def chunk_sizes(n_runs: int, n_workers: int, fixed: int = 0, run_s: float | None = None) -> list[int]:
    """Sizes of the chunks that ``n_runs`` runs are cut into when each run takes ``run_s`` (:class:`ChunkSizer`).

    Args:
        n_runs: Runs to cut.
        n_workers: Worker threads.
        fixed: Runs per chunk; 0 = guided (shrinking) chunks.
        run_s: Wall time of one run (s); None = unknown (chunks of at most :data:`FIRST_CHUNK`).
    """
    sizer = ChunkSizer(n_workers, fixed, run_s)
    sizes = []
    left = n_runs
    while left > 0:
        sizes.append(sizer.next(left))
        left -= sizes[-1]
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
        n_timeout: Runs executed now that were stopped at the run budget (counted in ``n_failed`` too).
    """

    n_ran: int
    n_failed: int
    wall_s: float
    busy_s: float
    n_workers: int
    n_tasks: int
    n_timeout: int = 0


def _chunk_failed(chunk: Sequence[RunTask], exc: BaseException) -> list[dict[str, Any]]:
    return [{"run_id": t.run_id, "status": "error", "error": f"{type(exc).__name__}: {exc}", "metrics": {},
             "timeseries": None, "run_time_s": 0.0, "worker": None} for t in chunk]


class _Chunk:
    """A chunk of runs shipped as one object that Dask does not look into.

    Dask walks every list, tuple and dict of a task's arguments for futures:
    through a plain list of runs, that is every value of every scenario mapping,
    about 0.3 ms of the client's time per run.
    """

    def __init__(self, tasks: list[RunTask]) -> None:
        self.tasks = tasks


def _run_packed(chunk: _Chunk, code: str, chunk_fn: Callable[..., list[dict[str, Any]]],
                run_timeout_s: float | None = None) -> list[dict[str, Any]]:
    if run_timeout_s is None:  # the fast path: chunk_fn as it always was called
        return chunk_fn(chunk.tasks, code)
    return chunk_fn(chunk.tasks, code, run_timeout_s)


def pending(tasks: Sequence[RunTask], store: CampaignStore, retry_failed: bool = False) -> list[RunTask]:
    """The distinct runs of ``tasks`` that ``store`` does not hold yet (nor as failed or timed out, unless ``retry_failed``)."""
    finished = {rid for rid, status in store.statuses().items() if status == "ok" or not retry_failed}
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
    run_timeout_s: float | None = None,
) -> Outcome:
    """Run ``todo`` (see :func:`pending`) on ``client`` and store every chunk as it completes.

    Args:
        todo: The runs to execute.
        store: The campaign folder.
        client: A ``distributed.Client``.
        code: The client's code version (checked by every worker).
        chunk_size: Runs per task, 0 = shrinking chunks (:func:`chunk_sizes`).
        progress: Progress bar to update.
        chunk_fn: The function a task runs on a chunk (:func:`run_chunk`), called as
            ``chunk_fn(tasks, code)``, or ``chunk_fn(tasks, code, run_timeout_s)`` with a budget.
        run_timeout_s: Wall-clock budget of each run on its worker (s); None = no budget.
            A run over it is recorded with status ``timeout`` and the others go on.

    Raises:
        ConfigError: ``run_timeout_s`` is not a number > 0.
        RunError: the cluster failed (lost scheduler, ...); stored runs are kept.
    """
    # deferred: distributed (see dask_client)
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    if run_timeout_s is not None:
        check_positive("run_timeout_s", run_timeout_s)
    if todo and not client.nthreads():
        try:
            client.wait_for_workers(1, timeout=60)
        except TimeoutError:
            raise RunError(f"the Dask scheduler {client.scheduler.address} has no workers (waited 60 s)") from None
    n_workers = max(1, sum(client.nthreads().values()))
    sizer = ChunkSizer(n_workers, chunk_size)
    t0 = time.perf_counter()
    futures: dict[Any, Sequence[RunTask]] = {}
    queue = as_completed()
    pos = n_tasks = 0

    def submit() -> None:
        # sized when submitted, from the run times measured so far
        nonlocal pos, n_tasks
        size = sizer.next(len(todo) - pos)
        chunk = list(todo[pos:pos + size])
        pos += size
        n_tasks += 1
        fut = client.submit(_run_packed, _Chunk(chunk), code, chunk_fn, run_timeout_s,
                            key=f"vesselbot-chunk-{chunk[0].run_id}-{size}", pure=False)
        futures[fut] = chunk
        queue.add(fut)

    n_failed = n_timeout = 0
    busy = 0.0
    try:
        while pos < len(todo) and len(futures) < IN_FLIGHT * n_workers:
            submit()
        for fut in queue:
            chunk = futures.pop(fut)
            try:
                records = fut.result()
            except KilledWorker as exc:  # a run that kills its worker process, after Dask's retries
                records = _chunk_failed(chunk, exc)
            except Exception as exc:  # noqa: BLE001 - lost scheduler etc.: not a property of the runs
                raise RunError(
                    f"the Dask cluster failed ({type(exc).__name__}: {exc}); finished runs are saved in "
                    f"{str(store.root)!r}, run the same command again to resume"
                ) from None
            times = [float(r.get("run_time_s") or 0.0) for r in records]
            sizer.observe([t for t, r in zip(times, records) if r["status"] == "ok"])
            if pos < len(todo):
                submit()
            store.write_records(records)
            bad = sum(1 for r in records if r["status"] != "ok")
            n_failed += bad
            n_timeout += sum(1 for r in records if r["status"] == TIMEOUT_STATUS)
            busy += sum(times)
            if progress is not None:
                progress.update(ok=len(records) - bad, failed=bad)
    finally:
        if futures:
            client.cancel(list(futures))
        if progress is not None:
            progress.close()
    return Outcome(len(todo), n_failed, time.perf_counter() - t0, busy, n_workers, n_tasks, n_timeout)
