"""Flat CDR codecs (vesselbot_ros.nodes.wire) against rclpy's own serializer, both directions."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vesselbot_ros.graph_spec import FRAME_ID, TOPICS, WIRE_STRINGS, import_type
from vesselbot_ros.nodes import conversions as cv
from vesselbot_ros.nodes import wire

rclpy_ser = pytest.importorskip("rclpy.serialization")

def _encode(codec, msg):
    """A message's CDR through its flat form (what a node publishes)."""
    return codec.pack(codec.flatten(msg))


def _decode(codec, raw):
    """A buffer's message through its flat form (what a node reads)."""
    return codec.to_message(codec.unpack(raw))


PER_TICK_TYPES = sorted({t.msgtype for t in TOPICS if t.per_tick})
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
tick = st.integers(min_value=0, max_value=2**32 - 1)


def _messages(draw_f, k):
    """One message of every per-tick type from 40 floats ``draw_f`` and a tick ``k`` (the conversions' builders)."""
    f = list(draw_f)
    t = k * 1e-3

    class Out:
        applied, k_scale, saturated, slew_limited, rejected = np.array(f[0:2]), f[2], True, np.array([True, False]), False

    class Limits:
        saturation_T_per_m, slew_rate_T_per_m_per_s = f[3], f[4]

    return [
        cv.clock_msg(t),
        cv.measurement_msg(t, np.array(f[5:7])),
        cv.gradient_msg(t, f[7:9]),
        cv.estimate_msg(t, np.array(f[9:11]), np.array(f[11:13]), f[13], f[14]),
        cv.reference_msg(k, t, f[15:17], f[17:19], f[19:21]),
        cv.coil_state_msg(k, t, np.array(f[21:23]), Out, Limits, True, f[23], f[24]),
        cv.plant_state_msg(k, t, np.array(f[25:27]), np.array(f[27:29]), (f[29], f[30]), f[31], f[32], f[33], f[34],
                           bool(k % 2), k % 3, np.array(f[35:37]), np.arange(16.0).reshape(8, 2) * f[37]),
    ]


def test_every_per_tick_type_has_a_flat_codec():
    for name in PER_TICK_TYPES:
        assert wire.codec_for(import_type(name), WIRE_STRINGS) is not None, name


def test_a_type_with_a_free_string_has_none():
    from diagnostic_msgs.msg import KeyValue

    assert wire.codec_for(KeyValue, WIRE_STRINGS) is None


@settings(max_examples=60, deadline=None)
@given(st.lists(finite, min_size=40, max_size=40), tick)
def test_encode_and_decode_equal_rclpys_serializer(values, k):
    """Both directions against rclpy's serializer, as messages and as flat forms."""
    for msg in _messages(values, k):
        codec = wire.codec_for(type(msg), WIRE_STRINGS)
        ours = _encode(codec, msg)
        theirs = rclpy_ser.serialize_message(msg)
        assert len(ours) == codec.size == len(theirs)
        # CDR padding is not initialised by rclpy's serializer: compare what the bytes decode to
        assert rclpy_ser.deserialize_message(ours, type(msg)) == msg
        decoded = _decode(codec, theirs)
        assert type(decoded) is type(msg)
        assert decoded == msg
        assert rclpy_ser.serialize_message(decoded) is not None  # a valid rclpy message object
        # the flat form: unpack(CDR) == flatten(message), pack(flat form) is that CDR, to_message gives it back
        flat = codec.flatten(msg)
        assert type(flat) is codec.Flat and len(flat) == len(codec.Flat._fields)
        theirs = rclpy_ser.serialize_message(msg)
        assert codec.on_layout(theirs)
        assert codec.unpack(theirs) == flat
        assert rclpy_ser.deserialize_message(codec.pack(flat), type(msg)) == msg
        assert codec.to_message(flat) == msg
        if hasattr(msg, "header"):
            assert flat.header_frame_id_cdr == FRAME_ID.encode() + b"\0"
            assert cv.stamp_ns(flat) == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


