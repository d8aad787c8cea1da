"""The plant node's real-time schedule: tick 0 goes out on the schedule every later tick follows."""

from __future__ import annotations

import time

import pytest

rclpy = pytest.importorskip("rclpy")


def _plant(**graph: object):
    """A plant node in a context of its own, with ``graph.<name>`` parameters; destroyed after the test."""
    from rclpy.parameter import Parameter

    from vesselbot_ros.nodes.plant_node import PlantNode

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = PlantNode(context=ctx, parameter_overrides=[Parameter(f"graph.{k}", value=v) for k, v in graph.items()])
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)


@pytest.fixture()
def realtime_plant():
    yield from _plant(mode="realtime", real_time_factor=0.1)


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
    # tick 0 goes out when it is due, not after its slow emit: the schedule starts before that emit, and less than
    # the emit's own 50 ms before it (a loaded machine may preempt between the two, so no tighter wall-clock bound)
    assert seen["emitted_at"] - seen["wall_start"] < 0.05
    # the schedule the later ticks follow is the one tick 0 went out on
    assert node._wall_start == seen["wall_start"]
    # after a 50 ms emit at 0.1x real time (10 ms per tick), tick 0 is late but no later tick is scheduled later
    before = int((time.monotonic() - node._wall_start) * 0.1 / node.dt)
    node._realtime_tick()
    after = int((time.monotonic() - node._wall_start) * 0.1 / node.dt)
    assert before <= node.k <= after


def test_average_factor_is_sim_time_over_the_wall_time_played(realtime_plant):
    """The plant's figures of the run's average real-time factor: first to last tick published, pauses left out
    (a client that paused a real-time run did not make the machine slower)."""
    node = realtime_plant
    node._start()
    time.sleep(0.035)
    node._realtime_tick()  # 0.1x: a tick per 10 ms of wall, so ticks 1..3 are due
    assert node.pause() == ""
    time.sleep(0.3)
    assert node.play() == ""
    time.sleep(0.025)
    node._realtime_tick()
    d = node.diagnostic_values()
    wall, sim = float(d["run_wall_s"]), float(d["run_sim_s"])
    assert sim == pytest.approx(node.tick_now * node.dt, abs=1e-12) and node.tick_now >= 4
    assert node._paused_wall_s >= 0.3
    assert wall == pytest.approx(node._last_emit_wall - node._first_emit_wall - node._paused_wall_s, abs=1e-12)
    assert float(d["real_time_factor_held"]) == pytest.approx(sim / wall, rel=1e-12)
    assert float(d["real_time_factor_held"]) <= 0.1 * (1 + 1e-3)  # never ahead of the schedule


@pytest.fixture()
def lockstep_plant():
    yield from _plant(stall_timeout_s=0.2)


def test_a_late_tick_is_asked_for_once_then_after_the_grace_and_a_held_tick_never(lockstep_plant, monkeypatch):
    """Lockstep watchdog, the plant's half: coil/stall for the tick in flight once its coil/applied is
    stall_timeout_s late (once per tick); while commands stay lost, after LOST_GRACE_S; a tick answered
    in time ends that; a tick held at the gate (paused) is never asked for."""
    from vesselbot_ros.nodes import conversions as cv
    from vesselbot_ros.nodes.plant_node import LOST_GRACE_S

    node = lockstep_plant
    asked: list[int] = []
    publish = node.publish

    def spy(key, msg):
        if key == "coil_stall":
            asked.append(cv.tick_of_ns(cv.ns_of_stamp(msg.stamp), node.dt)[0])
            assert msg.frame_id == "vessel"
        publish(key, msg)

    monkeypatch.setattr(node, "publish", spy)
    node._start()  # tick 0 in flight
    node._stall_check()
    assert asked == []  # not late yet
    node._last_emit_wall -= 0.21
    node._stall_check()
    node._stall_check()
    assert asked == [0]  # once per tick
    node._on_applied(cv.gradient_flat(0.0, (0.0, 0.0)))  # the driver's watchdog answer to tick 0
    assert node.k == 1
    node._last_emit_wall -= LOST_GRACE_S + 1e-3  # commands lost: the grace, not the timeout
    node._stall_check()
    assert asked == [0, 1]
    node._on_applied(cv.gradient_flat(node.dt, (0.0, 0.0)))  # answered by the watchdog: still lost
    node._on_applied(cv.gradient_flat(2 * node.dt, (0.0, 0.0)))  # tick 2 answered in time: commands are back
    node._last_emit_wall -= LOST_GRACE_S + 1e-3
    node._stall_check()
    assert asked == [0, 1]  # tick 3 waits the full timeout again
    assert node.pause() == ""
    node._on_applied(cv.gradient_flat(3 * node.dt, (0.0, 0.0)))  # tick 4 integrated, held at the gate
    node._last_emit_wall -= 10.0
    node._stall_check()
    assert asked == [0, 1] and node.k == 4 and node.idle


def test_a_network_with_y_gets_its_wall_mesh_and_a_planar_one_its_meshed_wall_segments():
    """The vessel markers the plant publishes once: a 3-D tree (branches with ``y_m``) as a triangle mesh."""
    import numpy as np
    from visualization_msgs.msg import Marker

    from vesselbot_ros.graph_spec import NETWORK_WALL_NS
    from vesselbot_ros.nodes import conversions as cv
    from vesselbot_ros.nodes.plant_node import network_scene_markers
    from vesselbot_ros.physics.params import BloodParams
    from vesselbot_ros.vessels.cfd import network_wall
    from vesselbot_ros.vessels.network import load_network
    from vesselbot_ros.vessels.tube_geometry import NetworkGeometry

    blood, r = BloodParams(), 2.5e-4
    planar = load_network("paper_iiic_artery")
    assert not planar.is_3d
    assert network_scene_markers(planar, blood, r) == cv.network_markers(NetworkGeometry(planar),
                                                                          network_wall(planar, blood).segments, r)
    # the same tree given with y_m (all 0): 3-D tubes, in the plane y = 0 but with a wall all round
    tree = load_network("paper_iiic_artery_3d")
    assert tree.is_3d and tree.is_planar
    wall = network_scene_markers(tree, blood, r).markers[0]
    assert (wall.ns, wall.type) == (NETWORK_WALL_NS, Marker.TRIANGLE_LIST)
    y = np.array([p.y for p in wall.points])
    assert y.min() == pytest.approx(-1.5e-3, rel=1e-6) and y.max() == pytest.approx(1.5e-3, rel=1e-6)  # the trunk
    # a tree that leaves the plane: the wall its plant computes with, centrelines with y
    from vesselbot_ros.vessels.tree_field import wall_mesh

    net = load_network("carotid_bifurcation_3d")
    carotid = network_scene_markers(net, blood, r).markers
    v, t = wall_mesh(net, blood)
    assert carotid[0].type == Marker.TRIANGLE_LIST
    assert np.array_equal([[p.x, p.y, p.z] for p in carotid[0].points], v[t].reshape(-1, 3))
    assert min(p.y for m in carotid[1:] for p in m.points) < -3e-3
