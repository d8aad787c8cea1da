"""The launcher's own node: the nodes' diagnostics, the run's time series, the users' slots.

:class:`Monitor` subscribes to ``/diagnostics`` (names from the graph spec, in
the run's namespace), which carries every node's counts, progress and real-time
figures, and to the outputs of every role left to a user's node
(``--without``), whose messages it counts: a user's node reports no
diagnostics, so these counts are what the launcher knows it published.  It takes
no per-tick topic of our own nodes: after the run it asks each of them for the
series it published (``<role>/series``, :mod:`vesselbot_ros.nodes.series`), so
the launcher costs the loop nothing per tick.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from vesselbot_ros.errors import RunError
from vesselbot_ros.graph_spec import (
    DEFAULT_NAMESPACE,
    NODE_NAMES,
    TOPICS,
    WIRE_STRINGS,
    import_type,
    loop_roles,
    qos_profile,
    remap_args,
    role,
    series_service_key,
    service,
    topic,
)
from vesselbot_ros.nodes.calls import Resend
from vesselbot_ros.nodes.recorder_node import LIVE_URL_KEY
from vesselbot_ros.nodes.series import SeriesLog, empty_series, series_from_response
from vesselbot_ros.nodes.wire import codec_for

__all__ = ["Monitor", "counts_with_prefix"]


def counts_with_prefix(diag: dict[str, str], prefix: str) -> dict[str, int]:
    """``{"<prefix><topic>": "n"}`` diagnostics -> ``{topic: n}``."""
    out = {}
    for k, v in diag.items():
        if k.startswith(prefix):
            with contextlib.suppress(ValueError):
                out[k[len(prefix):]] = int(v)
    return out


class Monitor:
    """Every node's latest diagnostics, and the run's series after it.

    Args:
        context: rclpy Context of the run's domain.
        n: Number of ticks of the run.
        dt: Control period (s).
        namespace: The graph's namespace (None: default).
        user_roles: Roles left to users' nodes; their outputs are counted.
        dims: Axes of the scenario's vectors (``Scenario.dims``): the width of the run's vector series.
    """

    def __init__(self, context: Any, n: int, dt: float, namespace: str | None = None,
                 user_roles: Sequence[str] = (), dims: int = 2, frames: bool = False) -> None:
        # deferred: rclpy, the message packages and nodes.process (which imports rclpy); launch.graph imports this
        # module ROS-free (its exceptions, tests)
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from vesselbot_msgs.srv import GetSeries, RunControl

        from vesselbot_ros.nodes.process import make_executor

        self.n = n
        self.dt = dt
        self.dims = dims
        args = remap_args(namespace)
        self.node = rclpy.create_node("vesselbot_launcher", namespace=DEFAULT_NAMESPACE, context=context,
                                      cli_args=["--ros-args", *args] if args else None)
        self.ex = make_executor(context)
        self.ex.add_node(self.node)
        from rclpy.task import Future  # deferred: rclpy (see above)

        self._never = Future()  # spin() handles every event of its slice, then returns
        self.diag: dict[str, dict[str, str]] = {}
        #: wall time (time.monotonic) at which each node's latest diagnostics arrived
        self.diag_wall: dict[str, float] = {}
        self.diag_level: dict[str, tuple[int, str]] = {}
        self.user_roles = tuple(user_roles)
        #: messages received per canonical topic name from the users' nodes
        self.user_counts: dict[str, int] = {}
        #: wall times of the first and last truth from a user's plant
        self.t_first_truth: float | None = None
        self.t_last_truth: float | None = None
        sub = self.node.create_subscription
        sub(DiagnosticArray, topic("diagnostics").rel, self._on_diag, qos_profile(topic("diagnostics")))
        # the per-tick topics our nodes publish are not subscribed to: each node serves its series at the end
        # (nodes/series.py).  A user's node serves nothing, so its outputs arrive here, raw (one bytes copy per
        # message), counted, and decoded after the run.
        self._types: dict[str, Any] = {}
        self._raw: dict[str, list[bytes]] = {}
        self._user_series_keys: list[str] = []
        for r in user_roles:
            for key in role(r).outputs_for(frames):
                t = topic(key)
                self.user_counts[t.name] = 0
                self._types[key] = import_type(t.msgtype)
                if t.series:
                    self._raw[key] = []
                    self._user_series_keys.append(key)
                sub(self._types[key], t.rel, self._user_callback(key), qos_profile(t), raw=True)
        self.run_control = self.node.create_client(RunControl, service("run_control").rel)
        spec = service("set_simulation_state")
        self.set_simulation_state = self.node.create_client(import_type(spec.srvtype), spec.rel)
        self.series_clients = {
            r: self.node.create_client(GetSeries, service(series_service_key(r)).rel)
            for r in loop_roles(frames) if r not in self.user_roles and series_service_key(r) in role(r).services}
        self._series_futures: dict[str, Resend] = {}
        #: per slot's topics: what the graph last showed of its nodes, and since when (wall; :meth:`slot_settled`)
        self._slot_seen: dict[tuple[str, ...], tuple[Any, float]] = {}

    def _user_callback(self, key: str) -> Any:
        name = topic(key).name
        store = self._raw[key].append if key in self._raw else None
        counts = self.user_counts
        is_truth = key == "truth"

        def on_message(data: bytes) -> None:
            if is_truth:
                now = time.monotonic()
                if self.t_first_truth is None:
                    self.t_first_truth = now
                self.t_last_truth = now
            if store is not None:
                store(data)
            counts[name] += 1
        return on_message

    def _decode(self, key: str, data: bytes) -> Any:
        from rclpy.serialization import deserialize_message  # deferred: rclpy (see __init__)

        return deserialize_message(data, self._types[key])

    @property
    def max_tick(self) -> int:
        """The latest tick of the plant so far (-1 before the first): its diagnostics, or a user's truth."""
        raw = self._raw.get("truth")
        if raw is not None:
            return int(self._decode("truth", raw[-1]).tick) if raw else -1
        d = self.diag.get(NODE_NAMES["plant"], {})
        return int(d.get("tick", -1)) if d.get(f"published:{topic('truth').name}", "0") != "0" else -1

    def run_wall_s(self, fallback: float) -> float:
        """Wall time (s) from tick 0 to the last tick: the plant's own figure, or a user's truth as it arrived."""
        if self.t_first_truth is not None and self.t_last_truth is not None:
            return self.t_last_truth - self.t_first_truth
        d = self.diag.get(NODE_NAMES["plant"], {})
        return float(d["run_wall_s"]) if "run_wall_s" in d else fallback

    def watch_coil(self) -> None:
        """Start taking the coil state (raw): what :attr:`last_coil` reads (a node died: the watchdog's ramp)."""
        if "coil_state" in self._raw:
            return
        t = topic("coil_state")
        self._types["coil_state"] = import_type(t.msgtype)
        self._raw["coil_state"] = []
        store: Callable[[Any], None] = self._raw["coil_state"].append  # raw=True: the callback gets the CDR bytes
        self.node.create_subscription(self._types["coil_state"], t.rel, lambda data: store(data), qos_profile(t),
                                      raw=True)

    @property
    def last_coil(self) -> tuple[int, tuple[float, float, float], bool] | None:
        """The latest coil state since :meth:`watch_coil`: (tick, applied (x, y, z), watchdog_active)."""
        raw = self._raw.get("coil_state")
        if not raw:
            return None
        m = self._decode("coil_state", raw[-1])
        return int(m.tick), (float(m.applied.x), float(m.applied.y), float(m.applied.z)), bool(m.watchdog_active)

    def request_series(self) -> None:
        """Ask each of our nodes for its run series (after the run); :meth:`series_ready` tells when all came."""
        from vesselbot_msgs.srv import GetSeries  # deferred: a message package (see __init__)

        self._series_futures = {r: Resend.service(c, GetSeries.Request()) for r, c in self.series_clients.items()}

    def series_ready(self) -> bool:
        """True once every node asked by :meth:`request_series` answered."""
        return all(f.done() for f in self._series_futures.values())

    def series(self) -> dict[str, np.ndarray]:
        """The run's series: from our nodes' answers and the users' nodes' messages (unknown: NaN / False).

        Raises:
            RunError: a node's answer is malformed or says it has not finished.
        """
        out = empty_series(self.n, self.dims)
        for r, fut in self._series_futures.items():
            resp = fut.result()
            if resp is None or not resp.success:
                raise RunError(f"node {NODE_NAMES[r]} did not serve its run series: "
                                     f"{'no answer' if resp is None else resp.message}")
            try:
                got = series_from_response(resp)
            except ValueError as exc:
                raise RunError(f"node {NODE_NAMES[r]} served malformed series: {exc}") from None
            for name, arr in got.items():
                if arr.shape[0] != self.n:
                    raise RunError(f"node {NODE_NAMES[r]} served {arr.shape[0]} rows, the run has {self.n}")
                out[name] = arr
        keys = self._user_series_keys
        if keys:
            log = SeriesLog(keys, self.n, self.dt, self.dims)
            for key in keys:
                codec = codec_for(self._types[key], WIRE_STRINGS)  # the series logs read flat forms
                for data in self._raw[key]:
                    log.add(key, codec.flatten(self._decode(key, data)))  # type: ignore[union-attr]  # series types have codecs
            out.update(log.as_dict())
        return out

    def _on_diag(self, m: Any) -> None:
        now = time.monotonic()
        for st in m.status:
            self.diag[st.name] = {kv.key: kv.value for kv in st.values}
            self.diag_wall[st.name] = now
            lvl = int.from_bytes(st.level, "little") if isinstance(st.level, bytes) else int(st.level)
            self.diag_level[st.name] = (lvl, st.message)

    def spin(self, dt: float = 0.05) -> None:
        """Handle everything that arrives during ``dt`` s (one call, not one per message)."""
        self.ex.spin_until_future_complete(self._never, timeout_sec=dt)

    def recorder_subscribed(self) -> bool:
        """True once the recorder subscribes to every topic of the spec."""
        name = NODE_NAMES["recorder"]
        return all(any(i.node_name == name for i in self.node.get_subscriptions_info_by_topic(self.resolved(t.key)))
                   for t in TOPICS)

    def resolved(self, key: str) -> str:
        """Absolute name of topic ``key`` as this node sees it (namespace and remaps applied)."""
        return str(self.node.resolve_topic_name(topic(key).rel))

    def publishes(self, key: str) -> bool:
        """True if some node publishes topic ``key``."""
        return self.node.count_publishers(self.resolved(key)) > 0

    def subscribers(self, key: str) -> int:
        """Number of subscriptions to topic ``key``."""
        return int(self.node.count_subscribers(self.resolved(key)))

    def slot_settled(self, keys: Sequence[str], hold_s: float) -> bool:
        """True once some node publishes each of topics ``keys`` (a user's node in a slot) and what the graph shows
        of those nodes (their names and their subscriptions' topics) has not changed for ``hold_s`` (wall).

        DDS announces a node's publications and subscriptions on separate built-in writers: seeing a user's node
        publish does not mean its subscriptions are known yet.  Their publishers' matches are then checked
        against the count that includes them (``_wired``), so no input of tick 0 is sent before they match.
        """
        nodes: set[tuple[str, str]] = set()
        for k in keys:
            infos = self.node.get_publishers_info_by_topic(self.resolved(k))
            if not infos:
                return False
            nodes.update((i.node_name, i.node_namespace) for i in infos)
        from rclpy.node import NodeNameNonExistentError  # deferred: rclpy (see __init__)

        seen = []
        for name, ns in sorted(nodes):
            try:
                subs = sorted(t for t, _types in self.node.get_subscriber_names_and_types_by_node(name, ns))
            except NodeNameNonExistentError:  # its endpoints are known before the node itself
                return False
            seen.append((name, ns, tuple(subs)))
        now = time.monotonic()
        slot, shown = tuple(keys), tuple(seen)
        if slot not in self._slot_seen or self._slot_seen[slot][0] != shown:
            self._slot_seen[slot] = (shown, now)
        return now - self._slot_seen[slot][1] >= hold_s

    def published(self, roles: Sequence[str], require_finished: bool = False) -> dict[str, int] | None:
        """Per canonical topic: what our nodes (diagnostics) and the users' nodes (counted here) published.

        None while a node's diagnostics are missing (or, with ``require_finished``, not final).
        """
        out: dict[str, int] = dict(self.user_counts)
        for r in roles:
            d = self.diag.get(NODE_NAMES[r])
            if d is None or (require_finished and d.get("finished") != "true"):
                return None
            for t, c in counts_with_prefix(d, "published:").items():
                out[t] = out.get(t, 0) + c
        out.pop(topic("diagnostics").name, None)  # every node publishes there, the recorder too
        return out

    def recorder_matched(self) -> bool:
        """True once the recorder's reader of every topic matched every publisher the graph has of it.

        A reader that has not yet matched a writer drops what it sends (volatile
        durability), so the launcher starts the run only after this.
        """
        rec = self.diag.get(NODE_NAMES["recorder"])
        if rec is None:
            return False
        matched = counts_with_prefix(rec, "matched_publishers:")
        return all(matched.get(t.name, 0) >= self.node.count_publishers(self.resolved(t.key)) for t in TOPICS
                   if t.key != "diagnostics")

    def recorder_live_url(self) -> str | None:
        """The live view's address as the recorder reports it once its server accepts connections (else None)."""
        rec = self.diag.get(NODE_NAMES["recorder"])
        return None if rec is None else rec.get(LIVE_URL_KEY)

    def recorder_received(self) -> dict[str, int] | None:
        """The recorder's ``received:<topic>`` counts (None before its first diagnostics)."""
        rec = self.diag.get(NODE_NAMES["recorder"])
        return None if rec is None else counts_with_prefix(rec, "received:")

    def close(self) -> None:
        """Destroy the node and its executor."""
        with contextlib.suppress(Exception):
            self.ex.remove_node(self.node)
            self.ex.shutdown()
            self.node.destroy_node()
