"""The unit of work of a campaign: a chunk of runs of the pure closed loop.

:func:`run_chunk` is the one function a Dask task calls: it takes a list of
:class:`RunTask`, runs each with
:func:`~vesselbot_ros.sim.closed_loop.run_closed_loop` and returns one record
per run.  A run that raises is recorded with its error; it never stops the
chunk.  Nothing here knows about Dask or files.

Runs that differ only in their seed share one scenario mapping (the same
object in the tasks, so a chunk carries it once).  A worker builds and
validates each distinct scenario once, and keeps the last few
(:data:`SCENARIO_CACHE`), so the compiled loop's prepared inputs (stages,
reference samples) are built once per scenario, not once per run, as in
:func:`~vesselbot_ros.sim.closed_loop.run_many`; each run then costs its
compiled loop and its metrics only, and its numbers are bit for bit those of
``run_closed_loop(scenario, seed)``.

Runs are content-addressed: :func:`run_id` hashes the resolved scenario
mapping (every field, defaults filled in, seed included) together with
:func:`code_version`, a hash of the source of the cores that compute a run
(physics, control, sim, config) and of the numeric libraries' versions.  The
same scenario, seed and code give the same id and, the loop being
deterministic, the same numbers; new code gives new ids, so a resumed campaign
never mixes results of two versions.  :class:`SeedHasher` gives the same ids
as :func:`run_id` for every seed of one scenario while serialising the
scenario once.

A wall-clock budget per run (``run_timeout_s``) bounds a run that crawls (the
plant's adaptive step collapsing while the bead rests on the wall).  The
compiled loop holds its thread until the run ends, so no thread-level timeout
can stop it: with a budget, each worker thread hands its chunk to a process of
its own (:class:`RunProcess`, forked from the worker, so the loaded code and
the imports come along), which runs the chunk's runs back to back and sends
each record as it finishes; the thread waits for each record at most the
budget, and on expiry kills that process, records the run with status
``timeout`` and forks a new one for the runs left.  Without a budget the runs
run in the worker thread itself, as they always did.
"""

from __future__ import annotations

import collections
import contextlib
import ctypes
import functools
import hashlib
import json
import multiprocessing.connection
import os
import platform
import signal
import socket
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numba
import numpy as np
import scipy

from vesselbot_ros.config import ConfigError
from vesselbot_ros.physics.axes import AXES
from vesselbot_ros.sim import closed_loop, kinds
from vesselbot_ros.sim import scenario as scenario_module

__all__ = ["RunTask", "code_version", "run_id", "SeedHasher", "resolve_mapping", "resolve_with_code", "run_chunk", "flatten_timeseries",
           "SCENARIO_CACHE", "RunProcess", "TIMEOUT_STATUS"]

# Sources whose change can change a run's numbers (relative to the package folder).
_CODE_GLOBS = ("config.py", "errors.py", "physics/**/*.py", "physics/data/*", "control/**/*.py", "sim/**/*.py")


