"""live: the sim time from /clock and its rate limit, and one port that answers both names of the protocol.

The handshakes here are raw HTTP over a socket, so they pin exactly what a client
offering each name gets back (the rules: ``test_live_front.py``); Foxglove's own
client on the same server is ``test/integration/test_live.py``.
"""

from __future__ import annotations

import base64
import os
import socket

import pytest

TIMEOUT_S = 10.0


def _head(*protocol_headers: str) -> bytes:
    key = base64.b64encode(os.urandom(16)).decode("ascii")
    lines = ["GET / HTTP/1.1", "Host: 127.0.0.1", "Upgrade: websocket", "Connection: Upgrade",
             f"Sec-WebSocket-Key: {key}", "Sec-WebSocket-Version: 13"]
    lines += [f"Sec-WebSocket-Protocol: {p}" for p in protocol_headers]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("ascii")


def test_clock_ns_reads_the_cdr_of_a_clock_as_rclpy_writes_it():
    pytest.importorskip("rclpy")
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock

    from vesselbot_ros.live import clock_ns

    for sec, nanosec in ((0, 0), (0, 1_000_000), (2, 999_999_999), (1_800_000_000, 123)):
        c = Clock()
        c.clock.sec, c.clock.nanosec = sec, nanosec
        assert clock_ns(serialize_message(c)) == sec * 1_000_000_000 + nanosec
    assert clock_ns(b"\x00\x00\x00\x00" + (3).to_bytes(4, "big") + (7).to_bytes(4, "big")) == 3_000_000_007  # CDR_BE
    with pytest.raises(ValueError, match="12 bytes, got 4"):
        clock_ns(b"\x00\x01\x00\x00")


def _handshake(port: int, *offers: str) -> bytes:
    with socket.create_connection(("127.0.0.1", port), timeout=TIMEOUT_S) as s:
        s.sendall(_head(*offers))
        buf = b""
        while b"\r\n\r\n" not in buf:
            data = s.recv(4096)
            if not data:
                break
            buf += data
        return buf.split(b"\r\n\r\n", 1)[0].lower()


@pytest.fixture(scope="module")
def live():
    pytest.importorskip("foxglove")
    from vesselbot_ros.bag.writer import make_typestore
    from vesselbot_ros.graph_spec import topic
    from vesselbot_ros.live import LiveView

    view = LiveView([(topic("clock").name, topic("clock").msgtype, False)], make_typestore([]), port=0)
    yield view
    view.close()


def test_the_live_view_listens_on_the_port_it_reports_and_answers_either_name(live):
    assert live.port > 0 and live.url == f"ws://127.0.0.1:{live.port}"
    old = _handshake(live.port, "foxglove.websocket.v1")
    assert old.startswith(b"http/1.1 101") and b"sec-websocket-protocol: foxglove.websocket.v1" in old
    new = _handshake(live.port, "foxglove.sdk.v1")
    assert new.startswith(b"http/1.1 101") and b"sec-websocket-protocol: foxglove.sdk.v1" in new
    assert _handshake(live.port, "mqtt").startswith(b"http/1.1 400")


def test_a_busy_port_is_an_error_naming_no_other_port(live):
    from vesselbot_ros.bag.writer import make_typestore
    from vesselbot_ros.live import LiveView

    with pytest.raises(OSError, match="in use"):
        LiveView([], make_typestore([]), port=live.port)


def test_sim_time_is_held_back_by_the_rate_limit_and_flushed(live, monkeypatch):
    sent = []
    real = live._send_time  # the server object is native: record what reaches it here

    def record(t_ns, now=None):
        sent.append(t_ns)
        real(t_ns, now)

    monkeypatch.setattr(live, "_send_time", record)
    live._time_wall = -1e9
    live.set_time(1_000_000)
    live.set_time(2_000_000)  # within 1/TIME_RATE_HZ of the first: held back
    assert sent == [1_000_000] and live.time_ns == 2_000_000
    live.flush_time()
    live.flush_time()  # nothing new: no second broadcast
    assert sent == [1_000_000, 2_000_000]


def test_a_latched_message_is_re_sent_to_a_new_subscriber_with_its_own_log_time():
    pytest.importorskip("foxglove")
    from vesselbot_ros.bag.writer import make_typestore
    from vesselbot_ros.graph_spec import topic
    from vesselbot_ros.live import LiveView

    path = topic("reference_path")
    view = LiveView([(path.name, path.msgtype, True)], make_typestore([]), port=0)
    try:
        sent = []

        class Channel:  # stands in for the SDK's channel: records what the live view logs on it
            def log(self, data, log_time):
                sent.append((bytes(data), log_time))

        view._channels[path.name] = Channel()
        view.view.offer = lambda *a: None  # no derived view from these bytes
        view.log(path.name, b"\x00\x01\x00\x00path", 1_800_000_000_123_456_789)
        view._resend_latched(path.name)  # what a subscription triggers, any wall time later
        assert sent == [(b"\x00\x01\x00\x00path", 1_800_000_000_123_456_789)] * 2
    finally:
        view.close()