@pytest.mark.parametrize("frame", ["", "robot", "vessel2"])
def test_a_flat_form_off_the_layout_travels_through_rclpy(frame):
    msg = cv.gradient_msg(0.002, (1e-3, -2e-3))
    msg.header.frame_id = frame
    codec = wire.codec_for(type(msg), WIRE_STRINGS)
    raw = rclpy_ser.serialize_message(msg)
    assert not codec.on_layout(raw)
    flat = codec.unpack(raw)  # by rclpy's deserializer
    assert flat.header_frame_id_cdr == frame.encode() + b"\0" and flat.header_frame_id_size == len(frame) + 1
    assert flat.vector_x == 1e-3 and flat.vector_z == -2e-3
    assert rclpy_ser.deserialize_message(codec.pack(flat), type(msg)) == msg  # not truncated to the layout's size
    assert codec.to_message(flat) == msg


def test_a_maker_fills_the_defaults_and_the_graphs_strings():
    from geometry_msgs.msg import Vector3Stamped
    from nav_msgs.msg import Odometry

    codec = wire.codec_for(Vector3Stamped, WIRE_STRINGS)
    make = codec.maker("header.stamp.nanosec", "vector.z")
    msg = codec.to_message(make(5, 2.5))
    assert msg.header.frame_id == FRAME_ID and msg.header.stamp.nanosec == 5 and msg.header.stamp.sec == 0
    assert (msg.vector.x, msg.vector.y, msg.vector.z) == (0.0, 0.0, 2.5)
    odo = wire.codec_for(Odometry, WIRE_STRINGS)
    est = odo.to_message(odo.maker("pose.covariance_35")(0.25))
    assert est.pose.pose.orientation.w == 1.0 and est.child_frame_id == WIRE_STRINGS["child_frame_id"]
    assert est.pose.covariance[35] == 0.25 and sum(est.pose.covariance) == 0.25
    for bad in ("vector.w", "header.frame_id", "cdr_header", "vector"):
        with pytest.raises(KeyError):
            codec.maker(bad)


def test_nan_travels_as_nan():
    msg = cv.gradient_msg(0.001, (math.nan, math.inf))
    codec = wire.codec_for(type(msg), WIRE_STRINGS)
    back = _decode(codec, _encode(codec, msg))
    assert math.isnan(back.vector.x) and back.vector.z == math.inf
    back = rclpy_ser.deserialize_message(_encode(codec, msg), type(msg))
    assert math.isnan(back.vector.x) and back.vector.z == math.inf


@pytest.mark.parametrize("frame", ["", "robot", "vessel2", "vesse"])
def test_another_frame_goes_through_rclpy_both_ways(frame):
    msg = cv.measurement_msg(0.002, np.array([1e-3, 2e-4]))
    msg.header.frame_id = frame
    codec = wire.codec_for(type(msg), WIRE_STRINGS)
    raw = _encode(codec, msg)
    assert rclpy_ser.deserialize_message(raw, type(msg)) == msg
    back = _decode(codec, rclpy_ser.serialize_message(msg))
    assert back == msg and back.header.frame_id == frame


def test_an_odometry_from_another_child_frame_is_decoded_by_rclpy():
    msg = cv.estimate_msg(0.003, np.array([1e-3, -2e-4]), np.array([3e-3, 4e-5]), 0.02, 0.97)
    msg.child_frame_id = "base_link"
    codec = wire.codec_for(type(msg), WIRE_STRINGS)
    assert _decode(codec, rclpy_ser.serialize_message(msg)) == msg


def _outcome(fn, raw, cls):
    try:
        return fn(raw, cls)
    except Exception as exc:  # noqa: BLE001 - the outcome compared is the error's type
        return type(exc)


def test_a_truncated_or_big_endian_buffer_is_left_to_rclpy():
    msg = cv.reference_msg(3, 0.003, (1e-3, 0.0), (2e-3, 1e-4), (3.0, -4.0))
    codec = wire.codec_for(type(msg), WIRE_STRINGS)
    raw = rclpy_ser.serialize_message(msg)
    for odd in (raw[: codec.size - 8], b"\x00\x00" + raw[2:]):  # short; big-endian encapsulation
        assert not codec.on_layout(odd)
        ours = _outcome(lambda r, _c: _decode(codec, r), odd, type(msg))
        theirs = _outcome(rclpy_ser.deserialize_message, odd, type(msg))
        assert ours == theirs


def test_received_buffers_may_carry_trailing_padding():
    msg = cv.clock_msg(0.004)
    codec = wire.codec_for(type(msg), WIRE_STRINGS)
    assert _decode(codec, _encode(codec, msg) + b"\x00\x00\x00") == msg


def test_the_frame_is_the_graphs():
    assert WIRE_STRINGS["header.frame_id"] == FRAME_ID