class RunTask(NamedTuple):
    """One run as shipped to a worker.

    Attributes:
        index: Position in the campaign's run order.
        run_id: Content hash (:func:`run_id`).
        seed: Imager noise seed of the run.  It wins over ``mapping["seed"]``.
        mapping: The scenario mapping to build and run (never modified).  The
            runs of one scenario over several seeds share one object.
        keep_timeseries: Return the time series too.
        scenario_key: Digest of ``mapping`` without its seed (:attr:`SeedHasher.key`), or ""; a
            worker keeps the scenarios it built under this key, so the chunks
            of one scenario build it once per worker.
    """

    index: int  # type: ignore[assignment]  # the field's name shadows tuple.index on purpose
    run_id: str
    seed: int
    mapping: dict[str, Any]
    keep_timeseries: bool
    scenario_key: str = ""


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """Hash (16 hex digits) of the run-relevant source files and library versions."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    files = sorted({f for g in _CODE_GLOBS for f in root.glob(g) if f.is_file() and "__pycache__" not in f.parts})
    for f in files:
        h.update(f.relative_to(root).as_posix().encode())
        h.update(b"\0")
        h.update(f.read_bytes())
    h.update(f"numpy {np.__version__} scipy {scipy.__version__} numba {numba.__version__} "
             f"python {platform.python_version()} {platform.machine()}".encode())
    return h.hexdigest()[:16]


def resolve_mapping(mapping: dict[str, Any]) -> dict[str, Any]:
    """The full, validated scenario mapping of ``mapping`` (defaults filled in).

    Raises:
        ConfigError: the mapping is not a valid scenario.
    """
    return scenario_module.scenario_from_mapping(mapping).to_mapping()


def resolve_with_code(mapping: dict[str, Any], code: str) -> tuple[dict[str, Any], str]:
    """:func:`resolve_mapping`, and the code version its run ids hash.

    That is ``code``, joined by the hash of the source of every stage kind of
    the user's that the scenario names (:func:`vesselbot_ros.sim.kinds.fingerprint`):
    editing a plug-in gives its runs new ids, so a resumed campaign reruns them.

    Raises:
        ConfigError: the mapping is not a valid scenario.
    """
    scenario = scenario_module.scenario_from_mapping(mapping)
    fp = kinds.fingerprint(scenario)
    return scenario.to_mapping(), f"{code}+{fp}" if fp else code


def run_id(mapping: dict[str, Any], code: str) -> str:
    """Content address of a run: sha256 of the scenario mapping (seed included) and the code version.

    Args:
        mapping: The scenario mapping (resolved with :func:`resolve_mapping`
            when it is valid, so equivalent spellings hash alike).
        code: :func:`code_version` of the code that runs it.
    """
    doc = json.dumps({"scenario": mapping, "code": code}, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(doc.encode()).hexdigest()[:24]


_SEED_SENTINEL = "\x00vesselbot-seed\x00"


class SeedHasher:
    """:func:`run_id` of one scenario mapping for any seed, with the mapping serialised once.

    ``SeedHasher(m, code)(s) == run_id({**m, "seed": s}, code)`` for every
    integer seed ``s``: the JSON document is cut at the seed's value, the part
    before it hashed once, and each seed hashes only its digits and the rest.

    Attributes:
        key: Digest (24 hex digits) of the mapping and code without the seed.
    """

    def __init__(self, mapping: dict[str, Any], code: str) -> None:
        doc = json.dumps({"scenario": {**mapping, "seed": _SEED_SENTINEL}, "code": code}, sort_keys=True,
                         separators=(",", ":"), allow_nan=True)
        head, sep, tail = doc.partition(json.dumps(_SEED_SENTINEL))
        if not sep or json.dumps(_SEED_SENTINEL) in tail:  # pragma: no cover - the sentinel cannot be a YAML value
            raise ValueError("SeedHasher: the seed sentinel appears in the mapping")
        self._head = hashlib.sha256(head.encode())
        self._tail = tail
        self.key = hashlib.sha256(doc.encode()).hexdigest()[:24]

    def __call__(self, seed: int) -> str:
        """The run id of the mapping with ``seed``."""
        h = self._head.copy()
        h.update(f"{int(seed)}{self._tail}".encode())
        return h.hexdigest()[:24]


def flatten_timeseries(series: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Time-series columns as 1-D arrays: (n, 2) vectors -> ``<key>_x``, ``<key>_z``; (n, 3) vectors of a 3-D tree
    -> ``<key>_x``, ``<key>_y``, ``<key>_z``.

    Higher ranks (the (n, 8, 2) or (n, 8, 3) force breakdown) become ``<key>_<i>_x`` / ... / ``_z``.
    """
    out: dict[str, np.ndarray] = {}
    for key, a in series.items():
        a = np.asarray(a)
        names = AXES.get(a.shape[-1]) if a.ndim > 1 else None
        if a.ndim == 1:
            out[key] = a
        elif a.ndim == 2 and names:
            for j, ax in enumerate(names):
                out[f"{key}_{ax}"] = a[:, j]
        else:
            flat = a.reshape(a.shape[0], -1, a.shape[-1])
            axes = names or [str(j) for j in range(a.shape[-1])]
            for i in range(flat.shape[1]):
                for j, ax in enumerate(axes):
                    out[f"{key}_{i}_{ax}"] = flat[:, i, j]
    return out


#: Scenarios a worker process keeps built (by :attr:`RunTask.scenario_key`): one campaign's distinct
#: scenarios arrive in order, so a few suffice for the chunks of one to find it built.
SCENARIO_CACHE = 16
_SCENARIOS: collections.OrderedDict[str, Any] = collections.OrderedDict()
_SCENARIOS_LOCK = threading.Lock()


