"""The node base: the intra-process bus (composed lockstep graphs: order, fairness, threads, which topics), publishing."""

from __future__ import annotations

import threading
import time
from typing import Any

import pytest

from vesselbot_ros.graph_spec import ROLES, TOPICS
from vesselbot_ros.nodes.base import IntraProcess


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


def test_a_volatile_message_no_reader_can_get_is_counted_but_not_serialized(monkeypatch) -> None:
    """Processes mode: a per-tick topic with no matched reader costs no serialization; latched ones always go."""
    rclpy = pytest.importorskip("rclpy")
    from rosgraph_msgs.msg import Clock

    from vesselbot_ros.graph_spec import topic
    from vesselbot_ros.nodes import conversions as cv
    from vesselbot_ros.nodes.plant_node import PlantNode

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = PlantNode(context=ctx)
    peer = rclpy.create_node("clock_reader", context=ctx)
    try:
        sent: dict[str, int] = {"clock": 0, "coil_stall": 0}
        for key in sent:
            monkeypatch.setattr(node._pubs[key], "publish", lambda _m, key=key: sent.__setitem__(key, sent[key] + 1))
        clock = topic("clock").name
        node.publish("clock", cv.clock_msg(0.0))
        node.publish("coil_stall", cv.header(0.0))
        assert sent == {"clock": 0, "coil_stall": 1}  # the latched stall request goes out for a late joiner
        assert node._published[clock] == 1  # counted all the same
        peer.create_subscription(Clock, clock, lambda _m: None, 10)
        deadline = time.monotonic() + 20.0
        while node._pubs["clock"].get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        node.publish("clock", cv.clock_msg(0.001))
        assert sent["clock"] == 1 and node._published[clock] == 2
    finally:
        peer.destroy_node()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
