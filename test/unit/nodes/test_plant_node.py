"""The plant node's real-time schedule: tick 0 goes out on the schedule every later tick follows."""

from __future__ import annotations

import time

import pytest

rclpy = pytest.importorskip("rclpy")


@pytest.fixture()
def realtime_plant():
    from rclpy.parameter import Parameter

    from vesselbot_ros.nodes.plant_node import PlantNode

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = PlantNode(context=ctx, parameter_overrides=[Parameter("graph.mode", Parameter.Type.STRING, "realtime"),
                                                       Parameter("graph.real_time_factor", Parameter.Type.DOUBLE, 0.1)])
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)


def test_tick_zero_is_due_when_the_wall_schedule_starts(realtime_plant, monkeypatch):
    """The nodes anchor their periods on tick 0's arrival: tick 0 must be emitted at the schedule's start.

    The schedule used to start after tick 0's (slow, first) emit, which made every later tick look about
    one period late to every node, so any real-time factor failed.
    """
    node = realtime_plant
    seen = {}
    emit = node._emit

    def spy() -> None:
        seen["wall_start"] = getattr(node, "_wall_start", None)
        seen["emitted_at"] = time.monotonic()
        time.sleep(0.05)  # a slow first emit (first messages, first force evaluation)
        emit()

    monkeypatch.setattr(node, "_emit", spy)
    node._start()
    assert seen["wall_start"] is not None and seen["wall_start"] <= seen["emitted_at"]
    assert seen["emitted_at"] - seen["wall_start"] < 0.01  # tick 0 goes out when it is due, not a period later
    # the schedule the later ticks follow is the one tick 0 went out on
    assert node._wall_start == seen["wall_start"]
    # after a 50 ms emit at 0.1x real time (10 ms per tick), tick 0 is late but no later tick is scheduled later
    before = int((time.monotonic() - node._wall_start) * 0.1 / node.dt)
    node._realtime_tick()
    after = int((time.monotonic() - node._wall_start) * 0.1 / node.dt)
    assert before <= node.k <= after