def _scenario(task: RunTask, local: dict[int, Any]) -> Any:
    """The task's :class:`Scenario` (or the ConfigError that building it raised), built once per mapping."""
    hit = local.get(id(task.mapping))
    if hit is not None:
        return hit
    if task.scenario_key:
        with _SCENARIOS_LOCK:  # a worker's threads share the cache
            hit = _SCENARIOS.get(task.scenario_key)
            if hit is not None:
                _SCENARIOS.move_to_end(task.scenario_key)
    if hit is None:
        try:
            hit = scenario_module.scenario_from_mapping(task.mapping)
        except ConfigError as exc:
            hit = exc
        if task.scenario_key:
            with _SCENARIOS_LOCK:
                _SCENARIOS[task.scenario_key] = hit
                while len(_SCENARIOS) > SCENARIO_CACHE:
                    _SCENARIOS.popitem(last=False)
    local[id(task.mapping)] = hit
    return hit


#: Status of a run that completed on commands the coil rejected (non-finite, not a command, a controller that
#: raised): the coil ramped to zero, so its metrics are not the controller's result.
REJECTED_STATUS = "rejected_commands"


def run_outcome(metrics: dict[str, Any]) -> tuple[str, str | None]:
    """``(status, error)`` of a completed run from its metrics: ``("ok", None)``, or the metrics' own status
    (``diverged``, ...) or :data:`REJECTED_STATUS` with its one warning line."""
    status = metrics.get("status")
    rejected = int(metrics.get("rejected_commands") or 0)
    if not isinstance(status, str) or not status or (status == "ok" and rejected):
        status = REJECTED_STATUS if rejected else "ok"
    if status == "ok":
        return "ok", None
    if status == REJECTED_STATUS:
        return status, kinds.rejection_warning(metrics)
    return status, str(metrics.get("divergence") or status)


def _one(task: RunTask, local: dict[int, Any]) -> dict[str, Any]:
    t0 = time.perf_counter()
    rec: dict[str, Any] = {"run_id": task.run_id, "status": "ok", "error": None, "metrics": {}, "timeseries": None}
    try:
        scenario = _scenario(task, local)
        if isinstance(scenario, Exception):  # built once, failed once: every run of it records that error
            rec.update(status="error", error=f"{type(scenario).__name__}: {scenario}",
                       run_time_s=time.perf_counter() - t0)
            return rec
        result = closed_loop.run_closed_loop(scenario, task.seed)
        rec["metrics"] = {k: v for k, v in result.metrics.items()
                          if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)}
        rec["status"], rec["error"] = run_outcome(result.metrics)  # ok, or a run whose result cannot be trusted
        if task.keep_timeseries:
            rec["timeseries"] = flatten_timeseries(result.timeseries)
    except Exception as exc:  # noqa: BLE001 - a failing run is a result, not a crash
        rec["status"] = "error"
        rec["error"] = f"{type(exc).__name__}: {exc}"
    rec["run_time_s"] = time.perf_counter() - t0
    return rec


#: Status of a run stopped at its wall-clock budget (besides ``ok`` and ``error``).
TIMEOUT_STATUS = "timeout"

_PR_SET_PDEATHSIG = 1  # prctl(2): signal this process when the thread that forked it ends


def _die_with_parent(parent_pid: int) -> None:
    """Have the kernel SIGKILL this process when the worker thread that forked it ends (Linux; elsewhere a no-op)."""
    # not Linux: the closed pipe still ends the process
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent_pid:  # the worker died between the fork and the prctl
        os._exit(0)


#: A run process that has had no chunk for this long (s) ends by itself (exit code :data:`IDLE_EXIT_CODE`):
#: a worker whose threads outlive its cluster (an in-process cluster's thread pool) leaves none behind for long,
#: while the chunks of a campaign, which follow each other closely, keep one process and its loaded code.
IDLE_EXIT_S = 20.0
IDLE_EXIT_CODE = 75


