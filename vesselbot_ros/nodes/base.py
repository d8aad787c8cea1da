"""Shared plumbing of every vesselbot node: parameters, sim time, diagnostics, input checks.

:class:`VesselbotNode` is the base of the six graph nodes.  It

* declares the whole scenario (:mod:`vesselbot_ros.nodes.params`) plus the
  graph settings :class:`~vesselbot_ros.nodes.graph_params.GraphParams`
  (``graph.*``) as ROS parameters and builds them through the same frozen
  dataclasses as the pure core; a bad or unknown parameter raises
  :class:`~vesselbot_ros.config.ConfigError` naming it, and
  :func:`~vesselbot_ros.nodes.process.run_node` turns that into exit code 2
  with one clear line;
* takes sim time only from ticks: the lockstep inputs' ticks, or (real
  time) the plant's announced ``/clock`` tick, validated; rclpy's sim clock
  is not used (``use_sim_time = false``: no hidden ``/clock`` subscription per
  node on the hot path, and a garbage ``/clock`` cannot move a node's time);
  ``/diagnostics`` are stamped with the node's latest tick;
* publishes ``/diagnostics`` (one ``DiagnosticStatus`` named after the node)
  every ``graph.diagnostics_period_s`` of *wall* time, on every rejection
  burst, and once when the run is finished.  Keys: ``published:<topic>``
  (messages published), ``received:<topic>`` (accepted inputs),
  ``rejected:<topic>`` (rejected inputs), ``rejected_total``, ``last_tick:<topic>``
  (the latest tick of an input that reached the node, :meth:`VesselbotNode.note_input_tick`),
  ``matched_subscribers:<topic>`` / ``matched_publishers:<topic>`` (DDS
  matches, used by the launcher to know the graph is wired), ``finished``,
  plus node-specific entries;
* validates every input message with one helper, :meth:`VesselbotNode.check`:
  non-finite numbers, a frame_id other than ``vessel``, a non-zero ``y`` in a
  planar scenario (in a 3-D vessel tree, ``Scenario.dims`` 3, y is a
  coordinate like x and z), a position more than ``graph.position_margin_m``
  outside the vessel (a 3-D tree's wall in space), and (in
  real-time mode) stamps older than ``graph.input_max_age_s`` or in the future
  by more than ``graph.future_tolerance_s`` are rejected: the message is
  dropped, a warning is logged (at most once per second per topic and
  reason), and the next diagnostics are WARN with the reason and counts.  In
  lockstep, tick bookkeeping (stale / future ticks) is each node's own and
  reported through :meth:`VesselbotNode.reject`.  The node keeps running.
  A node whose own stage gave a bad result (a rejected command) says so the
  same way, :meth:`VesselbotNode.flag_output` (WARN ``rejected output: ...``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock as ClockMsg
from std_srvs.srv import Trigger
from vesselbot_msgs.srv import GetSeries

from vesselbot_ros.config import ConfigError, load_dataclass
from vesselbot_ros.graph_spec import (
    DEFAULT_NAMESPACE,
    FRAME_ID,
    LOOP_ROLES,
    NODE_NAMES,
    WIRE_STRINGS,
    ns_of_time,
    qos_profile,
    reset_service_key,
    series_service_key,
    service,
    tick_of_ns,
    topic,
)
from vesselbot_ros.graph_spec import role as graph_role
from vesselbot_ros.nodes.graph_params import GRAPH_PREFIX, GraphParams
from vesselbot_ros.nodes.intra_process import intra_process
from vesselbot_ros.nodes.params import kind_parameters, scenario_from_parameters, scenario_schema
from vesselbot_ros.nodes.series import SeriesLog
from vesselbot_ros.nodes.wire import FlatCodec, codec_for
from vesselbot_ros.physics.axes import AXES
from vesselbot_ros.sim.closed_loop import warm_up
from vesselbot_ros.sim.scenario import Scenario
from vesselbot_ros.vessels.network import load_network
from vesselbot_ros.vessels.tree_field import meshed_wall

__all__ = ["VesselbotNode"]

#: ``header.frame_id`` as a flat form holds it (CDR string bytes, NUL-terminated)
_FRAME_CDR = FRAME_ID.encode() + b"\0"
#: Real time: a ``/clock`` more than this many ticks ahead of the announced one is garbage.
MAX_CLOCK_JUMP_TICKS = 50
#: Real time: a gap in ``/clock`` longer than this (wall s) is a pause of the plant: re-anchor the schedule.
PAUSE_GAP_S = 0.5
#: Real time: after the last tick, a node whose last period never came finishes after this wall time (s).
REALTIME_END_GRACE_S = 1.0
_IGNORED_OVERRIDES = ("use_sim_time", "start_type_description_service")
#: The loop's roles: a publisher is wired once the loop's readers of its topic (graph spec) matched it; a topic
#: only outside readers take (the coil state: the recorder, viewers) needs none.
_LOOP_READERS = frozenset(LOOP_ROLES)


class VesselbotNode(Node):
    """Base class: parameters, diagnostics and input checks (see module docstring).

    Args:
        role: Node role (key of :data:`vesselbot_ros.graph_spec.NODE_NAMES`).
        context: rclpy Context (None: the default one).
        cli_args: Extra ROS arguments, e.g. ``["--ros-args", "--params-file", F]``.
        parameter_overrides: Parameter overrides (rclpy ``Parameter`` list).

    Raises:
        ConfigError: a parameter is unknown or invalid (the message names it).
    """

    def __init__(
        self,
        role: str,
        *,
        context: Any = None,
        cli_args: Sequence[str] | None = None,
        parameter_overrides: Sequence[Any] | None = None,
    ) -> None:
        overrides = list(parameter_overrides or []) + [Parameter("use_sim_time", Parameter.Type.BOOL, False)]
        super().__init__(
            NODE_NAMES[role], namespace=DEFAULT_NAMESPACE, context=context,
            cli_args=list(cli_args) if cli_args else None, parameter_overrides=overrides,
        )
        self.role = role
        #: the pure loop's stage this node runs (graph spec); it builds and warms only that one
        self.stage = graph_role(role).stage
        self.scenario, self.graph = self._load_parameters()
        self.rate_Hz = float(self.scenario.sim.control_rate_Hz)
        self.dt = float(self.scenario.sim.dt_control_s)
        self.n_ticks = int(self.scenario.sim.n_ticks)
        self.lockstep = self.graph.mode == "lockstep"
        #: axes of the scenario's vectors (2: planar (x, z), messages' y = 0; 3: a 3-D tree (x, y, z)), the one
        #: switch every vector packed or unpacked by this node follows (nodes/conversions.py)
        self.dims = self.scenario.dims
        self.finished = False
        self._published: Counter[str] = Counter()
        self._received: Counter[str] = Counter()
        self._last_input_tick: dict[str, int] = {}  # per topic: the latest tick of an input that reached this node
        self._rejected: Counter[str] = Counter()
        self._reject_reasons: Counter[str] = Counter()
        self._last_reason = ""
        self._warn_pending = False
        self._last_warn: dict[tuple[str, str], float] = {}
        self._last_diag_wall = 0.0
        self._pubs: dict[str, Any] = {}
        #: per-tick topic key -> its flat codec: such a topic's messages are flat forms (nodes/wire.py) in the node,
        #: one struct call from and to the CDR
        self._codecs: dict[str, FlatCodec] = {}
        self._topic_names: dict[str, str] = {}  # topic key -> topic name, for the counters
        self._subs: dict[str, Any] = {}
        self._optional_inputs = frozenset(graph_role(role).optional_inputs)
        #: the process's intra-process bus, if composed with one (lockstep and real time; in real time it takes the
        #: composed process from 0.36 to 0.27 ms of CPU per 1 ms tick unrecorded, recorded both take 0.52: the DDS
        #: publications the recorder reads then cost the difference)
        self._intra = intra_process()
        self._pub_intra: set[str] = set()  # topic keys also delivered intra-process
        self._readers: dict[str, Callable[[], int]] = {}  # topic key -> its matched DDS readers (volatile topics)
        self._subs_intra: list[str] = []  # topic keys received intra-process
        self._diag_pub = self.create_publisher(DiagnosticArray, topic("diagnostics").rel, qos_profile(topic("diagnostics")))
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)
        # before the run starts the launcher polls our DDS matches: report fast
        self._diag_timer = self.create_timer(0.1, self._diag_tick, clock=self._wall)
        # real-time bookkeeping: the plant's announced tick, missed periods, input age
        self.tick_now = -1
        self.period_tick = -1
        self.missed_periods = 0
        self._age_max = 0.0
        self._age_sum = 0.0
        self._age_n = 0
        self._anchor: float | None = None
        self._last_clock_wall = 0.0
        self._period_wall = self.dt / self.graph.real_time_factor
        self._end_wall: float | None = None
        self._late_sum = 0.0  # real time: wall time by which periods ended after they were due (s)
        self._late_max = 0.0
        self._late_n = 0
        self._future_ticks = int(round(self.graph.future_tolerance_s / self.dt))
        #: half the vessel's widest diameter (diameter pulsation), m: where a position check puts the walls
        self._half_walls = 0.5 * self.scenario.physics.vessel.diameter_m * (1.0 + self.scenario.physics.flow.diameter_pulsation)
        # the stages' first calls cost tens of ms (numba's cache, first allocations): pay them before the run, so
        # that a real-time node's first ticks are on time and a lockstep run's wall time is the loop's own.
        # Only this node's own stage (graph spec): warming the whole loop made every node start as slowly as all six.
        warm_up(self.scenario, (self.stage,) if self.stage else None)
        if self.scenario.physics.vessel.network:  # the input check's compiled clearance (and the network's file)
            p0 = self.scenario.initial.p0_m
            self._network_clearance([float(v) for v in p0])
        reset_key = reset_service_key(role)
        if reset_key in graph_role(role).services:
            self.add_service(reset_key, Trigger, self._on_reset)
        #: the run series of this node's outputs (graph spec), served once the run is over
        self.series = SeriesLog(graph_role(role).outputs, self.n_ticks, self.dt, self.dims)
        self._series_keys = frozenset(self.series.keys)
        series_key = series_service_key(role)
        if series_key in graph_role(role).services:
            self.add_service(series_key, GetSeries, self._on_series)

    def reset_state(self) -> None:
        """Put the node's core back as the scenario builds it, at tick 0 (override; called by ``__init__`` too)."""

    def _on_reset(self, request: Any, response: Any) -> Any:
        """Lockstep: back to t = 0 with the scenario's initial state (the plant's ResetSimulation calls this).

        Counts of published and received messages go on (they are what the
        bag holds); tick bookkeeping and the core start again, so the same
        seed gives the same messages again.
        """
        if not self.lockstep:
            response.success = False
            response.message = "reset applies to lockstep runs only"
            return response
        self.tick_now = -1
        self.period_tick = -1
        self.finished = False
        self.series.reset()
        self.reset_state()
        response.success = True
        response.message = f"{self.get_name()} at t = 0"
        return response

    def _on_series(self, request: Any, response: Any) -> Any:
        """The run series of this node's outputs, one row per tick (``success`` once the node finished)."""
        self.series.fill(response)
        response.success = self.finished
        response.message = (f"{len(self.series.columns)} columns x {self.series.n} ticks" if self.finished
                            else "the run is not over yet; rows so far")
        return response

    def realtime_clock(self) -> None:
        """Real time: follow ``/clock`` for the announced tick (call in a subclass's ``__init__``, after its ports)."""
        if self.lockstep:
            return
        if "clock" not in self._subs and "clock" not in self._subs_intra:
            self.add_subscription("clock", ClockMsg, self._on_realtime_clock)
        self.create_timer(0.1, self._realtime_end, clock=self._wall)

    def _on_realtime_clock(self, msg: Any) -> None:
        k = self.accept_clock(msg)
        if k is not None:
            self.on_realtime_tick(k)

    def on_realtime_tick(self, k: int) -> None:
        """Real time: the plant announced tick ``k`` (override: the node's periodic work)."""

    # ------------------------------------------------------------------ real time
    def accept_clock(self, msg: Any) -> int | None:
        """Real time: validate a ``/clock`` and make it the announced tick; the tick, or None (rejected).

        A clock off the tick grid, not newer than the announced tick, or more
        than :data:`MAX_CLOCK_JUMP_TICKS` ahead of it (a hostile or garbage
        clock) is rejected and moves nothing.
        """
        ns = msg.clock_sec * 1_000_000_000 + msg.clock_nanosec  # flat form
        k, on_grid = tick_of_ns(ns, self.dt)
        if not on_grid:
            self.reject("clock", "off_tick_stamp", f"clock {ns} ns is not a tick time")
            return None
        if k <= self.tick_now:
            self.reject("clock", "stale_stamp", f"clock tick {k} not newer than {self.tick_now}")
            return None
        if k > self.tick_now + MAX_CLOCK_JUMP_TICKS or k >= self.n_ticks + MAX_CLOCK_JUMP_TICKS:
            self.reject("clock", "future_stamp", f"clock tick {k} jumps from {self.tick_now}")
            return None
        self.count_received("clock")
        now = time.monotonic()
        cand = now - k * self._period_wall
        # (re)anchor the node's wall schedule: first clock, an earlier arrival, or after a pause of the plant
        if self._anchor is None or cand < self._anchor or now - self._last_clock_wall > PAUSE_GAP_S:
            self._anchor = cand
        self._last_clock_wall = now
        self.tick_now = k
        return k

    def note_input_age(self, stamp_ns: int, extra_age_s: float = 0.0) -> None:
        """Real time: record the age of an accepted input (announced tick time minus its stamp, s)."""
        if self.lockstep or self.tick_now < 0:
            return
        age = max(0.0, self.tick_now * self.dt - stamp_ns * 1e-9 - extra_age_s)
        self._age_max = max(self._age_max, age)
        self._age_sum += age
        self._age_n += 1

    def period_done(self, k: int) -> None:
        """The node finished its work for tick ``k``: count skipped ticks, and (real time) a late period."""
        if k <= self.period_tick:
            return
        self.missed_periods += k - self.period_tick - 1
        self.period_tick = k
        if not self.lockstep and self._anchor is not None:
            late = time.monotonic() - (self._anchor + k * self._period_wall)
            self._late_sum += max(late, 0.0)
            self._late_max = max(self._late_max, late)
            self._late_n += 1
            if late > self._period_wall:
                self.missed_periods += 1
        if not self.lockstep and k >= self.n_ticks - 1 and self.role != "plant":  # the plant finishes itself
            self.mark_finished()

    def _realtime_end(self) -> None:
        """Real time: the run ended (last tick announced) and this node's last period never came: finish anyway."""
        if self.finished or self.tick_now < self.n_ticks - 1:
            return
        now = time.monotonic()
        if self._end_wall is None:
            self._end_wall = now
        elif now - self._end_wall > REALTIME_END_GRACE_S:
            self.mark_finished()

    # ------------------------------------------------------------------ parameters
    def _load_parameters(self) -> tuple[Scenario, GraphParams]:
        # read-only: the core is built once from them, so `ros2 param set` is refused instead of ignored
        dyn = ParameterDescriptor(dynamic_typing=True, read_only=True)
        values: dict[str, Any] = {}
        # the stages' kinds first: the parameters of each section are those of the kind it names
        for name, default in kind_parameters().items():
            values[name] = self.declare_parameter(name, default, dyn).value
        stage_kinds = {k: v for k, v in values.items() if isinstance(v, str)}
        for name, spec in scenario_schema(stage_kinds).items():
            if name not in values:
                values[name] = self.declare_parameter(name, spec.default, dyn).value
        graph_values: dict[str, Any] = {}
        for f in dataclasses.fields(GraphParams):
            graph_values[f.name] = self.declare_parameter(GRAPH_PREFIX + f.name, f.default, dyn).value
        for name, value in self.extra_parameters().items():
            self.declare_parameter(name, value, dyn)
        declared = set(self._parameters)
        unknown = sorted(
            n for n in self._parameter_overrides if n not in declared and n not in _IGNORED_OVERRIDES
            and not n.startswith("qos_overrides.")
        )
        if unknown:
            raise ConfigError(
                f"unknown parameter {unknown[0]!r} (value {self._parameter_overrides[unknown[0]].value!r}) "
                f"for node {self.get_name()}"
            )
        scenario = scenario_from_parameters(values)
        graph = load_dataclass(GraphParams, graph_values, "graph")
        return scenario, graph

    def extra_parameters(self) -> dict[str, Any]:
        """Node-specific parameters (name -> default), declared after the scenario's."""
        return {}

    # ------------------------------------------------------------------ ports
    def add_publisher(self, key: str, msg_cls: Any) -> Any:
        """Create the publisher of topic ``key`` with the contract's QoS."""
        spec = topic(key)
        pub = self.create_publisher(msg_cls, spec.rel, qos_profile(spec))
        self._pubs[key] = pub
        self._topic_names[key] = spec.name
        codec = self._codec(key, msg_cls)
        if codec is not None:  # one struct call instead of rclpy's field-by-field conversion (nodes/wire.py)
            self._codecs[key] = codec
        bus = self._intra
        if bus is not None and bus.carries(key):  # the bus carries volatile topics only
            bus.add_publisher(key)
            self._pub_intra.add(key)
        if spec.qos != "reliable_latched":
            # a volatile message no reader is matched to is not serialized (a late joiner gets a latched
            # topic's last message, so those are always published); the handle's own count is a quarter of
            # Publisher.get_subscription_count's cost, on every publish
            self._readers[key] = pub.handle.get_subscription_count
        return pub

    @staticmethod
    def _codec(key: str, msg_cls: Any) -> FlatCodec | None:
        """The flat codec of topic ``key``: every per-tick topic's type has one, the others none."""
        if not topic(key).per_tick:
            return None
        codec = codec_for(msg_cls, WIRE_STRINGS)
        if codec is None:
            raise TypeError(f"per-tick topic {key} of type {msg_cls.__name__} has no flat layout")
        return codec

    def add_subscription(self, key: str, msg_cls: Any, callback: Callable[[Any], None]) -> Any:
        """Subscribe to topic ``key`` with the contract's QoS (intra-process if its publisher is co-located).

        ``callback`` gets a per-tick topic's messages in their flat form (:class:`~vesselbot_ros.nodes.wire.FlatCodec`:
        a named tuple of the CDR's values, e.g. ``header_stamp_sec``, ``vector_x``), any other topic's as rclpy messages.
        """
        spec = topic(key)
        codec = self._codec(key, msg_cls)
        self._topic_names[key] = spec.name
        bus = self._intra
        if bus is not None and bus.carries(key):
            bus.subscribe(key, callback)  # the publisher posts flat forms too (publish)
            self._subs_intra.append(key)
            return None
        if codec is None:
            sub = self.create_subscription(msg_cls, spec.rel, callback, qos_profile(spec))
        else:  # the CDR as it arrived, unpacked by one struct call (nodes/wire.py)
            unpack = codec.unpack

            def on_raw(raw: bytes) -> None:
                try:
                    msg = unpack(raw)
                except Exception:  # noqa: BLE001 - rclpy's error for bytes that are not this type's CDR
                    self.reject(key, "malformed_cdr", f"{len(raw)} bytes that do not decode as {spec.msgtype}")
                    return
                callback(msg)

            sub = self.create_subscription(msg_cls, spec.rel, on_raw, qos_profile(spec), raw=True)
        self._subs[key] = sub
        return sub

    def add_service(self, key: str, srv_cls: Any, callback: Callable[[Any, Any], Any]) -> Any:
        """Serve service ``key`` of the graph spec (name relative to the node namespace)."""
        return self.create_service(srv_cls, service(key).rel, callback)

    def publish(self, key: str, msg: Any) -> None:
        """Publish on topic ``key`` and count it for diagnostics.

        Composed (:class:`~vesselbot_ros.nodes.intra_process.IntraProcess`): co-located subscribers get the
        message itself.  DDS carries a volatile topic's message only when a
        reader is matched (outside the process, when composed): a message no
        one can receive is not serialized, yet counted as published, since a
        reader that joins later could not have had it either.  Latched topics
        are always published (a late joiner gets the last one).
        Real time: nothing is published once the node finished (its final
        diagnostics hold its final counts, which the launcher checks against the bag).
        """
        if self.finished and not self.lockstep:
            return
        codec = self._codecs.get(key)
        if codec is not None and type(msg) is not codec.Flat:
            msg = codec.flatten(msg)  # a per-tick topic's messages travel in their flat form
        if key in self._pub_intra:
            self._intra.post(key, msg)  # type: ignore[union-attr]  # _pub_intra is empty without the bus
        readers = self._readers.get(key)
        if readers is None or readers():
            self._pubs[key].publish(msg if codec is None else codec.pack(msg))
        self._published[self._topic_names[key]] += 1
        if key in self._series_keys:
            self.series.add(key, msg)

    def count_received(self, key: str) -> None:
        """Count one accepted input on topic ``key``."""
        names = self._topic_names
        self._received[names[key] if key in names else topic(key).name] += 1

    def note_input_tick(self, key: str, k: int) -> None:
        """Note that an input of tick ``k`` on topic ``key`` reached this node (accepted or not).

        Diagnostics ``last_tick:<topic>``: when the node that publishes ``key`` dies, the launcher names the sim
        time of its last output as its readers saw it, not a progress sample.
        """
        names = self._topic_names
        name = names[key] if key in names else topic(key).name
        if k > self._last_input_tick.get(name, -1):
            self._last_input_tick[name] = k

    def wired(self) -> bool:
        """True once every publisher and subscription of this node is matched (over DDS or within the process)."""
        bus = self._intra
        return all(
            p.get_subscription_count() > 0 or (bus is not None and bus.subscribers(k) > 0)
            for k, p in self._pubs.items() if topic(k).qos != "reliable_latched" and _LOOP_READERS.intersection(
                topic(k).subscribers)
        ) and all(  # an optional input (a node in its publisher's slot may not publish it) is not waited for
            s.get_publisher_count() > 0 for k, s in self._subs.items() if k not in self._optional_inputs
        ) and all(bus is not None and bus.publishers(k) > 0 for k in self._subs_intra if k not in self._optional_inputs)

    # ------------------------------------------------------------------ validation
    def reject(self, key: str, reason: str, detail: str = "") -> None:
        """Record a rejected input on topic ``key`` (rate-limited warning + WARN diagnostics)."""
        name = topic(key).name
        self._rejected[name] += 1
        self._reject_reasons[reason] += 1
        self._last_reason = f"rejected input: {name}: {reason}" + (f" ({detail})" if detail else "")
        self._warn(name, reason, f"rejected input on {name}: {reason}" + (f" ({detail})" if detail else ""))

    def flag_output(self, key: str, reason: str, detail: str = "") -> None:
        """Record that this node's own output on topic ``key`` is bad (its stage's result was rejected).

        A rate-limited warning (once per second per topic and reason) and WARN diagnostics, as :meth:`reject`
        does for inputs; the node's own counters say how many.
        """
        name = topic(key).name
        self._last_reason = f"rejected output: {name}: {reason}" + (f" ({detail})" if detail else "")
        self._warn(name, reason, f"rejected output on {name}: {reason}" + (f" ({detail})" if detail else ""))

    def _warn(self, name: str, reason: str, text: str) -> None:
        now = time.monotonic()
        if now - self._last_warn.get((name, reason), -1e9) >= 1.0:
            self._last_warn[(name, reason)] = now
            self.get_logger().warning(text)
        self._warn_pending = True
        if now - self._last_diag_wall >= 0.2:
            self.publish_diagnostics()

    def _network_clearance(self, point: Sequence[float]) -> float:
        """Signed distance (m) of ``point`` (on the scenario's axes: (x, z), a 3-D tree's (x, y, z)) to the network's
        meshed wall (the plant's) at its widest (diameter pulsation), > 0 inside."""
        clearance = getattr(self, "_net_clearance", None)
        phys = self.scenario.physics
        if clearance is None:
            clearance = self._net_clearance = meshed_wall(load_network(phys.vessel.network), phys.blood).clearance
        s, diameter = clearance(*point)
        return float(s + 0.5 * diameter * phys.flow.diameter_pulsation)

    def check(
        self,
        key: str,
        *,
        frame_id: str | None = None,
        stamp_ns: int | None = None,
        values: Sequence[float] = (),
        y_values: Iterable[float] = (),
        z_position: float | None = None,
        x_position: float | None = None,
        y_position: float = 0.0,
        extra_age_s: float = 0.0,
    ) -> bool:
        """Validate one input message; on failure call :meth:`reject` and return False.

        Args:
            key: Topic key of the input.
            frame_id: The message's ``header.frame_id`` (must be ``vessel``), or in a flat form the
                ``header_frame_id_cdr`` bytes (NUL-terminated).
            stamp_ns: The message's stamp (ns); checked against the sim clock
                in real-time mode only (lockstep checks ticks instead).
            values: Every float of the message (must be finite).
            y_values: The message's y components: must be 0 in a planar scenario
                (``dims`` 2); in a 3-D tree they are coordinates, checked by ``values``.
            z_position: A position's z (m): must lie within the vessel walls
                plus ``graph.position_margin_m``.
            x_position: The position's x (m); in a vessel network the point
                (x, z) must lie within the network's walls (dilated by the
                diameter pulsation) plus ``graph.position_margin_m``.
            y_position: The position's y (m), in a 3-D tree: the point (x, y, z) must lie within its wall
                (as above); ignored in a planar scenario.
            extra_age_s: Allowed extra age (e.g. the imager latency), s.
        """
        if frame_id is not None and frame_id != FRAME_ID and frame_id != _FRAME_CDR:
            got = frame_id[:-1].decode(errors="replace") if isinstance(frame_id, bytes) else frame_id
            self.reject(key, "wrong_frame_id", f"got {got!r}, expected {FRAME_ID!r}")
            return False
        if not all(map(math.isfinite, values)):
            self.reject(key, "non_finite", f"values {list(values)}")
            return False
        if "y" not in AXES[self.dims]:  # a planar scenario pins y at 0
            for y in y_values:
                if y != 0.0:
                    self.reject(key, "nonzero_y", f"y components {list(y_values)} (a planar scenario's y is 0)")
                    return False
        if z_position is not None and self.scenario.physics.vessel.network and x_position is not None:
            xyz = {"x": x_position, "y": y_position, "z": z_position}
            axes = AXES[self.dims]
            s = self._network_clearance([xyz[a] for a in axes])
            if s < -self.graph.position_margin_m:
                where = f"({', '.join(axes)}) = ({', '.join(repr(xyz[a]) for a in axes)})"
                self.reject(key, "outside_vessel", f"{where} m lies {-s!r} m outside the vessel network's walls")
                return False
        elif z_position is not None:
            half = self._half_walls
            if abs(z_position) > half + self.graph.position_margin_m:
                self.reject(key, "outside_vessel", f"z = {z_position!r} m, walls at +/-{half!r} m")
                return False
        if stamp_ns is not None and not self.lockstep:
            now_ns = ns_of_time(max(self.tick_now, 0) * self.dt)  # the plant's announced tick, not the ROS clock
            if stamp_ns > now_ns + self.graph.future_tolerance_s * 1e9:
                self.reject(key, "future_stamp", f"stamp {stamp_ns * 1e-9:.6f} s > now {now_ns * 1e-9:.6f} s")
                return False
            if stamp_ns < now_ns - (self.graph.input_max_age_s + extra_age_s) * 1e9:
                self.reject(key, "stale_stamp", f"stamp {stamp_ns * 1e-9:.6f} s, now {now_ns * 1e-9:.6f} s")
                return False
            self.note_input_age(stamp_ns, extra_age_s)
        return True

    # ------------------------------------------------------------------ diagnostics
    def diagnostic_values(self) -> dict[str, str]:
        """Node-specific diagnostic entries (override)."""
        return {}

    def _diag_tick(self) -> None:
        now = time.monotonic()
        period = self.graph.diagnostics_period_s if (self.started() or self.finished) else 0.1
        if now - self._last_diag_wall >= period - 1e-3:
            self.publish_diagnostics()

    def started(self) -> bool:
        """True once this node has handled its first tick (override where relevant)."""
        return sum(self._published.values()) > 0

    def publish_diagnostics(self) -> None:
        """Publish this node's DiagnosticStatus now."""
        self._last_diag_wall = time.monotonic()
        kv: dict[str, str] = {}
        for t in sorted(set(self._published) | {topic(k).name for k in self._pubs}):
            kv[f"published:{t}"] = str(self._published[t])
        for t in sorted(self._received):
            kv[f"received:{t}"] = str(self._received[t])
        for t in sorted(self._rejected):
            kv[f"rejected:{t}"] = str(self._rejected[t])
        for name, last in sorted(self._last_input_tick.items()):
            kv[f"last_tick:{name}"] = str(last)
        for reason, n in sorted(self._reject_reasons.items()):
            kv[f"rejected_reason:{reason}"] = str(n)
        kv["rejected_total"] = str(sum(self._rejected.values()))
        for k, p in self._pubs.items():
            kv[f"matched_subscribers:{topic(k).name}"] = str(p.get_subscription_count())
        for k, s in self._subs.items():
            kv[f"matched_publishers:{topic(k).name}"] = str(s.get_publisher_count())
        kv["wired"] = "true" if self.wired() else "false"
        kv["finished"] = "true" if self.finished else "false"
        kv["mode"] = self.graph.mode
        kv["period_tick"] = str(self.period_tick)
        kv["missed_periods"] = str(self.missed_periods)
        kv["input_age_max_s"] = repr(self._age_max)
        kv["input_age_mean_s"] = repr(self._age_sum / self._age_n if self._age_n else 0.0)
        kv["lateness_mean_s"] = repr(self._late_sum / self._late_n if self._late_n else 0.0)
        kv["lateness_max_s"] = repr(self._late_max)
        kv.update(self.diagnostic_values())
        level = DiagnosticStatus.WARN if self._warn_pending else DiagnosticStatus.OK
        message = self._last_reason if self._warn_pending else ("finished" if self.finished else "ok")
        self._warn_pending = False
        st = DiagnosticStatus(level=level, name=self.get_name(), message=message, hardware_id="vesselbot")
        st.values = [KeyValue(key=k, value=v) for k, v in kv.items()]
        arr = DiagnosticArray(status=[st])
        tick = max(self.tick_now, self.period_tick, 0)
        arr.header.stamp.sec, arr.header.stamp.nanosec = divmod(int(round(tick * self.dt * 1e9)), 1_000_000_000)
        self._diag_pub.publish(arr)

    def mark_finished(self) -> None:
        """The run is over for this node: publish final diagnostics once."""
        if not self.finished:
            self.finished = True
            self.publish_diagnostics()

    @property
    def done(self) -> bool:
        """True when the node asks its process to exit (never, by default)."""
        return False

