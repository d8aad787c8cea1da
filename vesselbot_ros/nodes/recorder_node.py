"""Recorder node: every topic of the graph into a rosbag2 (MCAP) bag, bytes as published.

Ports (see :mod:`vesselbot_ros.graph_spec`):

* inputs: every topic of :data:`~vesselbot_ros.graph_spec.TOPICS` (raw, i.e.
  serialized subscriptions: no deserialisation, the CDR bytes are written as
  received), with the topic's QoS (latched topics transient local), plus the
  ``extra_topics`` parameter's ``"name:type"`` entries;
* output ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``, 1 Hz wall and
  after each flush): status ``vesselbot_recorder`` with KeyValues
  ``received:<topic>`` = messages written for that topic;
* with ``live_port`` set, the KeyValue ``live_url`` = ``ws://127.0.0.1:PORT``, the
  live view's bound port, published once the server accepts connections;
* service ``/vesselbot/recorder/flush`` (``std_srvs/Trigger``): closes the
  pending MCAP chunk, flushes and fsyncs the file, and returns the counts as
  JSON in ``message``.

Parameters: ``output_dir`` (the bag directory; may exist, e.g. with
``logs/``, but must not hold a bag), ``run_metadata`` (JSON string; pass it
YAML-quoted, see :func:`recorder_command`) or ``run_metadata_file`` (path to
a JSON file), ``extra_topics`` (string array), ``flush_period_s`` (wall-clock
period of chunk flushes, default 0.5 s), ``min_free_mb`` (default 256),
``use_sim_time`` (log times on the ROS clock instead of the system clock),
``compression`` (MCAP chunk compression: ``none``, ``zstd_fast``, ``zstd_small``,
rosbag2's storage presets, see :data:`vesselbot_ros.bag.writer.COMPRESSION_PRESETS`),
``live_rate_Hz`` (messages per topic and wall second forwarded live, at most; 0: all),
``live_port`` (>= 0: also serve every topic live over the Foxglove WebSocket
protocol on that port, :class:`vesselbot_ros.live.LiveView`; -1: off).  With
``live_port`` set, ``output_dir`` may be empty: live view only, no bag.

The live view rides on the recorder's raw subscriptions, so ``--live`` adds
no reader to the loop's topics; with it off the callback is the bag write
alone.

Durability: a chunk is written to the file when it reaches 1 MiB (rosbags'
threshold) or every ``flush_period_s`` of wall time, whichever comes first, so
a hard kill loses at most ``flush_period_s`` of data (at 1 kHz control the
graph writes about 1.8 MB/s, so a 1 MiB chunk spans about 0.6 s).

Signals: SIGINT and SIGTERM finalise the bag (``metadata.yaml``, MCAP
summary) and exit 0.  A bag directory that cannot be written (missing
permissions, full disk) is reported before any subscription, exit code 1.
"""

from __future__ import annotations

import json
import signal
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from vesselbot_ros.errors import BagError
from vesselbot_ros.graph_spec import (
    DEFAULT_NAMESPACE,
    NODE_NAMES,
    TOPICS,
    import_type,
    qos_profile,
    remap_args,
    service,
    topic,
)
from vesselbot_ros.live import DEFAULT_LIVE_RATE_HZ, LiveView

__all__ = ["RecorderNode", "recorder_command", "main", "FLUSH_SERVICE", "STATUS_NAME", "LIVE_URL_KEY"]

FLUSH_SERVICE = service("recorder_flush").name
SUBSCRIPTION_DEPTH = 10_000  # messages buffered per topic while the recorder is busy (10 s at 1 kHz)
STATUS_NAME = NODE_NAMES["recorder"]
#: The recorder's diagnostics key of the live view's address (``ws://127.0.0.1:PORT``, the bound port).
LIVE_URL_KEY = "live_url"


