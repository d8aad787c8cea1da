"""The intra-process bus of composed graphs: order, fairness, threads, which topics."""

from __future__ import annotations

import threading
from typing import Any

from vesselbot_ros.graph_spec import ROLES, TOPICS
from vesselbot_ros.nodes.intra_process import IntraProcess, intra_process, use_intra_process


class FakeExecutor:
    """Collects the tasks the bus schedules; ``run()`` runs them one turn at a time, as an executor does."""

    def __init__(self) -> None:
        self.tasks: list[Any] = []
        self.turns = 0

    def create_task(self, fn: Any) -> None:
        self.tasks.append(fn)

    def run(self) -> None:
        while self.tasks:
            self.turns += 1
            self.tasks.pop(0)()


def _bus(roles: tuple[str, ...] = tuple(r.name for r in ROLES)) -> tuple[IntraProcess, FakeExecutor]:
    bus = IntraProcess(roles)
    ex = FakeExecutor()
    bus.attach(ex)
    return bus, ex


def test_carries_only_topics_of_co_located_publishers_and_never_latched_ones() -> None:
    bus = IntraProcess(("plant", "imager"))
    for t in TOPICS:
        assert bus.carries(t.key) == (t.publisher in ("plant", "imager") and t.qos != "reliable_latched")
    assert not bus.carries("vessel_markers")  # the plant's latched markers stay on DDS for late joiners


def test_deliveries_are_first_in_first_out_and_breadth_first() -> None:
    """A chain of relays: what a callback publishes is delivered after what was queued before it."""
    bus, ex = _bus()
    log: list[tuple[str, int]] = []

    def relay(name: str, out: str | None) -> Any:
        def cb(msg: int) -> None:
            log.append((name, msg))
            if out is not None:
                bus.post(out, msg)
        return cb

    bus.subscribe("truth", relay("imager", "measurement"))
    bus.subscribe("clock", relay("reference", "reference"))
    bus.subscribe("measurement", relay("observer", None))
    bus.subscribe("reference", relay("controller", None))
    bus.post("clock", 1)
    bus.post("truth", 1)
    ex.run()
    assert log == [("reference", 1), ("imager", 1), ("controller", 1), ("observer", 1)]


def test_every_subscriber_gets_the_same_object_once() -> None:
    bus, ex = _bus()
    got: list[Any] = []
    bus.subscribe("coil_applied", got.append)
    bus.subscribe("coil_applied", got.append)
    msg = object()
    bus.post("coil_applied", msg)
    bus.post("estimate", object())  # no co-located subscriber: dropped (DDS carries it, if anyone listens)
    ex.run()
    assert got == [msg, msg]
    assert bus.subscribers("coil_applied") == 2 and bus.subscribers("estimate") == 0


def test_an_endless_loop_yields_to_the_executor_every_budget() -> None:
    """A lockstep loop never ends its drain by itself: the executor must get turns (timers, services)."""
    bus, ex = _bus()
    n = {"k": 0}

    def plant(_msg: Any) -> None:
        n["k"] += 1
        if n["k"] < 10 * IntraProcess.BUDGET:
            bus.post("coil_applied", n["k"])

    bus.subscribe("coil_applied", plant)
    bus.post("coil_applied", 0)
    ex.run()
    assert n["k"] == 10 * IntraProcess.BUDGET
    assert ex.turns == 10  # one task per BUDGET deliveries, none wasted


def test_posts_before_the_executor_is_attached_run_once_it_is() -> None:
    bus = IntraProcess(("plant",))
    got: list[int] = []
    bus.subscribe("truth", got.append)
    bus.post("truth", 7)
    assert got == []
    ex = FakeExecutor()
    bus.attach(ex)
    ex.run()
    assert got == [7]


def test_posts_from_another_thread_are_all_delivered_on_the_executor() -> None:
    bus, ex = _bus()
    got: list[int] = []
    bus.subscribe("truth", got.append)

    def poster() -> None:
        for i in range(2000):
            bus.post("truth", i)

    th = threading.Thread(target=poster)
    th.start()
    while th.is_alive() or ex.tasks:
        ex.run()
    th.join()
    ex.run()
    assert got == list(range(2000))


def test_use_intra_process_sets_the_bus_nodes_built_from_now_on_take() -> None:
    try:
        bus = use_intra_process(("plant", "imager"))
        assert intra_process() is bus and bus is not None and bus.roles == {"plant", "imager"}
    finally:
        assert use_intra_process(None) is None
    assert intra_process() is None
