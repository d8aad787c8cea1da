"""Live view: the graph's topics over the Foxglove WebSocket protocol (``vesselbot run --live``).

:class:`LiveView` runs the Foxglove SDK's WebSocket server (``foxglove-sdk`` on
PyPI; we never implement the protocol ourselves) and advertises one channel per
topic it is given: ``cdr`` messages with their ``ros2msg`` schema (the full
definition with its dependencies, the same text the bag embeds), so Foxglove
decodes them exactly as it decodes a recorded bag.  The channels come from
the graph spec (:data:`vesselbot_ros.graph_spec.TOPICS`): a port added there
appears in the live view with no view code.

Clients connect with either name of the protocol: ``foxglove.sdk.v1`` (the
SDK's, current Foxglove) or ``foxglove.websocket.v1`` (the specification's:
older Foxglove releases, Lichtblick, ``@foxglove/ws-protocol``); the SDK takes
only the first, so the port is held by :class:`vesselbot_ros.live_front.SubprotocolFront`,
which hands each connection to the SDK's server.  The server is listening when
the constructor returns, and :attr:`LiveView.port` is the bound port (also for 0).

Sim time: the server advertises the protocol's ``time`` capability and
broadcasts the simulation time, the latest ``/clock`` it is given (or
:meth:`LiveView.set_time`), at most :data:`TIME_RATE_HZ` times per wall second,
right before each derived view update, to each client that subscribes, and when
asked (:meth:`LiveView.flush_time`), so Foxglove's timeline runs on sim time,
not on the wall clock.  Every message keeps its log time (the bag's: the
recorder's receive time) as the protocol's message timestamp.

Messages are logged as the bytes the publisher sent (the recorder's raw
subscriptions feed both the bag and this server, so ``--live`` adds no DDS
reader to the loop).  A viewer needs far fewer than the loop's 1000 ticks per
second: each topic is forwarded at most ``max_rate_Hz`` times per wall second
(default :data:`DEFAULT_LIVE_RATE_HZ`; 0: every message), and nothing is
forwarded or derived while no client subscribes, so the live view's cost
does not grow with the control rate (``bench/bench_live.py``).  Latched topics (the vessel markers, the reference path)
are sent whenever published; a client that subscribes later gets the last
one again on subscription, with its original log time, as a transient-local subscriber would.

Besides the topics it serves the derived channels of
:data:`vesselbot_ros.graph_spec.VIEW_CHANNELS` (:mod:`vesselbot_ros.live_view`):
the scene as markers and the error time series, at most 20 updates per second.

The server listens on ``127.0.0.1`` only.  Connect Foxglove (desktop app or
browser) with *Open connection -> Foxglove WebSocket* ``ws://127.0.0.1:PORT``
and load ``config/foxglove/vesselbot.json`` as the layout.
"""

from __future__ import annotations

import contextlib
import json
import struct
import threading
import time
from collections.abc import Iterable
from typing import Any

from vesselbot_ros.graph_spec import VIEW_CHANNELS
from vesselbot_ros.graph_spec import topic as topic_spec
from vesselbot_ros.live_front import SubprotocolFront
from vesselbot_ros.live_view import ERRORS_SCHEMA, ERRORS_SCHEMA_NAME, DerivedView

__all__ = ["LiveView", "DEFAULT_LIVE_PORT", "DEFAULT_LIVE_RATE_HZ", "TIME_RATE_HZ", "check_port", "clock_ns"]

#: Foxglove's default WebSocket port.
DEFAULT_LIVE_PORT = 8765
#: Messages per topic and wall second forwarded to the viewer, at most.
DEFAULT_LIVE_RATE_HZ = 50.0
#: Sim-time broadcasts per wall second, at most (besides one right before each derived view update).  The
#: SDK queues them with its control messages, and disconnects a client whose control queue (1024) fills.
TIME_RATE_HZ = 50.0


def check_port(port: int) -> None:
    """Raise ValueError naming ``port`` if it is not a TCP port number (0: any free port)."""
    if not 0 <= int(port) <= 65535:
        raise ValueError(f"live port must be in [0, 65535], got {port}")