def _serve(conn: multiprocessing.connection.Connection, parent_pid: int) -> int:
    """A run process's loop: receive a list of :class:`RunTask`, send their records one by one as they finish,
    until the worker closes the pipe (returns 0) or sends nothing for :data:`IDLE_EXIT_S` (returns
    :data:`IDLE_EXIT_CODE`)."""
    global _SCENARIOS, _SCENARIOS_LOCK
    _die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C stops the command; the worker then ends this process
    # Another thread of the worker may have held the lock at the fork; this process starts its own cache.
    _SCENARIOS = collections.OrderedDict()
    _SCENARIOS_LOCK = threading.Lock()
    while True:
        try:
            if not conn.poll(IDLE_EXIT_S):
                return IDLE_EXIT_CODE  # nothing was received: the worker forks a new process for its next chunk
            tasks = conn.recv()
        except (EOFError, OSError):  # the worker closed the pipe, or died
            return 0
        # a fresh local cache per batch: the batch's runs of one scenario share one mapping object, which
        # lives as long as the batch (a later batch's mappings are new objects whose ids may repeat)
        local: dict[int, Any] = {}
        for task in tasks:
            conn.send(_one(task, local))


class RunProcess:
    """A process forked from this worker that runs lists of :class:`RunTask`, each run within a wall-clock budget.

    The fork copies the worker's memory: the imported modules and the compiled
    code it has loaded (a fresh worker's first run process loads numba's cache
    once, then runs every run it is given).  The process keeps its own cache
    of built scenarios, closes every file the worker had open but its pipe,
    ignores Ctrl-C and is killed by the kernel when the thread that forked it
    ends (``PR_SET_PDEATHSIG``); it ends by itself when the pipe closes, or after
    :data:`IDLE_EXIT_S` without a chunk.
    """

    def __init__(self) -> None:
        parent_pid = os.getpid()
        mine, theirs = multiprocessing.connection.Pipe(duplex=True)
        pid = os.fork()
        if pid == 0:  # the run process
            code = 0
            try:
                keep = theirs.fileno()
                os.closerange(3, keep)  # the worker's sockets, files and other run processes' pipes
                os.closerange(keep + 1, os.sysconf("SC_OPEN_MAX"))
                code = _serve(theirs, parent_pid)
            except BaseException:  # noqa: BLE001 - nothing of the worker's may run in this process
                code = 1
            finally:
                os._exit(code)
        theirs.close()
        self.pid = pid
        self.conn = mine
        self._owner = parent_pid
        # a handle on this very process: killing and reaping by pid could hit another process (or a thread of this
        # one) that reused the pid if something else reaped ours after it ended idle
        self._pidfd = os.pidfd_open(pid) if hasattr(os, "pidfd_open") else -1

    def run(self, tasks: Sequence[RunTask], budget_s: float) -> list[dict[str, Any]]:
        """Run ``tasks`` in this process, one after the other; their records, up to the first that did not finish.

        The tasks go in one message and the process runs them back to back,
        sending each record as it finishes; each run has ``budget_s`` from the
        previous record's arrival (or from the send).  A run over it ends the
        list with a ``timeout`` record, a process that died with an ``error``
        record; this object is then closed (make a new one for the runs left).
        """
        out: list[dict[str, Any]] = []
        t0 = time.perf_counter()
        try:
            self.conn.send(list(tasks))
            for task in tasks:
                if not self.conn.poll(budget_s):
                    self.close()
                    out.append({"run_id": task.run_id, "status": TIMEOUT_STATUS, "metrics": {}, "timeseries": None,
                                "run_time_s": time.perf_counter() - t0,
                                "error": f"Timeout: over the budget of {budget_s:g} s of wall time (run_timeout_s); "
                                         f"stopped"})
                    return out
                out.append(self.conn.recv())
                t0 = time.perf_counter()
        except (EOFError, OSError):  # the process died (a crash in compiled code, the OOM killer)
            status = self.close()
            if not out and status == f"exit code {IDLE_EXIT_CODE}":
                return out  # it had ended idle before it took the chunk: nothing ran, the caller forks a new one
            out.append({"run_id": tasks[len(out)].run_id, "status": "error", "metrics": {}, "timeseries": None,
                        "run_time_s": time.perf_counter() - t0,
                        "error": f"RunProcessDied: the run's process ended ({status}) before returning the run"})
        return out

    @property
    def closed(self) -> bool:
        """Whether the process was ended (:meth:`close`)."""
        return self.conn.closed

    def close(self) -> str:
        """Kill the process (if alive) and reap it; how it ended (``signal N`` / ``exit code N``).

        Only the worker that forked it does: a run process forked later inherits this object
        (in another thread's locals, which the fork clears) and must leave it alone.
        """
        if os.getpid() != self._owner:
            return "not this process's"
        if self.conn.closed:
            return "closed"
        self.conn.close()
        if self._pidfd >= 0:  # Linux: signal and reap through the process's own handle
            try:
                with contextlib.suppress(ProcessLookupError):
                    signal.pidfd_send_signal(self._pidfd, signal.SIGKILL)
                try:
                    info = os.waitid(os.P_PIDFD, self._pidfd, os.WEXITED)
                except ChildProcessError:
                    return "reaped"
            finally:
                os.close(self._pidfd)
                self._pidfd = -1
            if info is None:  # pragma: no cover - WEXITED without WNOHANG always reports
                return "reaped"
            if info.si_code in (os.CLD_KILLED, os.CLD_DUMPED):
                return f"signal {info.si_status}"
            return f"exit code {info.si_status}"
        with contextlib.suppress(ProcessLookupError):  # pragma: no cover - elsewhere: by pid
            os.kill(self.pid, signal.SIGKILL)
        try:  # pragma: no cover
            _, status = os.waitpid(self.pid, 0)
        except ChildProcessError:  # pragma: no cover
            return "reaped"
        if os.WIFSIGNALED(status):  # pragma: no cover
            return f"signal {os.WTERMSIG(status)}"
        return f"exit code {os.WEXITSTATUS(status)}"  # pragma: no cover

    def __del__(self) -> None:
        try:  # noqa: SIM105 - at interpreter exit contextlib itself may be gone
            self.close()
        except Exception:  # noqa: BLE001 - at interpreter exit the os module may be gone
            pass