def recorder_command(
    output_dir: str | Path | None,
    run_metadata: Mapping[str, Any] | None = None,
    extra_topics: Sequence[str] = (),
    python: str | None = None,
    namespace: str | None = None,
    compression: str = "none",
    live_port: int | None = None,
    live_rate_Hz: float | None = None,
    min_free_mb: int | None = None,
) -> list[str]:
    """The argv that starts a recorder (the launcher's and replay's way to start one).

    Args:
        output_dir: The bag directory to create.
        run_metadata: The run's description; JSON-encoded and YAML-quoted so
            that rcl's parameter parser keeps it a string.
        extra_topics: ``"name:type"`` entries recorded besides the graph's topics.
        python: Interpreter (default: this one).
        namespace: The graph's namespace (None: the default one).
        compression: MCAP chunk compression preset (``none``, ``zstd_fast``, ``zstd_small``).
        live_port: Serve the topics live on this port (None: no live view).
            ``output_dir`` None: live view only.
        live_rate_Hz: Messages per topic and wall second forwarded live, at most (0: all; None: the default).
        min_free_mb: Free space the recorder checks for before it opens the bag (MiB; None: its default, 256;
            the launcher passes 0: it checked the run's own estimate before it started anything).
    """
    argv = [python or sys.executable, "-m", "vesselbot_ros.nodes.recorder_node", "--ros-args", *remap_args(namespace),
            "-p", f"output_dir:={_yaml_str(str(output_dir or ''))}"]
    if live_port is not None:
        argv += ["-p", f"live_port:={int(live_port)}"]
    if live_rate_Hz is not None:
        argv += ["-p", f"live_rate_Hz:={float(live_rate_Hz)!r}"]
    if run_metadata is not None:
        argv += ["-p", f"run_metadata:={_yaml_str(json.dumps(dict(run_metadata), sort_keys=True))}"]
    if compression != "none":
        argv += ["-p", f"compression:={_yaml_str(compression)}"]
    if min_free_mb is not None:
        argv += ["-p", f"min_free_mb:={int(min_free_mb)}"]
    if extra_topics:
        argv += ["-p", "extra_topics:=[" + ", ".join(_yaml_str(t) for t in extra_topics) + "]"]
    return argv


def _yaml_str(text: str) -> str:
    """A YAML single-quoted scalar (rcl parses ``-p`` values as YAML)."""
    return "'" + text.replace("'", "''") + "'"


def parse_extra_topics(entries: Sequence[str]) -> list[tuple[str, str]]:
    """Parse ``"name:type"`` entries; raise ValueError naming a bad one."""
    out = []
    for e in entries:
        if not e:
            continue
        name, sep, msgtype = e.partition(":")
        if not sep or not name.startswith("/") or msgtype.count("/") != 2:
            raise ValueError(f"extra_topics entry {e!r} must be '/topic/name:pkg/msg/Type'")
        out.append((name, msgtype))
    return out


