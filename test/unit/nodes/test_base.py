"""The node base: publishing (a volatile message no reader can get is counted, not serialized)."""

from __future__ import annotations

import time

import pytest


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
