"""Message <-> numpy conversions: tick times survive the wire bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")

from vesselbot_ros.nodes import conversions as cv


@pytest.mark.parametrize("rate", [1000.0, 50.0, 333.0, 1234.5])
def test_tick_recovered_from_stamp_and_time_is_bit_identical(rate):
    dt = 1.0 / rate
    ts = np.arange(5000) * dt  # the pure runner's grid
    for k in (0, 1, 7, 999, 1000, 4999):
        ns = cv.ns_of_stamp(cv.stamp_of_ns(cv.ns_of_time(float(ts[k]))))
        k2, on_grid = cv.tick_of_ns(ns, dt)
        assert (k2, on_grid) == (k, True)
        assert cv.tick_time(k2, dt) == float(ts[k])  # exact, not approx


def test_off_grid_stamp_is_detected():
    _k, on_grid = cv.tick_of_ns(1_000_500_000, 1e-3)  # 1.0005 s on a 1 ms grid
    assert not on_grid


def _flat(msg):
    """A message's flat form (what the nodes read)."""
    return cv.codec(type(msg)).flatten(msg)


def test_estimate_round_trip_and_age_slot():
    msg = cv.estimate_msg(0.25, np.array([1e-3, -2e-4]), np.array([3e-3, 4e-5]), 0.02)
    x, z, age = cv.estimate_arrays(_flat(msg))
    np.testing.assert_array_equal(x, [1e-3, -2e-4])
    np.testing.assert_array_equal(z, [3e-3, 4e-5])
    assert age == 0.02
    assert msg.pose.pose.position.y == 0.0 and msg.header.frame_id == "vessel"
    assert sum(msg.pose.covariance) == pytest.approx(0.02, abs=0)


def test_flow_scale_travels_exactly_and_none_reads_as_one():
    s_hat = 1.0498765432101234
    msg = cv.estimate_msg(0.25, np.zeros(2), np.zeros(2), 0.0, s_hat)
    assert cv.estimate_flow_scale(_flat(msg)) == s_hat  # the double itself: the law downstream is bit-identical
    assert sum(msg.twist.covariance) == s_hat and msg.twist.covariance[cv.FLOW_SCALE_COVARIANCE_INDEX] == s_hat
    assert cv.estimate_flow_scale(_flat(cv.estimate_msg(0.25, np.zeros(2), np.zeros(2), 0.0))) == 1.0
    legacy = cv.estimate_msg(0.25, np.zeros(2), np.zeros(2), 0.0)
    legacy.twist.covariance = [0.0] * 36  # a bag recorded before the scale travelled
    assert cv.estimate_flow_scale(_flat(legacy)) == 1.0


def test_infinite_age_travels_as_a_large_finite_number():
    msg = cv.estimate_msg(0.0, np.zeros(2), np.zeros(2), float("inf"))
    assert cv.estimate_arrays(_flat(msg))[2] == 1e9


def test_stamp_split_into_sec_and_nanosec():
    s = cv.stamp_of_ns(2_000_000_001)
    assert (s.sec, s.nanosec) == (2, 1)


def test_estimate_carries_the_flow_scale_and_unset_reads_as_one():
    msg = cv.estimate_msg(0.1, np.zeros(2), np.zeros(2), 0.0, 0.9523)
    assert cv.estimate_flow_scale(_flat(msg)) == 0.9523
    assert cv.estimate_arrays(_flat(msg))[2] == 0.0  # the age slot is untouched
    from nav_msgs.msg import Odometry

    assert cv.estimate_flow_scale(_flat(Odometry())) == 1.0  # a user's observer that does not set it
    for bad in (float("nan"), -1.0, 0.0):
        msg.twist.covariance[35] = bad
        assert cv.estimate_flow_scale(_flat(msg)) == 1.0


