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


class _Mon:
    """The launcher's monitor as last_output reads it: diagnostics per node, and when each arrived (wall)."""

    def __init__(self, diag, wall):
        self.diag, self.diag_wall, self.spins = diag, wall, 0

    def spin(self, dt: float) -> None:
        self.spins += 1
        time.sleep(dt)


def test_a_dead_nodes_last_output_is_the_tick_its_readers_last_got_not_a_progress_sample():
    """The controller died after its command of tick 499: the coil driver's report sent after the death says so
    (the launcher's message used to name the plant's last progress sample, e.g. t = 0.326 s)."""
    from vesselbot_ros.launch.supervision import last_output

    now = time.monotonic()
    mon = _Mon({"vesselbot_coil_driver": {"last_tick:/vesselbot/gradient_command": "499"},
                "vesselbot_plant": {"tick": "326"}},
               {"vesselbot_coil_driver": now + 0.1, "vesselbot_plant": now + 0.1})
    line = last_output(mon, ["/vesselbot/gradient_command"], now, 1e-3, ["vesselbot_controller"])
    assert line == ("its last message: /vesselbot/gradient_command of tick 499 (t = 0.499 s), "
                    "as vesselbot_coil_driver received it")
    assert mon.spins == 0


def test_without_a_fresh_report_the_last_output_is_named_a_bound_after_a_bounded_wait():
    from vesselbot_ros.launch.supervision import last_output

    now = time.monotonic()
    mon = _Mon({"vesselbot_coil_driver": {"last_tick:/vesselbot/gradient_command": "120"}},
               {"vesselbot_coil_driver": now - 5.0})
    t0 = time.monotonic()
    line = last_output(mon, ["/vesselbot/gradient_command"], now, 1e-3, wait_s=0.2)
    assert time.monotonic() - t0 < 0.2 + 5.0  # bounded (the loaded machine: generous)
    assert "of tick 120 (t = 0.120 s) at least" in line and mon.spins >= 1
    assert "unknown" in last_output(_Mon({}, {}), ["/vesselbot/estimate"], now, 1e-3, wait_s=0.0)
