"""The run's process supervisor (vesselbot_ros.launch.supervision): stopping the node processes."""

from __future__ import annotations

import time
from pathlib import Path

from vesselbot_ros.launch.supervision import Supervisor


class _HungNode:
    """A node process that ignores SIGINT: ``wait`` lasts its whole timeout, then the process is killed."""

    def __init__(self) -> None:
        self.signals: list[int] = []
        self.timeouts: list[float] = []
        self.closed = False

    def signal(self, sig: int) -> None:
        self.signals.append(sig)

    def wait(self, timeout: float) -> int:
        self.timeouts.append(timeout)
        time.sleep(timeout)
        return -9  # SIGKILLed

    def close(self) -> None:
        self.closed = True


def test_stop_nodes_gives_hung_nodes_one_grace_in_all_not_one_each(tmp_path: Path) -> None:
    """Four nodes hung in their shutdown: each gets SIGINT, and the waits share one deadline (what a user's Ctrl-C
    waits is the grace, not the grace times the nodes); every node is then killed and its log closed."""
    sup = Supervisor({}, tmp_path)
    hung = [_HungNode() for _ in range(4)]
    sup.nodes = hung  # type: ignore[assignment]  # stands in for ChildProcess: signal, wait, close
    sup.stop_nodes(0.5)
    assert all(len(h.signals) == 1 and h.closed for h in hung)
    waits = [t for h in hung for t in h.timeouts]
    assert len(waits) == 4 and sum(waits) <= 0.5  # one grace in all (per node: 2 s)
