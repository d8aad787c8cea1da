"""Helpers for testing nodes over real topics: ours, and users' own.

* :func:`isolated_ros` leases a ROS domain and a log folder and yields an
  initialised rclpy ``Context`` on that domain (nothing else on the machine can
  join the graph).
* :class:`NodeProcess` starts a node (any command) as a subprocess in the same
  domain and stops it cleanly (SIGINT, then SIGKILL after a deadline).
* :func:`spin_until` spins an executor until a predicate holds or a deadline
  passes: every wait in a test is bounded.
* :func:`call_service` calls a service and spins until the answer: a
  request whose repetition changes nothing is sent again until answered (a
  loaded machine can drop a fresh client's first answer:
  :mod:`vesselbot_ros.nodes.calls`).
* :func:`fill_message` sets every field of a message to a distinct,
  non-default value, for round-trip tests.
* :func:`cli_on_a_full_disk` runs a ``vesselbot`` command in a child
  process whose files cannot grow (``RLIMIT_FSIZE``), from the start or once
  a given step has returned: a full disk, without filling one.
* :func:`cli_under_memory_limit` runs a ``vesselbot`` command in a child
  process whose address space is limited (``RLIMIT_AS``): a step too large
  for the machine fails there, not on the machine.

Example::

    with isolated_ros(tmp_path) as ros:
        node = rclpy.create_node("probe", context=ros.context)
        ...
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vesselbot_ros.launch.processes import ChildProcess
from vesselbot_ros.nodes.calls import Resend
from vesselbot_ros.ros_env import allocate_domain, apply_to_process, restore_process_env, ros_environment

__all__ = ["RosSandbox", "isolated_ros", "NodeProcess", "spin_until", "call_service", "spin_node", "fill_message",
           "cli_on_a_full_disk", "cli_under_memory_limit", "MEMORY_LIMIT_BYTES"]


@dataclass
class RosSandbox:
    """An isolated ROS environment: domain id, env for subprocesses, a Context."""

    domain_id: int
    env: dict[str, str]
    log_dir: Path
    context: Any


@contextlib.contextmanager
def isolated_ros(workdir: str | os.PathLike[str], domain_id: int | None = None) -> Iterator[RosSandbox]:
    """Lease a domain, point ROS logs into ``workdir`` and init an rclpy Context on it."""
    # deferred: rclpy; this module's process and Node.js helpers are used ROS-free (unit tests, the benches)
    import rclpy

    lease = allocate_domain(domain_id)
    log_dir = Path(workdir) / "ros_log"
    env = ros_environment(lease.domain_id, log_dir)
    saved = apply_to_process(env)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=lease.domain_id)
    try:
        yield RosSandbox(lease.domain_id, env, log_dir, context)
    finally:
        rclpy.try_shutdown(context=context)
        restore_process_env(saved)
        lease.release()


class NodeProcess(ChildProcess):
    """A node (or any command) run as a subprocess in a sandbox's domain.

    The project's one child wrapper (:class:`vesselbot_ros.launch.processes.ChildProcess`):
    the node dies with the test process, whatever ends it.

    Args:
        argv: The command; ``python`` as first element means this interpreter.
        env: Environment (use ``RosSandbox.env``).
        log_path: File receiving the process's stdout and stderr.
    """

    def __init__(self, argv: Sequence[str], env: dict[str, str], log_path: str | os.PathLike[str]) -> None:
        super().__init__(Path(str(argv[0])).name if argv else "node", argv, env, log_path)

    def __enter__(self) -> NodeProcess:
        return self


def spin_until(executor: Any, predicate: Callable[[], bool], timeout: float, step: float = 0.01) -> bool:
    """Spin ``executor`` until ``predicate()`` is true or ``timeout`` s pass; return predicate()."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        executor.spin_once(timeout_sec=step)
    return predicate()


def call_service(executor: Any, client: Any, request: Any, timeout: float, idempotent: bool = True) -> Any:
    """Call ``client`` with ``request`` and spin ``executor`` until the answer; return it (``None`` after ``timeout``).

    ``idempotent`` (the request may run twice: a query, a refused request, a
    state the server is in): sent again until one answer arrives.  Else sent
    once: make the client's first call an idempotent one
    (:func:`vesselbot_ros.nodes.calls.prime`), or its answer can be lost.
    """
    if idempotent:
        call = Resend.service(client, request)
        return call.result() if spin_until(executor, call.done, timeout) else None
    fut = client.call_async(request)
    if spin_until(executor, fut.done, timeout):
        return fut.result()
    client.remove_pending_request(fut)
    return None


