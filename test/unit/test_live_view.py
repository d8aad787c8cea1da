"""live_view: the derived scene and errors, and the Foxglove layout only names channels the live view serves."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from vesselbot_ros.graph_spec import TOPICS, VIEW_CHANNELS, topic
from vesselbot_ros.live_view import ARROW_AT_LIMIT_M, scene_numbers

REPO = Path(__file__).resolve().parents[2]


def test_scene_numbers_take_the_radius_from_the_gap_and_errors_as_norms():
    d, z, r = 3e-3, 2e-4, 2.5e-4
    gap = 0.5 * d - z - r
    sn = scene_numbers(0.5, (1e-3, z), d, gap, z + 0.5 * d - r, (0.03, -0.04), 0.08, (1e-3 + 3e-6, z + 4e-6),
                       (1e-3 - 6e-5, z + 8e-5))
    assert sn.robot_radius_m == pytest.approx(r, abs=1e-18)
    assert sn.wall_z_m == 0.5 * d
    assert sn.estimation_error_m == pytest.approx(5e-6, rel=1e-9)
    assert sn.tracking_error_m == pytest.approx(1e-4, rel=1e-9)
    none = scene_numbers(0.0, (0.0, 0.0), d, 0.5 * d - r, 0.5 * d - r, (0.0, 0.0), 0.08, None, None)
    assert none.tracking_error_m is None and none.estimation_error_m is None


def test_markers_draw_pulsing_walls_robot_estimate_gradient_arrow_and_path():
    pytest.importorskip("rclpy")
    from geometry_msgs.msg import Point
    from std_msgs.msg import Header
    from visualization_msgs.msg import Marker

    from vesselbot_ros.live_view import DerivedView

    view = DerivedView(lambda *a: None)
    view._path_points = [Point(x=0.0, z=0.0), Point(x=0.01, z=1e-4)]
    sn = scene_numbers(0.1, (2e-3, 1e-4), 3.1e-3, 0.5 * 3.1e-3 - 1e-4 - 2.5e-4, 1e-4 + 0.5 * 3.1e-3 - 2.5e-4, (0.08, 0.0), 0.08,
                       (2e-3, 1e-4), None)
    ms = {m.ns: m for m in view.markers(sn, Header()).markers}
    assert set(ms) == {"upper_wall", "lower_wall", "robot", "estimate", "gradient", "reference_path"}
    assert ms["upper_wall"].pose.position.z > 0.5 * 3.1e-3 > -ms["lower_wall"].pose.position.z - 1e-3
    assert ms["upper_wall"].pose.position.z - ms["upper_wall"].scale.z / 2 == pytest.approx(0.5 * 3.1e-3)
    assert ms["robot"].type == Marker.SPHERE and ms["robot"].scale.x == pytest.approx(5e-4)
    a, b = ms["gradient"].points
    assert math.hypot(b.x - a.x, b.z - a.z) == pytest.approx(ARROW_AT_LIMIT_M)  # |G| at the limit: 2 mm
    assert all(m.header.frame_id == "vessel" for m in ms.values())


def test_layout_names_only_channels_the_live_view_serves():
    layout = json.loads((REPO / "config" / "foxglove" / "vesselbot.json").read_text())
    served = {t.name for t in TOPICS} | {v.name for v in VIEW_CHANNELS}
    named = set()
    for cfg in layout["configById"].values():
        named |= set(cfg.get("topics", {}))
        named |= {p["value"].split(".", 1)[0] for p in cfg.get("paths", [])}
        if "topicPath" in cfg:
            named.add(cfg["topicPath"].split(".", 1)[0])
        if "imageMode" in cfg:
            named.add(cfg["imageMode"]["imageTopic"])
    assert named and named <= served, named - served
    assert {v.name for v in VIEW_CHANNELS} <= named  # every derived channel has a panel
    # the MR frames' magnitude (imager.kind mr_images) in an Image panel
    assert layout["configById"]["Image!mr"]["imageMode"]["imageTopic"] == topic("mr_image").name
    assert "Image!mr" in json.dumps(layout["layout"])


def test_the_static_path_is_built_once_and_rides_along_at_most_once_a_second():
    pytest.importorskip("rclpy")
    from geometry_msgs.msg import Point
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Header
    from visualization_msgs.msg import MarkerArray

    from vesselbot_ros.live_view import DerivedView

    view = DerivedView(lambda *a: None)
    view._path_points = [Point(x=1e-5 * i, z=0.0) for i in range(500)]
    sn = scene_numbers(0.1, (2e-3, 1e-4), 3.1e-3, 0.5 * 3.1e-3 - 1e-4 - 2.5e-4, 1e-4 + 0.5 * 3.1e-3 - 2.5e-4, (0.08, 0.0), 0.08, None, None)
    first = [m for m in view.markers(sn, Header()).markers if m.ns == "reference_path"]
    again = [m for m in view.markers(sn, Header()).markers if m.ns == "reference_path"]
    assert len(first[0].points) == 500 and again[0] is first[0]  # not rebuilt
    assert not [m for m in view.markers(sn, Header(), with_path=False).markers if m.ns == "reference_path"]
    # emit(): a view update every 1/20 s, the path in one of them per second
    sent = []
    view._send = lambda key, data, t: sent.append(deserialize_message(data, MarkerArray)) if key == "view_markers" else None
    view._path_wall = -1e9
    from rclpy.serialization import serialize_message

    from vesselbot_ros.nodes import conversions as cv

    view._last_wall = math.inf  # offer() emits nothing by itself here
    view.offer(topic("truth").name, serialize_message(cv.plant_state_msg(
        5, 0.005, (2e-3, 1e-4), (0.0, 0.0), (0.0, 0.0), 3.1e-3, 1e-3, 1e-3, -1e-3, False, 0, (0.0, 0.0),
        [(0.0, 0.0)] * 8)), 5)
    for _ in range(3):
        view.emit(5)
    with_path = [any(m.ns == "reference_path" for m in arr.markers) for arr in sent]
    assert with_path == [True, False, False]


def _truth(k: int, x: float) -> bytes:
    from rclpy.serialization import serialize_message

    from vesselbot_ros.nodes import conversions as cv

    return serialize_message(cv.plant_state_msg(k, k * 1e-3, (x, 0.0), (0.0, 0.0), (0.0, 0.0), 3.1e-3, 1e-3, 1e-3,
                                                -1e-3, False, 0, (0.01 * k, 0.0), [(0.0, 0.0)] * 8))


def test_one_update_pairs_truth_reference_estimate_and_coil_of_one_tick_when_the_queues_lag():
    """The recorder takes each topic on its own subscription: a loaded machine hands them over out of step.  The
    errors are of one tick (the coil's when its truth and reference came, else the newest tick that has both)."""
    pytest.importorskip("rclpy")
    from rclpy.serialization import serialize_message

    from vesselbot_ros.live_view import TICK_RING, DerivedView
    from vesselbot_ros.nodes import conversions as cv
    from vesselbot_ros.scanner.actuator_limits import CoilLimits, CoilOutput

    got: list[dict[str, float]] = []
    view = DerivedView(lambda key, data, t: got.append(json.loads(data)) if key == "view_errors" else None)
    view._last_wall = math.inf  # emit() by hand

    def ref(k: int) -> bytes:
        return serialize_message(cv.reference_msg(k, k * 1e-3, (1e-3 * k + 1e-4, 0.0), (0.0, 0.0), (0.0, 0.0)))

    def est(k: int) -> bytes:
        return serialize_message(cv.estimate_msg(k * 1e-3, (1e-3 * k - 2e-5, 0.0), (0.0, 0.0), 0.0))

    def coil(k: int) -> bytes:
        out = CoilOutput(np.zeros(2), 1.0, False, np.zeros(2, bool), False)
        return serialize_message(cv.coil_state_msg(k, k * 1e-3, (0.0, 0.0), out, CoilLimits(), False))

    name = {k: topic(k).name for k in ("truth", "reference", "estimate", "coil_state")}
    # the truth runs 5 ticks ahead of the reference, the estimate 2 behind the truth, the coil state 1 behind
    for k in range(20):
        view.offer(name["truth"], _truth(k, 1e-3 * k), k)
        if k >= 5:
            view.offer(name["reference"], ref(k - 5), k)
        if k >= 2:
            view.offer(name["estimate"], est(k - 2), k)
        if k >= 1:
            view.offer(name["coil_state"], coil(k - 1), k)
    view.emit(0)
    # tick 14: the newest with both a truth and a reference (the coil's, 18, has no reference yet)
    e = got[-1]
    assert e["t_s"] == pytest.approx(14e-3, abs=1e-12)
    assert e["tracking_error_m"] == pytest.approx(1e-4, rel=1e-9)
    assert e["estimation_error_m"] == pytest.approx(2e-5, rel=1e-6)
    assert e["gradient_norm_T_per_m"] == pytest.approx(0.14, rel=1e-12)  # the truth's own applied gradient
    # once the reference catches up, the update is of the coil state's tick
    for k in range(15, 20):
        view.offer(name["reference"], ref(k), 20)
    view.emit(0)
    assert got[-1]["t_s"] == pytest.approx(18e-3, abs=1e-12) and got[-1]["tracking_error_m"] == pytest.approx(1e-4)
    # no reference at all: the truth's tick, no tracking error; the ring keeps TICK_RING messages each
    view2 = DerivedView(lambda key, data, t: got.append(json.loads(data)) if key == "view_errors" else None)
    for k in range(TICK_RING + 10):
        view2.offer(name["truth"], _truth(k, 0.0), k)
    assert len(view2._recent["truth"]) == TICK_RING
    view2.emit(0)
    assert got[-1]["t_s"] == pytest.approx((TICK_RING + 9) * 1e-3) and "tracking_error_m" not in got[-1]


def test_a_network_run_gets_no_straight_walls_and_the_radius_from_both_gaps():
    pytest.importorskip("rclpy")
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Header

    from vesselbot_ros.graph_spec import topic
    from vesselbot_ros.live_view import DerivedView
    from vesselbot_ros.nodes import conversions as cv
    from vesselbot_ros.vessels.cfd import network_wall
    from vesselbot_ros.vessels.network import load_network
    from vesselbot_ros.vessels.tube_geometry import NetworkGeometry

    # in a network the gaps are to the nearest wall and the opposite one, not D/2 -/+ z: the old upper-gap rule
    # (D/2 - z - gap_up) gave a wrong radius wherever the centreline is not at z = 0
    d, r, near = 2.4e-3, 2.5e-4, 1e-4
    sn = scene_numbers(0.1, (12e-3, 1.5e-3), d, near, d - 2 * r - near, (0.0, 0.0), 0.08, None, None)
    assert sn.robot_radius_m == pytest.approx(r, rel=1e-12)
    view = DerivedView(lambda *a: None)
    assert {m.ns for m in view.markers(sn, Header()).markers} >= {"upper_wall", "lower_wall"}  # no markers seen yet
    net = load_network("paper_iiic_artery")
    markers = cv.network_markers(NetworkGeometry(net), network_wall(net).segments, r)
    view.offer(topic("vessel_markers").name, serialize_message(markers), 0)
    assert view.network
    assert not {m.ns for m in view.markers(sn, Header()).markers} & {"upper_wall", "lower_wall"}
    straight = cv.vessel_markers(0.0, 0.01, 3e-3, r)
    view.offer(topic("vessel_markers").name, serialize_message(straight), 0)
    assert not view.network


def test_scene_numbers_in_3d_and_a_planar_point_is_one_with_y_zero():
    d, r = 3e-3, 2.5e-4
    sn = scene_numbers(0.5, (1e-3, 2e-4, 3e-4), d, 1e-3, 1e-3, (0.03, 0.04, 0.0), 0.08, (1e-3, 2e-4 + 3e-6, 3e-4 + 4e-6),
                       (1e-3 + 2e-5, 2e-4 + 2e-5, 3e-4 + 1e-5))
    assert sn.robot == (1e-3, 2e-4, 3e-4) and sn.gradient == (0.03, 0.04, 0.0)
    assert sn.estimation_error_m == pytest.approx(5e-6, rel=1e-9)  # the y offset counts
    assert sn.tracking_error_m == pytest.approx(3e-5, rel=1e-9)
    # (x, z) is (x, 0, z): the same numbers, bit for bit
    plane = scene_numbers(0.5, (1e-3, 3e-4), d, 0.5 * d - 3e-4 - r, 3e-4 + 0.5 * d - r, (0.03, -0.04), 0.08,
                          (1e-3 + 3e-6, 3e-4 + 4e-6), (1e-3 - 6e-5, 3e-4 + 8e-5))
    space = scene_numbers(0.5, (1e-3, 0.0, 3e-4), d, 0.5 * d - 3e-4 - r, 3e-4 + 0.5 * d - r, (0.03, 0.0, -0.04), 0.08,
                          (1e-3 + 3e-6, 0.0, 3e-4 + 4e-6), (1e-3 - 6e-5, 0.0, 3e-4 + 8e-5))
    assert plane == space and plane.robot == (1e-3, 0.0, 3e-4)


def test_a_3d_scene_draws_robot_estimate_arrow_and_path_where_the_messages_put_them():
    pytest.importorskip("rclpy")
    from geometry_msgs.msg import Point, Vector3
    from nav_msgs.msg import Odometry
    from rclpy.serialization import deserialize_message, serialize_message
    from vesselbot_msgs.msg import CoilState, PlantState
    from visualization_msgs.msg import MarkerArray

    from vesselbot_ros.live_view import DerivedView
    from vesselbot_ros.nodes import conversions as cv

    sent = []
    view = DerivedView(lambda key, data, t: sent.append((key, data)))
    # the plant's markers of a 3-D tree: a wall mesh (no straight walls in the view then)
    cube = [[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)]
    markers = MarkerArray(markers=[cv.wall_mesh_marker(cube, [[0, 1, 2], [1, 3, 2]])])
    view.offer(topic("vessel_markers").name, serialize_message(markers), 0)
    assert view.network
    route = [(0.0, 0.0, 0.0), (1e-3, -5e-4, 2e-4), (2e-3, -1e-3, 4e-4)]
    view.offer(topic("reference_path").name, serialize_message(cv.path_msg(route)), 0)
    p, r, lumen = Point(x=1e-3, y=-5e-4, z=2e-4), 2.5e-4, 1e-3
    truth = PlantState(header=cv.header(0.25), position=p, vessel_diameter=2 * lumen, wall_gap_upper=lumen - r,
                       wall_gap_lower=lumen - r, applied_gradient=Vector3(x=0.03, y=-0.04, z=0.0))
    est = Odometry(header=cv.header(0.25))
    est.pose.pose.position = Point(x=p.x + 3e-6, y=p.y + 4e-6, z=p.z)
    view._last_wall = math.inf  # emit() by hand
    for key, msg in (("truth", truth), ("estimate", est),
                     ("coil_state", CoilState(header=cv.header(0.25), max_gradient=0.1))):
        view.offer(topic(key).name, serialize_message(msg), 250_000_000)
    view.emit(250_000_000)
    ms = {m.ns: m for m in deserialize_message(dict(sent)["view_markers"], MarkerArray).markers}
    assert set(ms) == {"robot", "estimate", "gradient", "reference_path"}  # no straight walls
    pos = lambda q: (q.x, q.y, q.z)  # noqa: E731 - a one-line accessor
    assert pos(ms["robot"].pose.position) == pos(p) and ms["robot"].scale.x == pytest.approx(2 * r)
    assert pos(ms["estimate"].pose.position) == (p.x + 3e-6, p.y + 4e-6, p.z)
    a, b = ms["gradient"].points
    assert pos(a) == pos(p)
    assert (b.x - a.x, b.y - a.y, b.z - a.z) == pytest.approx((0.6e-3, -0.8e-3, 0.0), rel=1e-12)  # 2 mm * G / U_sat
    assert [pos(q) for q in ms["reference_path"].points] == route
    errors = json.loads(dict(sent)["view_errors"])
    assert errors["estimation_error_m"] == pytest.approx(5e-6, rel=1e-9)
    assert errors["gradient_norm_T_per_m"] == pytest.approx(0.05, rel=1e-12)


def test_layout_opens_a_side_view_that_orbits_and_shows_a_networks_wall():
    """Foxglove's 2D mode (``perspective: false``) is an orthographic view from above, onto XY: the planar
    scene is a line there.  The 3D panel opens on the XZ side view (phi 90, theta 0: camera on -y, z up) in
    3D mode, which a 3-D tree's user can orbit, and shows the plant's vessel markers (a network's wall, a
    3-D tree's mesh) but the straight vessel's nominal wall lines (the view draws its pulsing walls)."""
    layout = json.loads((REPO / "config" / "foxglove" / "vesselbot.json").read_text())
    panel = layout["configById"]["3D!vessel"]
    cam = panel["cameraState"]
    assert (cam["perspective"], cam["phi"], cam["thetaOffset"]) == (True, 90, 0)
    vessel = panel["topics"][topic("vessel_markers").name]
    assert vessel["visible"] is True
    assert {ns for ns, s in vessel["namespaces"].items() if not s["visible"]} == {"upper_wall", "lower_wall"}


def test_straight_walls_drawn_before_the_plants_markers_show_a_network_are_deleted_once():
    """The plant's markers come on a topic of their own (a 3-D tree's mesh is large): updates before them draw
    the straight walls, which a viewer keeps until deleted."""
    pytest.importorskip("rclpy")
    from rclpy.serialization import deserialize_message, serialize_message
    from visualization_msgs.msg import Marker, MarkerArray

    from vesselbot_ros.live_view import DerivedView
    from vesselbot_ros.nodes import conversions as cv

    sent = []
    view = DerivedView(lambda key, data, t: sent.append(deserialize_message(data, MarkerArray))
                       if key == "view_markers" else None)
    view.offer(topic("truth").name, serialize_message(cv.plant_state_msg(
        5, 0.005, (2e-3, 1e-4), (0.0, 0.0), (0.0, 0.0), 3.1e-3, 1e-3, 1e-3, -1e-3, False, 0, (0.0, 0.0),
        [(0.0, 0.0)] * 8)), 5)
    view.emit(5)
    mesh = MarkerArray(markers=[cv.wall_mesh_marker([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [[0, 1, 2]])])
    view.offer(topic("vessel_markers").name, serialize_message(mesh), 0)
    view.emit(5)
    view.emit(5)
    walls = [[(m.ns, m.action) for m in arr.markers if m.ns.endswith("_wall")] for arr in sent]
    assert walls == [[("upper_wall", Marker.ADD), ("lower_wall", Marker.ADD)],
                     [("upper_wall", Marker.DELETE), ("lower_wall", Marker.DELETE)], []]
    assert all(m.header.frame_id == "vessel" for m in sent[1].markers)


def test_an_update_before_the_path_arrived_does_not_use_up_the_paths_period():
    """The first updates of a short run come before the reference's path: the path rides on the first update after
    it arrives, not a period later (a 0.3 s run may end within one period)."""
    pytest.importorskip("rclpy")
    from geometry_msgs.msg import Point
    from rclpy.serialization import deserialize_message, serialize_message
    from visualization_msgs.msg import MarkerArray

    from vesselbot_ros.live_view import DerivedView
    from vesselbot_ros.nodes import conversions as cv

    view = DerivedView(lambda *a: None)
    sent = []
    view._send = lambda key, data, t: sent.append(deserialize_message(data, MarkerArray)) if key == "view_markers" else None
    view._last_wall = math.inf  # offer() emits nothing by itself here
    view.offer(topic("truth").name, serialize_message(cv.plant_state_msg(
        5, 0.005, (2e-3, 1e-4), (0.0, 0.0), (0.0, 0.0), 3.1e-3, 1e-3, 1e-3, -1e-3, False, 0, (0.0, 0.0),
        [(0.0, 0.0)] * 8)), 5)
    view.emit(5)  # no path yet
    view._path_points = [Point(x=1e-5 * i, z=0.0) for i in range(50)]
    view.emit(6)  # within the period of the first update: the path rides along now
    view.emit(7)
    assert [any(m.ns == "reference_path" for m in arr.markers) for arr in sent] == [False, True, False]
