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
from vesselbot_ros.graph_spec import NODE_NAMES, role, topic
from vesselbot_ros.launch.processes import ChildProcess

__all__ = ["NodeDied", "Supervisor", "wait_for", "last_output", "LAST_OUTPUT_WAIT_S"]


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
        k_death = mon.max_tick  # a progress sample (diagnostics, once a second): not when the node died
        t_found = time.monotonic()
        mon.watch_coil()  # the coil state from now on: where the watchdog's ramp ends
        print(f"vesselbot run: node {dead.label} died (exit code {dead.poll()}); letting the coil driver's watchdog "
              f"ramp the gradient to zero", file=sys.stderr, flush=True)
        others = [p for p in self.all if p is not dead]
        outputs = [topic(k).name for r in self.roles_of.get(dead.label, [dead.label]) for k in role(r).outputs]
        deadline = time.monotonic() + timeout
        plant_name = NODE_NAMES["plant"]
        end = f"the coil output did not reach zero within {timeout:.0f} s (wall)"
        while time.monotonic() < deadline:
            mon.spin(0.05)
            self.check_alive(others)
            lc = mon.last_coil
            if lc is not None and lc[0] > k_death and lc[2] and lc[1] == (0.0, 0.0, 0.0):
                end = f"coil output ramped to zero by the driver's watchdog at tick {lc[0]} (t = {lc[0] * dt:.3f} s)"
                break
            if mon.diag.get(plant_name, {}).get("finished") == "true":
                end = "the run reached its end before the coil output was zero"
                break
        last = last_output(mon, outputs, t_found, dt, [NODE_NAMES[r] for r in self.roles_of.get(dead.label, [])])
        raise NodeDied(f"{died}\n{last}\n{end}") from None

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


#: Wall time (s) :func:`last_output` waits for its readers' diagnostics sent after the death was found.
LAST_OUTPUT_WAIT_S = 2.5


def last_output(mon: Any, outputs: Sequence[str], t_found: float, dt: float, dead_names: Sequence[str] = (),
                wait_s: float = LAST_OUTPUT_WAIT_S) -> str:
    """The sim time of a dead node's last output, as the living nodes that read it saw it (one line).

    Each node reports the latest tick of every input that reached it (``last_tick:<topic>``, diagnostics
    once a second): a report sent after the death was found (``t_found``, wall) holds the node's last
    message.  Waits at most ``wait_s`` (wall) for one; else says what is known, naming it a bound.
    """
    deadline = time.monotonic() + wait_s
    while True:
        best: tuple[int, str, str] | None = None
        fresh = False
        for name, d in mon.diag.items():
            if name in dead_names:
                continue
            for t in outputs:
                v = d.get(f"last_tick:{t}")
                if v is None:
                    continue
                fresh = fresh or mon.diag_wall.get(name, 0.0) > t_found
                with contextlib.suppress(ValueError):
                    if best is None or int(v) > best[0]:
                        best = (int(v), t, name)
        if fresh or time.monotonic() >= deadline:
            break
        mon.spin(0.05)
    if best is None:
        return "no living node reported an output of it (its last output's time is unknown)"
    k, t, name = best
    when = "" if fresh else " at least (no report of its readers since it died came in time)"
    return f"its last message: {t} of tick {k} (t = {k * dt:.3f} s){when}, as {name} received it"


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