def clock_ns(data: bytes) -> int:
    """Sim time (ns) of a serialized ``rosgraph_msgs/Clock``.

    The CDR is a 4-byte encapsulation header (byte 1: 1 little endian, 0 big) and
    ``builtin_interfaces/Time``: int32 sec, uint32 nanosec.

    Raises:
        ValueError: ``data`` is shorter than a Clock.
    """
    if len(data) < 12:
        raise ValueError(f"a serialized Clock has 12 bytes, got {len(data)}")
    sec, nanosec = struct.unpack_from("<iI" if data[1] & 1 else ">iI", data, 4)
    return int(sec) * 1_000_000_000 + int(nanosec)


class LiveView:
    """A Foxglove WebSocket server of a set of ROS topics, on sim time.

    Args:
        topics: ``(name, msgtype, latched)`` per channel.
        typestore: rosbags typestore that knows every ``msgtype`` (for the
            ``ros2msg`` schema text).
        port: TCP port (0: any free one; see :attr:`port`).
        host: Interface to listen on.
        name: Server name shown by Foxglove.
        max_rate_Hz: Forward each topic at most this often per wall second (0: every message);
            latched topics are always forwarded.
        clock_topic: The topic whose messages (``rosgraph_msgs/Clock``) give the sim time
            (default: the graph spec's ``/clock``).

    Raises:
        OSError / RuntimeError: the port cannot be bound (the message names it).
    """

    def __init__(self, topics: Iterable[tuple[str, str, bool]], typestore: Any, port: int = DEFAULT_LIVE_PORT,
                 host: str = "127.0.0.1", name: str = "vesselbot", max_rate_Hz: float = DEFAULT_LIVE_RATE_HZ,
                 clock_topic: str | None = None) -> None:
        # deferred: the Foxglove SDK (~55 ms) loads only when a live view is served; the recorder and the CLIs
        # import this module for its defaults
        import foxglove
        from foxglove.websocket import Capability

        check_port(port)
        if not max_rate_Hz >= 0:
            raise ValueError(f"live rate must be >= 0 messages per second, got {max_rate_Hz}")
        self._period_s = 1.0 / max_rate_Hz if max_rate_Hz > 0 else 0.0
        self._last_sent: dict[str, float] = {}
        # subscriptions per channel topic, kept by the server listener: the hot path only reads this dict
        self._subscribers: dict[str, int] = {}
        self._view_wanted = False  # some client subscribes to a derived view channel (kept by the listener)
        self._ctx = foxglove.Context()
        self._channels: dict[str, Any] = {}
        self._latched: dict[str, tuple[bytes, int] | None] = {}  # the last message and its log time (ns)
        self._lock = threading.Lock()
        self._clock_topic = clock_topic if clock_topic is not None else topic_spec("clock").name
        self._time_ns: int | None = None  # the sim time (None until the first /clock: nothing to broadcast)
        self._time_sent: int | None = None  # the last broadcast
        self._time_wall = -1e9  # when (monotonic s)
        self._time_period_s = 1.0 / TIME_RATE_HZ

        def ros_channel(name: str, msgtype: str) -> Any:
            text, _ = typestore.generate_msgdef(msgtype, ros_version=2)
            schema = foxglove.Schema(name=msgtype, encoding="ros2msg", data=text.encode("utf-8"))
            return foxglove.Channel(name, schema=schema, message_encoding="cdr", context=self._ctx)

        for topic, msgtype, latched in topics:
            self._channels[topic] = ros_channel(topic, msgtype)
            if latched:
                self._latched[topic] = None
        errors_schema = foxglove.Schema(name=ERRORS_SCHEMA_NAME, encoding="jsonschema",
                                        data=json.dumps(ERRORS_SCHEMA).encode("utf-8"))
        self._views: dict[str, Any] = {}
        for v in VIEW_CHANNELS:
            self._views[v.key] = (foxglove.Channel(v.name, schema=errors_schema, message_encoding="json",
                                                   context=self._ctx)
                                  if v.msgtype == "json" else ros_channel(v.name, v.msgtype))
        self.view = DerivedView(self._send_view, lambda: self._view_wanted)
        self._view_names = {v.name for v in VIEW_CHANNELS}
        self._view_inputs = {topic_spec(k).name for v in VIEW_CHANNELS for k in v.inputs}
        view = self
        from foxglove.websocket import ServerListener  # deferred: the Foxglove SDK (see above)

        class _Listener(ServerListener):  # the protocol's no-op defaults for every other event
            def on_subscribe(self, client: Any, channel: Any) -> None:
                view._count_subscriber(channel.topic, +1)
                now_ns = view._time_ns
                if now_ns is not None:  # the new subscriber's timeline starts at the current sim time
                    view._send_time(now_ns)
                view._resend_latched(channel.topic)

            def on_unsubscribe(self, client: Any, channel: Any) -> None:
                view._count_subscriber(channel.topic, -1)

        # the SDK's server on a private loopback port; clients connect to the front's port
        self._server: Any = foxglove.start_server(name=name, host="127.0.0.1", port=0, context=self._ctx,
                                                  server_listener=_Listener(), capabilities=[Capability.Time])
        try:
            self._front: Any = SubprotocolFront(int(self._server.port), host=host, port=port)
        except BaseException:
            self._server.stop()
            raise
        self.host = host
        self.port = self._front.port

    @property
    def url(self) -> str:
        """``ws://HOST:PORT`` of the server (the bound port, also when asked for port 0)."""
        return f"ws://{self.host}:{self.port}"

    @property
    def topics(self) -> list[str]:
        """The forwarded topics (the derived view channels aside)."""
        return list(self._channels)

    def log(self, topic: str, data: bytes, t_ns: int) -> None:
        """Offer one serialized (CDR) message of ``topic`` logged at ``t_ns`` (ns; the bag's log time).

        It is sent to subscribed clients, at most at the live rate, with ``t_ns`` as its timestamp; a
        ``/clock`` message also sets the sim time (:meth:`set_time`).
        """
        ch = self._channels.get(topic)
        if ch is None:
            return
        if topic == self._clock_topic:
            with contextlib.suppress(ValueError):
                self.set_time(clock_ns(data))
        if topic in self._latched:
            with self._lock:
                self._latched[topic] = (bytes(data), int(t_ns))
            ch.log(bytes(data), log_time=int(t_ns))
            self.view.offer(topic, data, t_ns)
            return
        if self._view_wanted and topic in self._view_inputs:
            self.view.offer(topic, data, t_ns)
        if not self._subscribers.get(topic):  # no client subscribed to it
            return
        now = time.monotonic()
        if now - self._last_sent.get(topic, -1e9) < self._period_s:
            return
        self._last_sent[topic] = now
        ch.log(data, log_time=int(t_ns))

    def set_time(self, t_ns: int) -> None:
        """The sim time is now ``t_ns`` (ns): broadcast it, at most :data:`TIME_RATE_HZ` times per wall second."""
        self._time_ns = t_ns = int(t_ns)
        if t_ns != self._time_sent:
            now = time.monotonic()
            if now - self._time_wall >= self._time_period_s:
                self._send_time(t_ns, now)

    def flush_time(self) -> None:
        """Broadcast the sim time now if the last broadcast is behind it (the rate limit held it back)."""
        if self._time_ns is not None and self._time_ns != self._time_sent:
            self._send_time(self._time_ns)

    @property
    def time_ns(self) -> int | None:
        """The current sim time (ns; None before the first)."""
        return self._time_ns

    def _send_time(self, t_ns: int, now: float | None = None) -> None:
        server = self._server
        if server is None:
            return
        self._time_sent = t_ns
        self._time_wall = time.monotonic() if now is None else now
        server.broadcast_time(max(0, t_ns))

    def _send_view(self, key: str, data: bytes, t_ns: int) -> None:
        """One derived view update: the sim time first, so Foxglove receives the update at its sim time."""
        self.flush_time()
        self._views[key].log(data, log_time=int(t_ns))

    def _count_subscriber(self, topic: str, delta: int) -> None:
        """A client subscribed (+1) to or left (-1) ``topic``; keep whether a derived view is wanted."""
        with self._lock:
            self._subscribers[topic] = max(0, self._subscribers.get(topic, 0) + delta)
            self._view_wanted = any(self._subscribers.get(v) for v in self._view_names)

    def _resend_latched(self, topic: str) -> None:
        with self._lock:
            last = self._latched.get(topic)
        if last is not None:
            data, t_ns = last
            self._channels[topic].log(data, log_time=t_ns)

    def close(self) -> None:
        """Broadcast the last sim time, stop the server and its port (idempotent)."""
        if self._server is not None:
            self.flush_time()
        server, self._server = self._server, None
        if server is not None:
            server.stop()
            self._front.close()