def spin_node(node: Any) -> int:
    """Spin a peer node until SIGINT/SIGTERM, then destroy it and shut rclpy down; return 0.

    For small node scripts (test peers, stand-ins) whose ``main()`` is just
    "create the node, spin it, exit cleanly when stopped".
    """
    # deferred: rclpy (see isolated_ros)
    import rclpy
    from rclpy.executors import ExternalShutdownException

    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def fill_message(msg: Any, seed: int = 1) -> Any:
    """Set every field of ``msg`` (recursively) to a distinct non-default value; return msg."""
    counter = [seed]

    def nxt() -> int:
        counter[0] += 1
        return counter[0]

    def fill(m: Any) -> None:
        for name, typ in m.get_fields_and_field_types().items():
            cur = getattr(m, name)
            if hasattr(cur, "get_fields_and_field_types"):
                fill(cur)
            elif typ == "boolean":
                setattr(m, name, nxt() % 2 == 0 or True)
            elif typ in ("float", "double"):
                setattr(m, name, nxt() + 0.25)
            elif typ.startswith(("int", "uint")) or typ in ("octet", "byte", "char"):
                setattr(m, name, nxt() % 100)
            elif typ == "string":
                setattr(m, name, f"s{nxt()}")
            elif typ.startswith("double[") or typ.startswith("float["):
                setattr(m, name, [nxt() + 0.5 for _ in range(len(cur))])
            elif typ.startswith("sequence<"):
                continue  # leave unbounded sequences empty except where tests fill them
            else:
                raise TypeError(f"fill_message: unhandled field {name}: {typ}")

    fill(msg)
    return msg


#: Foxglove's own JavaScript readers and clients (``tools/js``, installed by ``tools/bootstrap.sh`` with npm ci).
JS_DIR = Path(__file__).resolve().parents[1] / "tools" / "js"


def run_node_script(script: str, *args: str, timeout: float = 120.0) -> Any:
    """Run ``node tools/js/SCRIPT ARGS`` (bounded) and return the JSON object it printed last.

    Raises:
        AssertionError: node failed, timed out or printed no JSON (its stderr is in the message).
    """
    node = shutil.which("node")
    assert node is not None, "node is not installed (tools/bootstrap.sh needs Node.js and npm)"
    assert (JS_DIR / "node_modules").is_dir(), f"{JS_DIR}/node_modules missing: run `make bootstrap`"
    proc = subprocess.run([node, str(JS_DIR / script), *args], cwd=JS_DIR, capture_output=True, text=True,
                          timeout=timeout)
    assert proc.returncode == 0, f"node {script} failed ({proc.returncode}): {proc.stderr[-2000:]}"
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    assert lines, f"node {script} printed no JSON: {proc.stdout[-2000:]} {proc.stderr[-2000:]}"
    return json.loads(lines[-1])


_FULL_DISK_CHILD = """
import resource, sys
def fill():
    resource.setrlimit(resource.RLIMIT_FSIZE, (0, 0))  # every write now fails (EFBIG), as on a full disk
module, _, name = sys.argv[1].partition(":")
if module:
    import importlib
    mod = importlib.import_module(module)
    step = getattr(mod, name)
    def step_then_fill(*a, **k):
        out = step(*a, **k)
        fill()
        return out
    setattr(mod, name, step_then_fill)
else:
    fill()
from vesselbot_ros.cli import main
sys.exit(main(sys.argv[2:]))
"""


def cli_on_a_full_disk(argv: Sequence[str], fill_after: str = "", cwd: str | os.PathLike[str] | None = None,
                       timeout: float = 600.0) -> subprocess.CompletedProcess[str]:
    """Run ``vesselbot ARGV`` in a child process on a "full disk": no file of it may grow past 0 bytes.

    ``RLIMIT_FSIZE`` = 0 makes every write fail with ``EFBIG`` (Python ignores
    ``SIGXFSZ``), while files can still be created, renamed and removed, as on
    a full disk; it holds for root too.  The disk may fill from the start
    (``fill_after=""``: the checks before the work see it) or once the step
    ``"module:function"`` has returned (e.g. the run, before the outputs are
    written): that name is looked up in ``module`` when called, so give the
    module that calls it.

    Returns:
        The finished process (text stdout and stderr).
    """
    return subprocess.run([sys.executable, "-c", _FULL_DISK_CHILD, fill_after, *argv], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout)


#: The address space :func:`cli_under_memory_limit` gives a command by default: 3 GiB.  A ``vesselbot`` command
#: reserves 0.5-0.7 GiB of it (numba's and llvmlite's, vtk's and gmsh's libraries; measured ``VmPeak`` of
#: ``vessels import`` and of a refused ``simulate``), so a step of a few GiB cannot start.
MEMORY_LIMIT_BYTES = 3 * 2**30


def _limit_address_space(limit: int) -> Callable[[], None]:
    def apply() -> None:
        import resource  # deferred: POSIX only, and only the child needs it

        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    return apply


def cli_under_memory_limit(argv: Sequence[str], limit_bytes: int = MEMORY_LIMIT_BYTES,
                           cwd: str | os.PathLike[str] | None = None,
                           timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    """Run ``vesselbot ARGV`` in a child process whose address space is at most ``limit_bytes`` (``RLIMIT_AS``).

    An allocation past the limit fails in the child (``MemoryError``, or a library's own error) instead of
    taking the machine's memory; a command that estimates its steps first refuses them in one line.

    Returns:
        The finished process (text stdout and stderr).
    """
    code = "import sys\nfrom vesselbot_ros.cli import main\nsys.exit(main(sys.argv[1:]))\n"
    return subprocess.run([sys.executable, "-c", code, *argv], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, preexec_fn=_limit_address_space(limit_bytes))