class RecorderNode:
    """Subscribes raw to the graph's topics and writes them into a :class:`BagWriter`.

    Built in two steps so that the bag directory is checked before any
    subscription: construct (declares parameters), then :meth:`start`.
    """

    def __init__(self, context: Any = None) -> None:
        # deferred: rclpy and the message packages load in the recorder process only; the launcher imports this
        # module ROS-free (launch.graph and monitor, for recorder_command and LIVE_URL_KEY)
        from rclpy.node import Node
        from rclpy.parameter import Parameter

        self.node = Node(NODE_NAMES["recorder"], namespace=DEFAULT_NAMESPACE, context=context)
        n = self.node
        n.declare_parameter("output_dir", "")
        n.declare_parameter("run_metadata", "")
        n.declare_parameter("run_metadata_file", "")
        n.declare_parameter("extra_topics", Parameter.Type.STRING_ARRAY)
        n.declare_parameter("flush_period_s", 0.5)
        n.declare_parameter("min_free_mb", 256)
        n.declare_parameter("compression", "none")
        n.declare_parameter("live_port", -1)
        n.declare_parameter("live_rate_Hz", DEFAULT_LIVE_RATE_HZ)
        self.bag: Any = None
        self._subs: list[Any] = []
        self._sub_names: list[str] = []  # the canonical topic name of each subscription
        self._matched: list[int] = []  # publishers each subscription matched, as last reported
        self.write_error: OSError | None = None  # set when the disk fills; main() stops
        self._diag_pub: Any = None
        self.live: Any = None  # the LiveView, when live_port >= 0

    def _param(self, name: str) -> Any:
        from rclpy.exceptions import ParameterUninitializedException  # deferred: rclpy (see __init__)

        try:
            return self.node.get_parameter(name).value
        except ParameterUninitializedException:
            return None

    def start(self) -> None:
        """Check the output directory, open the bag, subscribe; raise BagError/ValueError on bad input."""
        # deferred: rclpy and a message package (see __init__)
        from rclpy.clock import Clock, ClockType
        from std_srvs.srv import Trigger

        # deferred: rosbags (0.1 s to import) loads in the recorder process only; the launcher imports this module
        # for recorder_command and LIVE_URL_KEY
        from vesselbot_ros.bag.writer import BagWriter, check_output_dir, make_typestore

        out = str(self._param("output_dir") or "")
        live_port = int(self._param("live_port"))
        if not out and live_port < 0:
            raise BagError("parameter output_dir is required (the bag directory to create), unless live_port is set")
        meta_text = str(self._param("run_metadata") or "")
        meta_file = str(self._param("run_metadata_file") or "")
        if meta_file:
            try:
                meta_text = Path(meta_file).read_text(encoding="utf-8")
            except OSError as exc:
                raise BagError(f"cannot read run_metadata_file {meta_file}: {exc}") from None
        try:
            run_metadata = json.loads(meta_text) if meta_text else {}
        except json.JSONDecodeError as exc:
            raise BagError(f"parameter run_metadata is not valid JSON ({exc}): {meta_text[:80]!r}") from None
        if not isinstance(run_metadata, dict):
            raise BagError(f"parameter run_metadata must be a JSON object, got {type(run_metadata).__name__}")
        extra = parse_extra_topics(self._param("extra_topics") or [])
        path = check_output_dir(out, min_free_bytes=int(self._param("min_free_mb")) * 2**20) if out else None

        ts = make_typestore([t for _, t in extra])
        if path is not None:
            self.bag = BagWriter(path, run_metadata=run_metadata, typestore=ts,
                                 compression=str(self._param("compression") or "none")).open()
        n = self.node
        use_sim = bool(n.get_parameter("use_sim_time").value)
        clock = n.get_clock()
        now = (lambda: clock.now().nanoseconds) if use_sim else time.time_ns

        # (name in the bag: canonical, name subscribed: relative to the node namespace, type, QoS, latched)
        specs: list[tuple[str, str, str, Any, bool]] = [
            (s.name, s.rel, s.msgtype, qos_profile(s), s.qos == "reliable_latched") for s in TOPICS]
        known = {s[0] for s in specs}
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # deferred: rclpy (see __init__)

        for name, msgtype in extra:
            if name in known:
                continue
            specs.append((name, name, msgtype, QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                                                    reliability=ReliabilityPolicy.RELIABLE,
                                                    durability=DurabilityPolicy.VOLATILE), False))
            known.add(name)
        if live_port >= 0:
            try:
                self.live = LiveView([(name, msgtype, latched) for name, _, msgtype, _, latched in specs], ts,
                                     port=live_port, max_rate_Hz=float(self._param("live_rate_Hz")))
            except Exception as exc:  # noqa: BLE001 - the SDK raises its own types for a busy port
                raise BagError(f"live view: cannot serve on port {live_port}: {exc}") from None
            # the server accepts connections from here on (LiveView listens before it returns)
            n.get_logger().info(f"live view on {self.live.url}")
            print(f"vesselbot recorder: live view on {self.live.url}", flush=True)
        for name, sub_name, msgtype, qos, latched in specs:
            conn = self.bag.add_topic(name, msgtype, latched=latched, depth=qos.depth) if self.bag is not None else name
            cls = import_type(msgtype)
            # Depth is not part of QoS matching: a deep reader history means a recorder that
            # falls behind for a moment (a disk hiccup, a loaded CPU) buffers instead of dropping.
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(qos.depth, SUBSCRIPTION_DEPTH),
                             reliability=qos.reliability, durability=qos.durability)
            cb = self._callback(conn, name, now)
            self._subs.append(n.create_subscription(cls, sub_name, cb, qos, raw=True))
            self._sub_names.append(name)

        from diagnostic_msgs.msg import DiagnosticArray  # deferred: a message package (see __init__)

        self._diag_pub = n.create_publisher(DiagnosticArray, topic("diagnostics").rel, qos_profile(topic("diagnostics")))
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        n.create_timer(float(self._param("flush_period_s")), self._on_flush_timer, clock=steady)
        n.create_timer(1.0, self.publish_counts, clock=steady)
        if self.live is not None:  # the sim time the rate limit held back, e.g. at the end of a run
            n.create_timer(0.1, self.live.flush_time, clock=steady)
        # before a run starts the launcher waits for our readers to match every writer: report matches fast
        n.create_timer(0.1, self._on_match_timer, clock=steady)
        n.create_service(Trigger, service("recorder_flush").rel, self._on_flush_service)
        n.get_logger().info(f"recording {len(specs)} topics into {path}")
        if self.live is not None:
            self.publish_counts()  # the launcher prints the live view's address once it reads it here

    def _callback(self, conn: Any, name: str, now: Any) -> Any:
        """The raw subscription callback of one topic: the bag write, plus the live view's send when on."""
        live = self.live
        if self.bag is None:  # live view only
            self._live_counts: dict[str, int] = getattr(self, "_live_counts", {})
            self._live_counts[name] = 0
            counts = self._live_counts

            def live_only(data: bytes) -> None:
                counts[name] += 1
                live.log(name, data, now())

            return live_only
        write = self.bag.write
        if live is None:
            def cb(data: bytes) -> None:
                if self.write_error is not None:
                    return
                try:
                    write(conn, data, now())
                except OSError as exc:  # a full disk: main() stops with one line (no executor traceback)
                    self.write_error = exc
            return cb

        def cb_live(data: bytes) -> None:
            if self.write_error is not None:
                return
            try:
                t = write(conn, data, now())
            except OSError as exc:
                self.write_error = exc
                return
            live.log(name, data, t)
        return cb_live

    def counts(self) -> dict[str, int]:
        """Messages written per topic (received, in live-only mode)."""
        if self.bag is None:
            return dict(getattr(self, "_live_counts", {}))
        return dict(self.bag.counts)

    def publish_counts(self) -> None:
        """Publish ``received:<topic>`` KeyValues on /diagnostics."""
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # deferred: a message package (see __init__)

        if self._diag_pub is None:
            return
        arr = DiagnosticArray()
        arr.header.stamp = self.node.get_clock().now().to_msg()
        counts = self.counts()
        where = str(self.bag.path) if self.bag is not None else (self.live.url if self.live is not None else "")
        st = DiagnosticStatus(level=DiagnosticStatus.OK, name=STATUS_NAME, hardware_id=where,
                              message=f"{sum(counts.values())} messages " + ("written" if self.bag else "served"))
        self._matched = [s.get_publisher_count() for s in self._subs]
        st.values = [KeyValue(key=f"received:{k}", value=str(v)) for k, v in counts.items()] + [
            KeyValue(key=f"matched_publishers:{name}", value=str(m)) for name, m in zip(self._sub_names, self._matched)]
        if self.live is not None:
            st.values.append(KeyValue(key=LIVE_URL_KEY, value=self.live.url))
        arr.status = [st]
        self._diag_pub.publish(arr)

    def _on_match_timer(self) -> None:
        """Publish the counts as soon as a reader's matched publishers change (e.g. a node came up)."""
        if [s.get_publisher_count() for s in self._subs] != self._matched:
            self.publish_counts()

    def _on_flush_timer(self) -> None:
        if self.bag is not None and self.bag.is_open and self.write_error is None:
            try:
                self.bag.flush()
            except OSError as exc:
                self.write_error = exc

    def _on_flush_service(self, request: Any, response: Any) -> Any:
        try:
            if self.bag is not None:
                self.bag.flush(fsync=True)
            response.success = True
            response.message = json.dumps(self.counts(), sort_keys=True)
        except Exception as exc:  # noqa: BLE001 - answer the caller instead of dying
            response.success = False
            response.message = f"flush failed: {exc}"
        self.publish_counts()
        return response

    def finish(self) -> dict[str, int]:
        """Finalise the bag (idempotent) and return the counts."""
        counts = self.counts()
        if self.bag is not None:
            self.bag.finish()
        if self.live is not None:
            self.live.close()
        return counts


