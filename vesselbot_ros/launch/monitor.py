"""The launcher's own node: the run's time series, the nodes' diagnostics, the users' slots.

:class:`Monitor` subscribes to truth, estimate, reference, coil state and
``/diagnostics`` (names from the graph spec, in the run's namespace), plus the
outputs of every role left to a user's node (``--without``), whose messages it
counts: a user's node reports no diagnostics, so these counts are what the
launcher knows it published.  It is not part of the loop, so it cannot slow it
down beyond the DDS fan-out.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from vesselbot_ros.graph_spec import (
    DEFAULT_NAMESPACE,
    NODE_NAMES,
    TOPICS,
    import_type,
    qos_profile,
    remap_args,
    role,
    service,
    topic,
)

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
    """Collects the run's per-tick series and every node's latest diagnostics.

    Args:
        context: rclpy Context of the run's domain.
        n: Number of ticks of the run.
        dt: Control period (s).
        namespace: The graph's namespace (None: default).
        user_roles: Roles left to users' nodes; their outputs are counted.
    """

    def __init__(self, context: Any, n: int, dt: float, namespace: str | None = None,
                 user_roles: Sequence[str] = ()) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import Odometry

        from vesselbot_msgs.msg import CoilState, PlantState, ReferenceSample
        from vesselbot_msgs.srv import RunControl
        from vesselbot_ros.nodes.base import make_executor

        self.n = n
        self.dt = dt
        args = remap_args(namespace)
        self.node = rclpy.create_node("vesselbot_launcher", namespace=DEFAULT_NAMESPACE, context=context,
                                      cli_args=["--ros-args", *args] if args else None)
        self.ex = make_executor(context)
        self.ex.add_node(self.node)
        from rclpy.task import Future

        self._never = Future()  # spin() handles every event of its slice, then returns
        self.p_true = np.full((n, 2), np.nan)
        self.v_true = np.full((n, 2), np.nan)
        self.contact = np.zeros(n, dtype=bool)
        self.x_hat = np.full((n, 2), np.nan)
        self.z_hat = np.full((n, 2), np.nan)
        self.p_ref = np.full((n, 2), np.nan)
        self.g_applied = np.full((n, 2), np.nan)
        self.saturated = np.zeros(n, dtype=bool)
        self.slew = np.zeros((n, 2), dtype=bool)
        self.got = {"truth": 0, "estimate": 0, "reference": 0, "coil_state": 0}
        self.diag: dict[str, dict[str, str]] = {}
        self.diag_level: dict[str, tuple[int, str]] = {}
        self.t_first_truth: float | None = None
        self.t_last_truth: float | None = None
        #: messages received per canonical topic name from the users' nodes
        self.user_counts: dict[str, int] = {}
        sub = self.node.create_subscription
        # the per-tick topics arrive raw and are decoded after the run (or on demand): the launcher
        # then costs the loop one bytes copy per message, and never falls behind a fast graph
        self._types = {"truth": PlantState, "estimate": Odometry, "reference": ReferenceSample, "coil_state": CoilState}
        self._raw: dict[str, list[bytes]] = {key: [] for key in self._types}
        for key, msg_cls in self._types.items():
            sub(msg_cls, topic(key).rel, self._raw_callback(key), qos_profile(topic(key)), raw=True)
        sub(DiagnosticArray, topic("diagnostics").rel, self._on_diag, qos_profile(topic("diagnostics")))
        for r in user_roles:
            for key in role(r).outputs:
                t = topic(key)
                self.user_counts[t.name] = 0
                sub(import_type(t.msgtype), t.rel, lambda _data, name=t.name: self._count_user(name),
                    qos_profile(t), raw=True)
        self.run_control = self.node.create_client(RunControl, service("run_control").rel)
        spec = service("set_simulation_state")
        self.set_simulation_state = self.node.create_client(import_type(spec.srvtype), spec.rel)
        self._decoded = 0

    def _raw_callback(self, key: str) -> Any:
        store = self._raw[key].append
        got = self.got

        if key == "truth":
            def on_truth(data: bytes) -> None:
                now = time.monotonic()
                if self.t_first_truth is None:
                    self.t_first_truth = now
                self.t_last_truth = now
                store(data)
                got["truth"] += 1
            return on_truth

        def on_message(data: bytes) -> None:
            store(data)
            got[key] += 1
        return on_message

    def _decode(self, key: str, data: bytes) -> Any:
        from rclpy.serialization import deserialize_message

        return deserialize_message(data, self._types[key])

    @property
    def max_tick(self) -> int:
        """The latest tick of the plant's truth so far (-1 before the first)."""
        raw = self._raw["truth"]
        return int(self._decode("truth", raw[-1]).tick) if raw else -1

    @property
    def last_coil(self) -> tuple[int, tuple[float, float], bool] | None:
        """The latest coil state: (tick, applied (x, z), watchdog_active)."""
        raw = self._raw["coil_state"]
        if not raw:
            return None
        m = self._decode("coil_state", raw[-1])
        return int(m.tick), (float(m.applied.x), float(m.applied.z)), bool(m.watchdog_active)

    def decode_all(self) -> None:
        """Fill the per-tick arrays from every message received (after the run)."""
        for data in self._raw["truth"]:
            self._on_truth(self._decode("truth", data))
        for data in self._raw["estimate"]:
            self._on_estimate(self._decode("estimate", data))
        for data in self._raw["reference"]:
            self._on_reference(self._decode("reference", data))
        for data in self._raw["coil_state"]:
            self._on_coil(self._decode("coil_state", data))

    def _count_user(self, name: str) -> None:
        self.user_counts[name] += 1

    def _tick(self, stamp: Any) -> int | None:
        from vesselbot_ros.nodes.conversions import ns_of_stamp, tick_of_ns

        k, ok = tick_of_ns(ns_of_stamp(stamp), self.dt)
        return k if ok and 0 <= k < self.n else None

    def _on_truth(self, m: Any) -> None:
        k = int(m.tick)
        if 0 <= k < self.n:
            self.p_true[k] = (m.position.x, m.position.z)
            self.v_true[k] = (m.velocity.x, m.velocity.z)
            self.contact[k] = m.in_contact

    def _on_estimate(self, m: Any) -> None:
        k = self._tick(m.header.stamp)
        if k is not None:
            self.x_hat[k] = (m.pose.pose.position.x, m.pose.pose.position.z)
            self.z_hat[k] = (m.twist.twist.linear.x, m.twist.twist.linear.z)

    def _on_reference(self, m: Any) -> None:
        k = int(m.tick)
        if 0 <= k < self.n:
            self.p_ref[k] = (m.position.x, m.position.z)

    def _on_coil(self, m: Any) -> None:
        k = int(m.tick)
        if 0 <= k < self.n:
            self.g_applied[k] = (m.applied.x, m.applied.z)
            self.saturated[k] = m.saturated
            self.slew[k] = (m.slew_limited_x, m.slew_limited_z)

    def _on_diag(self, m: Any) -> None:
        for st in m.status:
            self.diag[st.name] = {kv.key: kv.value for kv in st.values}
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
