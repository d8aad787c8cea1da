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


def test_the_input_check_takes_y_as_a_coordinate_in_a_3d_tree_and_as_zero_in_a_planar_scenario() -> None:
    """VesselbotNode.check with its scenario's one switch: a planar node rejects any y; a 3-D tree's node checks
    (x, y, z) against the tree's meshed wall, so a y that leaves the lumen is rejected and one inside is not."""
    pytest.importorskip("rclpy")
    from types import SimpleNamespace

    from vesselbot_ros.nodes.base import VesselbotNode
    from vesselbot_ros.nodes.graph_params import GraphParams
    from vesselbot_ros.sim.scenario import load_scenario

    def node(config: str) -> SimpleNamespace:
        s = load_scenario(config)
        n = SimpleNamespace(scenario=s, dims=s.dims, graph=GraphParams(), lockstep=True, rejected=[])
        n.reject = lambda key, reason, detail="": n.rejected.append(reason)
        n._network_clearance = lambda point: VesselbotNode._network_clearance(n, point)
        return n

    tree = node("config/paper_iiic_network_upper_3d.yaml")
    assert tree.dims == 3
    ok = VesselbotNode.check(tree, "truth", values=(1e-3, 2e-4, 1e-3), y_values=(2e-4,), x_position=1e-3,
                             y_position=2e-4, z_position=1e-3)
    assert ok and tree.rejected == []
    # 12 mm across a 3 mm lumen: 10.5 mm outside its wall, beyond the 5 mm margin (GraphParams.position_margin_m)
    out = VesselbotNode.check(tree, "truth", values=(1e-3, 12e-3, 1e-3), y_values=(12e-3,), x_position=1e-3,
                              y_position=12e-3, z_position=1e-3)
    assert not out and tree.rejected == ["outside_vessel"]
    planar = node("config/paper_iiic_network_upper.yaml")
    assert planar.dims == 2
    assert not VesselbotNode.check(planar, "truth", values=(1e-3, 2e-4, 1e-3), y_values=(2e-4,), x_position=1e-3,
                                   z_position=1e-3)
    assert planar.rejected == ["nonzero_y"]
