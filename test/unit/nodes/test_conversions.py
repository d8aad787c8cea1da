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