_THREAD = threading.local()  # each worker thread's RunProcess


def _bounded(tasks: Sequence[RunTask], budget_s: float) -> list[dict[str, Any]]:
    """Run ``tasks`` in this thread's :class:`RunProcess`.

    The process is kept for the thread's next chunks, so the compiled code it
    loaded is loaded once (a new process of a worker that never ran a run itself
    loads numba's cache again, about 0.4 s); a new one is forked on first use,
    after a timeout or a death, and after the process ended idle (:data:`IDLE_EXIT_S`).
    """
    out: list[dict[str, Any]] = []
    while len(out) < len(tasks):
        proc: RunProcess | None = getattr(_THREAD, "proc", None)
        if proc is None or proc.closed:
            proc = _THREAD.proc = RunProcess()
        out.extend(proc.run(tasks[len(out):], budget_s))
    return out


def run_chunk(tasks: list[RunTask], expected_code: str | None = None,
              run_timeout_s: float | None = None) -> list[dict[str, Any]]:
    """Run ``tasks`` one after the other; one record per task, in order.

    Each distinct scenario of the chunk is built once (see the module docstring);
    ``run_time_s`` of the first run of a scenario includes building it.

    Args:
        tasks: The runs.
        expected_code: The client's :func:`code_version`.  A worker whose code
            differs (a remote cluster with another checkout) records every run
            as an error instead of producing numbers under a wrong address.
        run_timeout_s: Wall-clock budget of each run (s), or None for none.
            With a budget each run runs in this thread's :class:`RunProcess`
            (building its scenario included); a run over the budget is stopped
            and recorded with status ``timeout``, and the chunk goes on.

    Returns:
        Per task: ``run_id``, ``status`` (``ok`` / ``error`` / ``timeout``), ``error``
        (``"Type: message"`` or None), ``metrics`` (numeric metrics of
        :func:`run_closed_loop`), ``timeseries`` (flattened columns or None),
        ``run_time_s`` (wall time of the run on the worker) and ``worker``.
    """
    if run_timeout_s is not None and not (run_timeout_s > 0 and run_timeout_s < float("inf")):
        raise ValueError(f"run_timeout_s must be > 0 s, got {run_timeout_s!r}")
    worker = f"{socket.gethostname()}:{os.getpid()}"
    here = code_version()
    local: dict[int, Any] = {}
    if expected_code is not None and here != expected_code:
        out: list[dict[str, Any]] = [
            {"run_id": task.run_id, "status": "error", "metrics": {}, "timeseries": None, "run_time_s": 0.0,
             "error": f"VersionMismatch: worker code version {here} differs from the client's {expected_code} "
                      f"(install the same vesselbot_ros on the workers; python {sys.version.split()[0]})"}
            for task in tasks]
    elif run_timeout_s is None:
        out = [_one(task, local) for task in tasks]
    else:
        out = _bounded(tasks, run_timeout_s)
    for rec in out:
        rec["worker"] = worker
    return out