def test_sequence_phase_message_from_a_window():
    from vesselbot_ros.scanner.sequence import SequenceParams, window_at

    seq = SequenceParams(mode="multiplexed")
    msg = cv.sequence_phase_msg(0.022, window_at(seq, 0.022), 0.02, 0.5555)
    assert (msg.phase, msg.period_index, msg.window_start, msg.window_end) == (msg.PROPULSION, 0, 0.022, 0.052)
    assert cv.ns_of_stamp(msg.header.stamp) == 22_000_000 and msg.header.frame_id == "vessel"
    cont = cv.sequence_phase_msg(0.0, window_at(SequenceParams(), 0.0), 0.0, 1.0)
    assert cont.phase == cont.CONTINUOUS and cont.window_end == float("inf") and cont.duty_cycle == 1.0


# ---------------------------------------------------------------- the hot path's message builders
def _slow_references():
    """Each builder's message built the generated way (constructors and setters), with the same numbers."""
    from builtin_interfaces.msg import Time
    from geometry_msgs.msg import Point, PointStamped, Vector3, Vector3Stamped
    from nav_msgs.msg import Odometry
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Header
    from vesselbot_msgs.msg import CoilState, ForceBreakdown, PlantState, ReferenceSample

    from vesselbot_ros.physics.kernel import TERM_NAMES

    t = 0.123
    ns = cv.ns_of_time(t)
    h = Header(stamp=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id="vessel")
    odo = Odometry(header=h, child_frame_id="robot")
    odo.pose.pose.position = Point(x=1e-3, y=0.0, z=-2e-4)
    odo.pose.pose.orientation.w = 1.0
    odo.twist.twist.linear = Vector3(x=3e-3, y=0.0, z=4e-5)
    cov, tcov = [0.0] * 36, [0.0] * 36
    cov[cv.AGE_COVARIANCE_INDEX], tcov[cv.FLOW_SCALE_COVARIANCE_INDEX] = 0.02, 0.97
    odo.pose.covariance, odo.twist.covariance = cov, tcov
    forces = np.arange(16, dtype=float).reshape(8, 2) * 1e-9
    fb = ForceBreakdown(header=h, **{n: Vector3(x=forces[i, 0], y=0.0, z=forces[i, 1]) for i, n in enumerate(TERM_NAMES)})

    class Out:  # a CoilOutput's fields
        applied, k_scale, saturated, slew_limited, rejected = np.array([0.1, -0.2]), 0.5, True, np.array([True, False]), False

    class Limits:
        saturation_T_per_m, slew_rate_T_per_m_per_s = 0.08, 100.0

    return [
        (cv.clock_msg(t), Clock(clock=h.stamp)),
        (cv.measurement_msg(t, np.array([1e-3, 2e-4])), PointStamped(header=h, point=Point(x=1e-3, y=0.0, z=2e-4))),
        (cv.gradient_msg(t, (0.1, -0.2)), Vector3Stamped(header=h, vector=Vector3(x=0.1, y=0.0, z=-0.2))),
        (cv.estimate_msg(t, np.array([1e-3, -2e-4]), np.array([3e-3, 4e-5]), 0.02, 0.97), odo),
        (cv.reference_msg(7, t, (1e-3, 0.0), (2e-3, 1e-4), (3.0, -4.0)),
         ReferenceSample(header=h, tick=7, position=Point(x=1e-3, y=0.0, z=0.0), velocity=Vector3(x=2e-3, y=0.0, z=1e-4),
                         acceleration=Vector3(x=3.0, y=0.0, z=-4.0))),
        (cv.coil_state_msg(7, t, np.array([0.2, -0.4]), Out, Limits, True, 20.0, 0.25),
         CoilState(header=h, tick=7, commanded=Vector3(x=0.2, y=0.0, z=-0.4), applied=Vector3(x=0.1, y=0.0, z=-0.2),
                   saturation_scale=0.5, saturated=True, slew_limited_x=True, slew_limited_z=False, command_rejected=False,
                   watchdog_active=True, max_gradient=0.08, slew_rate=100.0, dbdt_limit=20.0, dbdt_radius=0.25)),
        (cv.plant_state_msg(7, t, np.array([1e-3, 2e-4]), np.array([3e-3, 0.0]), (0.1, 0.0), 2e-3, 5e-4, 6e-4, 4e-4,
                            True, 2, np.array([0.05, 0.01]), forces),
         PlantState(header=h, tick=7, position=Point(x=1e-3, y=0.0, z=2e-4), velocity=Vector3(x=3e-3, y=0.0, z=0.0),
                    blood_velocity=Vector3(x=0.1, y=0.0, z=0.0), vessel_diameter=2e-3, wall_gap_upper=5e-4,
                    wall_gap_lower=6e-4, signed_wall_distance=4e-4, in_contact=True, contact_phase=2,
                    applied_gradient=Vector3(x=0.05, y=0.0, z=0.01), forces=fb)),
    ]


