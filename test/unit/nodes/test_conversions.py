"""Message <-> numpy conversions: tick times survive the wire bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")

from vesselbot_ros.nodes import conversions as cv  # noqa: E402


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
    k, on_grid = cv.tick_of_ns(1_000_500_000, 1e-3)  # 1.0005 s on a 1 ms grid
    assert not on_grid


def test_estimate_round_trip_and_age_slot():
    msg = cv.estimate_msg(0.25, np.array([1e-3, -2e-4]), np.array([3e-3, 4e-5]), 0.02)
    x, z, age = cv.estimate_arrays(msg)
    np.testing.assert_array_equal(x, [1e-3, -2e-4])
    np.testing.assert_array_equal(z, [3e-3, 4e-5])
    assert age == 0.02
    assert msg.pose.pose.position.y == 0.0 and msg.header.frame_id == "vessel"
    assert sum(msg.pose.covariance) == pytest.approx(0.02, abs=0)


def test_flow_scale_travels_exactly_and_none_reads_as_one():
    s_hat = 1.0498765432101234
    msg = cv.estimate_msg(0.25, np.zeros(2), np.zeros(2), 0.0, s_hat)
    assert cv.estimate_flow_scale(msg) == s_hat  # the double itself: the law downstream is bit-identical
    assert sum(msg.twist.covariance) == s_hat and msg.twist.covariance[cv.FLOW_SCALE_COVARIANCE_INDEX] == s_hat
    assert cv.estimate_flow_scale(cv.estimate_msg(0.25, np.zeros(2), np.zeros(2), 0.0)) == 1.0
    legacy = cv.estimate_msg(0.25, np.zeros(2), np.zeros(2), 0.0)
    legacy.twist.covariance = [0.0] * 36  # a bag recorded before the scale travelled
    assert cv.estimate_flow_scale(legacy) == 1.0


def test_infinite_age_travels_as_a_large_finite_number():
    msg = cv.estimate_msg(0.0, np.zeros(2), np.zeros(2), float("inf"))
    assert cv.estimate_arrays(msg)[2] == 1e9


def test_stamp_split_into_sec_and_nanosec():
    s = cv.stamp_of_ns(2_000_000_001)
    assert (s.sec, s.nanosec) == (2, 1)


def test_estimate_carries_the_flow_scale_and_unset_reads_as_one():
    msg = cv.estimate_msg(0.1, np.zeros(2), np.zeros(2), 0.0, 0.9523)
    assert cv.estimate_flow_scale(msg) == 0.9523
    assert cv.estimate_arrays(msg)[2] == 0.0  # the age slot is untouched
    from nav_msgs.msg import Odometry

    assert cv.estimate_flow_scale(Odometry()) == 1.0  # a user's observer that does not set it
    for bad in (float("nan"), -1.0, 0.0):
        msg.twist.covariance[35] = bad
        assert cv.estimate_flow_scale(msg) == 1.0


def test_sequence_phase_message_from_a_window():
    from vesselbot_ros.scanner.sequence import SequenceParams, window_at

    seq = SequenceParams(mode="multiplexed")
    msg = cv.sequence_phase_msg(0.022, window_at(seq, 0.022), 0.02, 0.5555)
    assert (msg.phase, msg.period_index, msg.window_start, msg.window_end) == (msg.PROPULSION, 0, 0.022, 0.052)
    assert cv.ns_of_stamp(msg.header.stamp) == 22_000_000 and msg.header.frame_id == "vessel"
    cont = cv.sequence_phase_msg(0.0, window_at(SequenceParams(), 0.0), 0.0, 1.0)
    assert cont.phase == cont.CONTINUOUS and cont.window_end == float("inf") and cont.duty_cycle == 1.0
