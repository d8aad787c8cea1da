"""Start, watch and stop the graph's processes.

:class:`Supervisor` owns every child of a run (the recorder and the node
processes, each a :class:`~vesselbot_ros.launch.processes.ChildProcess`): the
children die with the launcher whatever kills it (parent-death signal) and
inherit the domain lease, which therefore stays held until the last one is
gone.  It names a dead node (:class:`NodeDied`), lets the coil driver's
watchdog bring the gradient to zero when a node upstream of it dies
(:meth:`Supervisor.safe_stop`), and stops the nodes first and the recorder last.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from vesselbot_ros.errors import RunError
from vesselbot_ros.graph_spec import NODE_NAMES, role
from vesselbot_ros.launch.processes import ChildProcess

__all__ = ["NodeDied", "Supervisor", "wait_for"]


class NodeDied(RunError):
    """A node process exited before the run finished."""


class Supervisor:
    """The processes of one run.

    Args:
        env: Environment of every child.
        log_dir: Folder of the children's logs.
        hold_fds: Descriptors every child inherits (the domain lease).
    """

    def __init__(self, env: dict[str, str], log_dir: Path, hold_fds: Sequence[int] = ()) -> None:
        self.env = env
        self.log_dir = log_dir
        self.hold_fds = tuple(hold_fds)
        self.recorder: ChildProcess | None = None
        self.nodes: list[ChildProcess] = []
        self.roles_of: dict[str, list[str]] = {}

    def start_recorder(self, argv: Sequence[str]) -> ChildProcess:
        """Start the recorder."""
        self.recorder = ChildProcess("recorder", argv, self.env, self.log_dir / "recorder.log", self.hold_fds)
        return self.recorder

    def start_nodes(self, roles: Sequence[str], ros_args: Sequence[str], single_process: bool,
                    intra_process: bool = True) -> None:
        """Start ``roles``: one process each, or one composed process (intra-process deliveries unless told not to)."""
        if single_process:
            argv = [sys.executable, "-m", "vesselbot_ros.launch.composed", "--roles", ",".join(roles),
                    *([] if intra_process else ["--no-intra-process"]), *ros_args]
            self.nodes.append(ChildProcess("composed", argv, self.env, self.log_dir / "composed.log", self.hold_fds))
            self.roles_of["composed"] = list(roles)
            return
        for r in roles:
            argv = [sys.executable, "-m", role(r).module, *ros_args]
            self.nodes.append(ChildProcess(r, argv, self.env, self.log_dir / f"{r}.log", self.hold_fds))
            self.roles_of[r] = [r]

    @property
    def all(self) -> list[ChildProcess]:
        """Every child: nodes and recorder."""
        return self.nodes + ([self.recorder] if self.recorder is not None else [])

    def check_alive(self, procs: Sequence[ChildProcess] | None = None) -> None:
        """Raise :class:`NodeDied` naming the first child that exited."""
        for p in self.all if procs is None else procs:
            code = p.poll()
            if code is not None:
                who = p.label if self.roles_of.get(p.label, [p.label]) == [p.label] else \
                    f"{p.label} ({', '.join(self.roles_of[p.label])})"
                raise NodeDied(f"node {who} died (exit code {code}) before the run finished; its last output:\n"
                               f"{p.tail()}")

    def dead(self) -> ChildProcess | None:
        """The first child that exited, if any."""
        return next((p for p in self.all if p.poll() is not None), None)

    def safe_stop(self, died: NodeDied, dead: ChildProcess, mon: Any, timeout: float, dt: float) -> None:
        """Keep the graph running until the coil driver's watchdog brought the gradient to zero, then raise.

        Raises:
            NodeDied: always; the message names the dead node and says where the coil output ended.
        """
        k_death = mon.max_tick
        mon.watch_coil()  # the coil state from now on: where the watchdog's ramp ends
        print(f"vesselbot run: node {dead.label} died (exit code {dead.poll()}) at tick {k_death} "
              f"(t = {k_death * dt:.3f} s); letting the coil driver's watchdog ramp the gradient to zero",
              file=sys.stderr, flush=True)
        others = [p for p in self.all if p is not dead]
        deadline = time.monotonic() + timeout
        plant_name = NODE_NAMES["plant"]
        while time.monotonic() < deadline:
            mon.spin(0.05)
            self.check_alive(others)
            lc = mon.last_coil
            if lc is not None and lc[0] > k_death and lc[2] and lc[1] == (0.0, 0.0, 0.0):
                raise NodeDied(f"{died}\ncoil output ramped to zero by the driver's watchdog at tick {lc[0]} "
                               f"(t = {lc[0] * dt:.3f} s)") from None
            if mon.diag.get(plant_name, {}).get("finished") == "true":
                raise NodeDied(f"{died}\nthe run reached its end before the coil output was zero") from None
        raise NodeDied(f"{died}\nthe coil output did not reach zero within {timeout:.0f} s (wall)") from None

    def stop_nodes(self, timeout: float = 10.0) -> None:
        """SIGINT every node process, wait ``timeout`` s in all (not per node), then SIGKILL those still running."""
        for p in self.nodes:
            p.signal(signal.SIGINT)
        deadline = time.monotonic() + timeout
        for p in self.nodes:
            p.wait(max(0.0, deadline - time.monotonic()))
            p.close()

    def stop_recorder(self, timeout: float = 30.0) -> int | None:
        """SIGINT the recorder (it finalises the bag); its exit code."""
        if self.recorder is None:
            return None
        self.recorder.signal(signal.SIGINT)
        code = self.recorder.wait(timeout)
        self.recorder.close()
        return code

    def kill_all(self) -> None:
        """Last resort: SIGKILL every child still running and reap it."""
        for p in self.all:
            if p.poll() is None:
                p.signal(signal.SIGKILL)
            with contextlib.suppress(Exception):
                p.wait(5.0)
            p.close()


def wait_for(pred: Callable[[], bool], timeout: float, mon: Any, sup: Supervisor | None, what: str,
             procs: Sequence[ChildProcess] | None = None) -> None:
    """Spin ``mon`` until ``pred()``; raise NodeDied if a child exits, RunError after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not pred():
        if sup is not None:
            sup.check_alive(procs)
        if time.monotonic() > deadline:
            raise RunError(f"timed out after {timeout:.0f} s waiting for {what}")
        mon.spin(0.05)