@pytest.mark.parametrize("i", range(7))
def test_fast_builders_equal_the_generated_constructors_on_the_wire(i):
    from rclpy.serialization import deserialize_message, serialize_message

    fast, slow = _slow_references()[i]
    assert type(fast) is type(slow)
    assert fast == slow
    # CDR alignment padding is not initialised by the serializer (it differed between two
    # serialisations of equal messages in CI), so the wire is compared by its length and
    # by what it decodes to, not byte by byte.
    wire_fast, wire_slow = serialize_message(fast), serialize_message(slow)
    assert len(wire_fast) == len(wire_slow)
    assert deserialize_message(wire_fast, type(slow)) == slow
    assert deserialize_message(wire_slow, type(slow)) == deserialize_message(wire_fast, type(slow))


def test_builder_needs_every_field():
    from geometry_msgs.msg import Vector3

    build = cv.message_builder(Vector3)
    with pytest.raises(TypeError):
        build(x=1.0, z=2.0)
    assert build(x=1.0, y=0.0, z=2.0) == Vector3(x=1.0, z=2.0)


# --- a 3-D vessel's scene -------------------------------------------------------------------------

#: A unit cube's surface: 8 vertices, 12 triangles, each wound counter-clockwise seen from outside.
CUBE_V = np.array([[x, y, z] for x in (0.0, 1e-3) for y in (0.0, 2e-3) for z in (0.0, 3e-3)])
CUBE_T = np.array([[0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                   [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5]])


def test_wall_mesh_marker_keeps_every_triangle_and_its_winding():
    from rclpy.serialization import deserialize_message, serialize_message
    from visualization_msgs.msg import Marker

    from vesselbot_ros.graph_spec import FRAME_ID, NETWORK_WALL_NS

    m = cv.wall_mesh_marker(CUBE_V, CUBE_T)
    assert (m.type, m.action, m.ns, m.id, m.header.frame_id) == (Marker.TRIANGLE_LIST, Marker.ADD, NETWORK_WALL_NS, 0,
                                                                  FRAME_ID)
    assert len(m.points) == 3 * len(CUBE_T) and not m.colors
    got = np.array([[p.x, p.y, p.z] for p in m.points]).reshape(-1, 3, 3)
    assert np.array_equal(got, CUBE_V[CUBE_T])  # triangle i is points 3i..3i+2, in its own vertex order
    # each triangle's winding still gives the outward normal: the normals point away from the cube's centre
    n = np.cross(got[:, 1] - got[:, 0], got[:, 2] - got[:, 0])
    assert (np.einsum("ij,ij->i", n, got.mean(axis=1) - CUBE_V.mean(axis=0)) > 0).all()
    assert 0 < m.color.a < 1 and (m.scale.x, m.scale.y, m.scale.z) == (1.0, 1.0, 1.0)
    assert m.pose.orientation.w == 1.0
    # over the wire: every vertex as given
    back = deserialize_message(serialize_message(m), Marker)
    assert np.array_equal(np.array([[p.x, p.y, p.z] for p in back.points]), CUBE_V[CUBE_T].reshape(-1, 3))
    # a reversed triangle stays reversed: the order is the caller's
    flipped = cv.wall_mesh_marker(CUBE_V, CUBE_T[:, ::-1])
    assert [(p.x, p.y, p.z) for p in flipped.points[:3]] == [tuple(CUBE_V[i]) for i in CUBE_T[0, ::-1]]


@pytest.mark.parametrize("vertices, triangles, match", [
    (CUBE_V[:, :2], CUBE_T, "vertices_m must be"),
    (CUBE_V, CUBE_T[:, :2], "triangles must be"),
    (CUBE_V, CUBE_T.astype(float), "integer"),
    (CUBE_V, np.r_[CUBE_T, [[0, 1, 8]]], "index vertices 0..7"),
    (CUBE_V, np.r_[CUBE_T, [[0, -1, 2]]], "index vertices 0..7"),
    (np.r_[CUBE_V[:7], [[np.nan, 0.0, 0.0]]], CUBE_T, "finite, got 1 vertices"),
])
def test_wall_mesh_marker_refuses_a_malformed_mesh(vertices, triangles, match):
    with pytest.raises(ValueError, match=match):
        cv.wall_mesh_marker(vertices, triangles)


def test_network_markers_3d_draw_the_tree_wall_and_its_3d_centrelines():
    from visualization_msgs.msg import Marker

    from vesselbot_ros.graph_spec import FRAME_ID, NETWORK_WALL_NS
    from vesselbot_ros.vessels import tree_mesh
    from vesselbot_ros.vessels.network import load_network
    from vesselbot_ros.vessels.tube_geometry import NetworkGeometry

    net = load_network("carotid_bifurcation_3d")
    geom = NetworkGeometry(net, dims=3)
    # a coarse mesh of the tree's lumen (a second: no flow solve), its wall's triangles
    meshed = tree_mesh.mesh_tree(tree_mesh.tree_from_network(net), 1.5e-3, 16)
    used, local = np.unique(meshed.boundaries["wall"], return_inverse=True)
    v, t = meshed.points[used], local.reshape(-1, 3)
    ms = cv.network_markers_3d(geom, v, t, 2.5e-4).markers
    wall = ms[0]
    assert (wall.ns, wall.type, wall.header.frame_id) == (NETWORK_WALL_NS, Marker.TRIANGLE_LIST, FRAME_ID)
    pts = np.array([[p.x, p.y, p.z] for p in wall.points])
    assert len(pts) == 3 * len(t) and np.isfinite(pts).all() and np.array_equal(pts, v[t].reshape(-1, 3))
    # the wall is the lumen's: every vertex on a branch's tube (caps left out), the tree leaves the plane
    assert np.abs(geom.query(v)["sdist"]).max() < 1e-5
    assert np.abs(pts[:, 1]).max() > 3e-3
    # a LINE_STRIP per branch, through its 3-D centreline samples (first and last included)
    assert [m.ns for m in ms[1:]] == [f"{b.name}/centreline" for b in net.branches]
    assert [m.id for m in ms] == list(range(len(ms)))
    for b, m in zip(net.branches, ms[1:]):
        c = np.array([[p.x, p.y, p.z] for p in m.points])
        samples = geom.centreline(b.name)
        every = round(2e-4 / net.sample_spacing_m)  # step_m's default
        assert m.type == Marker.LINE_STRIP and m.header.frame_id == FRAME_ID
        assert np.array_equal(c, samples[np.unique(np.r_[np.arange(0, len(samples), every), len(samples) - 1])])
        assert bool(np.abs(c[:, 1]).max() > 0) == (not b.is_planar)


def test_a_path_of_3d_points_keeps_its_y_and_a_planar_one_has_y_zero():
    pts3 = np.array([[0.0, 1e-3, 2e-3], [1e-3, -2e-3, 3e-3]])
    got = cv.path_msg(pts3, 0.5)
    assert [(p.pose.position.x, p.pose.position.y, p.pose.position.z) for p in got.poses] == [tuple(p) for p in pts3]
    assert all(p.header.frame_id == "vessel" for p in got.poses)
    flat = cv.path_msg(pts3[:, [0, 2]], 0.5)
    assert [(p.pose.position.x, p.pose.position.y, p.pose.position.z) for p in flat.poses] == \
        [(x, 0.0, z) for x, _, z in pts3]
    assert cv.point3((1.0, 2.0, 3.0)) == cv.point((1.0, 3.0)).__class__(x=1.0, y=2.0, z=3.0)
    with pytest.raises(ValueError, match=r"\(n, 2\) or \(n, 3\)"):
        cv.path_msg(np.zeros((3, 4)))