def main(argv: Sequence[str] | None = None) -> int:
    """Run the recorder until SIGINT/SIGTERM; finalise the bag; exit 0 (1 on a setup error)."""
    # deferred: rclpy (see RecorderNode.__init__)
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.experimental import EventsExecutor
    from rclpy.signals import SignalHandlerOptions

    stop = {"sig": 0}

    def on_signal(signum: int, _frame: Any) -> None:
        # Only set a flag: a KeyboardInterrupt raised inside a write could leave a chunk half-indexed.
        stop["sig"] = signum

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    rclpy.init(args=list(sys.argv if argv is None else argv), signal_handler_options=SignalHandlerOptions.NO)
    rec = RecorderNode()
    code = 0
    try:
        try:
            rec.start()
        except (BagError, ValueError) as exc:
            print(f"vesselbot recorder: error: {exc}", file=sys.stderr, flush=True)
            rec.node.get_logger().error(str(exc))
            return 1
        ex = EventsExecutor()
        ex.add_node(rec.node)
        try:
            while not stop["sig"] and rclpy.ok() and rec.write_error is None:
                ex.spin_once(timeout_sec=0.1)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except OSError as exc:
            rec.write_error = exc
        if rec.write_error is not None:  # a full disk: one line that says what to do, the MCAP left repairable
            # deferred: as in RecorderNode.start (rosbags; already loaded here, since start opened the bag)
            from vesselbot_ros.bag.writer import write_failed_message

            print(f"vesselbot recorder: error: {write_failed_message(rec.bag.path, rec.write_error)}",
                  file=sys.stderr, flush=True)
            rec.bag.abort()
            return 1
        counts = rec.finish()
        if rec.bag is not None:
            print(f"vesselbot recorder: bag {rec.bag.path} finalised: "
                  + json.dumps(counts, sort_keys=True), flush=True)
    except BagError as exc:
        print(f"vesselbot recorder: error: {exc}", file=sys.stderr, flush=True)
        code = 1
    finally:
        if rec.bag is not None or rec.live is not None:
            try:
                rec.finish()
            except BagError as exc:
                print(f"vesselbot recorder: error: {exc}", file=sys.stderr, flush=True)
                code = 1
        rec.node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
