"""Live view: the graph's topics over the Foxglove WebSocket protocol (``vesselbot run --live``).

:class:`LiveView` runs the Foxglove SDK's WebSocket server (``foxglove-sdk`` on
PyPI; we never implement the protocol ourselves) and advertises one channel per
topic it is given: ``cdr`` messages with their ``ros2msg`` schema (the full
definition with its dependencies, the same text the bag embeds), so Foxglove
decodes them exactly as it decodes a recorded bag.  The channels come from
the graph spec (:data:`vesselbot_ros.graph_spec.TOPICS`): a port added there
appears in the live view with no view code.

Messages are logged as the bytes the publisher sent (the recorder's raw
subscriptions feed both the bag and this server, so ``--live`` adds no DDS
reader to the loop).  A viewer needs far fewer than the loop's 1000 ticks per
second: each topic is forwarded at most ``max_rate_Hz`` times per wall second
(default :data:`DEFAULT_LIVE_RATE_HZ`; 0: every message), and nothing is
forwarded or derived while no client subscribes, so the live view's cost
does not grow with the control rate (``bench/bench_live.py``).  Latched topics (the vessel markers, the reference path)
are sent once when published; a client that subscribes later gets the last
one again on subscription, as a transient-local subscriber would.

Besides the topics it serves the derived channels of
:data:`vesselbot_ros.graph_spec.VIEW_CHANNELS` (:mod:`vesselbot_ros.live_view`):
the scene as markers and the error time series, at most 20 updates per second.

The server listens on ``127.0.0.1`` only.  Connect Foxglove (desktop app or
browser) with *Open connection -> Foxglove WebSocket* ``ws://127.0.0.1:PORT``
and load ``config/foxglove/vesselbot.json`` as the layout.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable
from typing import Any

__all__ = ["LiveView", "DEFAULT_LIVE_PORT", "DEFAULT_LIVE_RATE_HZ", "check_port"]

#: Foxglove's default WebSocket port.
DEFAULT_LIVE_PORT = 8765
#: Messages per topic and wall second forwarded to the viewer, at most.
DEFAULT_LIVE_RATE_HZ = 50.0


def check_port(port: int) -> None:
    """Raise ValueError naming ``port`` if it is not a TCP port number (0: any free port)."""
    if not 0 <= int(port) <= 65535:
        raise ValueError(f"live port must be in [0, 65535], got {port}")


class LiveView:
    """A Foxglove WebSocket server of a set of ROS topics.

    Args:
        topics: ``(name, msgtype, latched)`` per channel.
        typestore: rosbags typestore that knows every ``msgtype`` (for the
            ``ros2msg`` schema text).
        port: TCP port (0: any free one; see :attr:`port`).
        host: Interface to listen on.
        name: Server name shown by Foxglove.
        max_rate_Hz: Forward each topic at most this often per wall second (0: every message);
            latched topics are always forwarded.

    Raises:
        OSError / RuntimeError: the port cannot be bound (the message names it).
    """

    def __init__(self, topics: Iterable[tuple[str, str, bool]], typestore: Any, port: int = DEFAULT_LIVE_PORT,
                 host: str = "127.0.0.1", name: str = "vesselbot", max_rate_Hz: float = DEFAULT_LIVE_RATE_HZ) -> None:
        import foxglove

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
        self._latched: dict[str, bytes | None] = {}
        self._lock = threading.Lock()
        from vesselbot_ros.graph_spec import VIEW_CHANNELS
        from vesselbot_ros.graph_spec import topic as topic_spec
        from vesselbot_ros.live_view import ERRORS_SCHEMA, DerivedView

        def ros_channel(name: str, msgtype: str) -> Any:
            text, _ = typestore.generate_msgdef(msgtype, ros_version=2)
            schema = foxglove.Schema(name=msgtype, encoding="ros2msg", data=text.encode("utf-8"))
            return foxglove.Channel(name, schema=schema, message_encoding="cdr", context=self._ctx)

        for topic, msgtype, latched in topics:
            self._channels[topic] = ros_channel(topic, msgtype)
            if latched:
                self._latched[topic] = None
        self._views: dict[str, Any] = {}
        for v in VIEW_CHANNELS:
            self._views[v.key] = (foxglove.Channel(v.name, schema=ERRORS_SCHEMA, context=self._ctx)
                                  if v.msgtype == "json" else ros_channel(v.name, v.msgtype))
        self.view = DerivedView(lambda key, data, t_ns: self._views[key].log(data, log_time=int(t_ns)),
                                lambda: self._view_wanted)
        self._view_names = {v.name for v in VIEW_CHANNELS}
        self._view_inputs = {topic_spec(k).name for v in VIEW_CHANNELS for k in v.inputs}
        view = self
        from foxglove.websocket import ServerListener

        class _Listener(ServerListener):  # the protocol's no-op defaults for every other event
            def on_subscribe(self, client: Any, channel: Any) -> None:
                view._count_subscriber(channel.topic, +1)
                view._resend_latched(channel.topic)

            def on_unsubscribe(self, client: Any, channel: Any) -> None:
                view._count_subscriber(channel.topic, -1)

        self._server = foxglove.start_server(name=name, host=host, port=port, context=self._ctx,
                                             server_listener=_Listener())
        self.host = host
        self.port = int(self._server.port)

    @property
    def url(self) -> str:
        """``ws://HOST:PORT`` of the server."""
        return f"ws://{self.host}:{self.port}"

    @property
    def topics(self) -> list[str]:
        """The forwarded topics (the derived view channels aside)."""
        return list(self._channels)

    def log(self, topic: str, data: bytes, t_ns: int) -> None:
        """Offer one serialized (CDR) message of ``topic``: sent to subscribed clients, at most at the live rate."""
        ch = self._channels.get(topic)
        if ch is None:
            return
        if topic in self._latched:
            with self._lock:
                self._latched[topic] = bytes(data)
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

    def _count_subscriber(self, topic: str, delta: int) -> None:
        """A client subscribed (+1) to or left (-1) ``topic``; keep whether a derived view is wanted."""
        with self._lock:
            self._subscribers[topic] = max(0, self._subscribers.get(topic, 0) + delta)
            self._view_wanted = any(self._subscribers.get(v) for v in self._view_names)

    def _resend_latched(self, topic: str) -> None:
        with self._lock:
            data = self._latched.get(topic)
        if data is not None:
            self._channels[topic].log(data, log_time=time.time_ns())

    def close(self) -> None:
        """Stop the server (idempotent)."""
        server, self._server = self._server, None
        if server is not None:
            server.stop()
