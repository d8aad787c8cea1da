"""The graph spec: every role, port, service and diagnostic counter of the vesselbot graph, declared once.

Everything that lists roles or topics derives from this module: the nodes'
publishers, subscriptions and services (:class:`vesselbot_ros.nodes.base.VesselbotNode`
builds them from :class:`Role`), the launcher (start order, processes, the
``--without ROLE`` contract it prints), the single-process composition, the
recorder's topic list, ``replay --into``, the report's counters, the console
entry points (``setup.py``), and the README / docs tables
(``tools/gen_readme_sections.py``).  Adding a role or a topic is one edit here;
``test/unit/test_graph_spec.py`` fails when any other module spells a topic or
service name.  Importing this module imports nothing but the standard library
(``setup.py`` loads it by path); :func:`qos_profile` imports rclpy lazily.

Names.  Topic and service names are *relative* (``truth``, ``coil/applied``):
they resolve in the node namespace, ``/vesselbot`` by default
(:data:`DEFAULT_NAMESPACE`), so ``vesselbot run --namespace NAME`` puts a whole
graph under ``/NAME``.  ``/clock`` and ``/diagnostics`` are global by ROS
convention; a namespaced graph remaps them into its namespace
(:func:`remap_args`), so two graphs share one domain without crosstalk.  Bags
always store the canonical names (:attr:`TopicSpec.name`, i.e. the default
namespace); the namespace a run used is in its run metadata.

Frame ``vessel``: x along the vessel axis (blood flows towards +x), z vertical
(gravity along -z), centreline at z = 0, walls at z = +/- D(t)/2; y the
scanner's horizontal axis across the bore.  Every
vector travels with its three components.  In a planar scenario (a straight
vessel or a network in the XZ plane) y is 0 in every message and a non-zero y
is rejected; in a 3-D vessel tree (``Scenario.dims`` 3: its network file gives
``y_m``) y is a coordinate like x and z in every position, velocity,
acceleration, gradient and force, and ``coil/state`` carries the y axis's slew
flag (``slew_limited_y``, false in planar runs).

Lockstep protocol (the default mode; deterministic)
---------------------------------------------------
Tick k holds at sim time ``t_k = k / control_rate_Hz``.  Every topic marked
``per tick`` carries exactly one message per tick, in this order:

1. plant publishes ``/clock`` = t_k and ``truth`` (stamp t_k);
2. imager, on ``truth`` k, publishes ``measurement``.  In lockstep it publishes
   once per tick: the frame delivered at t_k, or, when no new frame is due
   (frame-rate decimation, latency, dropout), the last delivered frame again,
   unchanged (zero-order hold).  ``header.stamp`` is always the frame's
   *acquisition* time, so consumers detect fresh frames by a newer stamp.
   Before the first frame is ever delivered (latency, an early dropout) it
   publishes a placeholder with an empty ``frame_id`` and stamp 0, meaning
   "no frame yet".  The n-th ``measurement`` message belongs to tick n;
   With an imager that delivers MR frames (``imager.kind: mr_images``) the imager publishes ``imager/frame``
   instead (one per tick: the frame delivered at t_k, or an empty image stamped t_k), and the tracker, on
   frame message k, publishes ``measurement`` k as above (the frame's position, else the last one again);
3. reference, on ``/clock`` k, publishes ``reference`` sample k;
4. observer, once it has ``measurement`` k and ``coil/applied`` k-1, publishes
   ``estimate`` (stamp t_k);
5. controller, once it has ``estimate`` k and ``reference`` k, publishes
   ``gradient_command`` (stamp t_k);
6. coil driver publishes ``coil/applied`` and ``coil/state`` (stamp t_k);
   before them, when the scanner's phase at t_k+1 differs from the last one
   it published, ``scanner/phase`` (stamp t_k+1; latched; see below);
7. plant, once it has ``coil/applied`` k, integrates [t_k, t_k+1] and goes to 1.

Tick times are rebuilt as ``k * dt`` from the stamps (never by summing floats),
which is why a lockstep run reproduces the ROS-free runner bit for bit.  One
helper does the stamp <-> tick bookkeeping for every node
(:class:`vesselbot_ros.nodes.tick_join.TickJoin`): inputs keyed by tick, off-grid,
stale and future ticks rejected without moving any state.

The estimate is a ``nav_msgs/Odometry`` (in the XZ plane, y = 0, in a planar
scenario; in space in a 3-D tree); its otherwise unused yaw-yaw variance
``pose.covariance[35]`` carries the observer's time since the last fresh
measurement (s), which the controller's stale-estimate safe behaviour reads,
and its yaw-rate variance ``twist.covariance[35]`` the observer's
blood-velocity scale ``s_hat`` (-; 1 for observer (25), 0 read as 1), which
the flow-compensating law reads.

The scanner (``sequence:`` of the scenario).  ``scanner/phase`` says which
window of the MRI sequence holds: ``TRACKING`` (the gradients image; the coil
applies exactly zero), ``DEAD`` (switching), ``PROPULSION`` (the controller's
gradient is applied, within saturation, slew and dB/dt, and back at zero by
the window's end), or ``CONTINUOUS`` (the paper's loop: one message, on
[0, inf)).  Each message carries its window's ``[window_start, window_end)``,
the frame latency and the duty cycle, so a consumer holding the latest one
knows the phase of every tick up to ``window_end``; the phase of t_k+1 is
published before ``coil/applied`` k, hence before anything of tick k+1.  In
a multiplexed sequence the imager takes one frame per tracking window (the
robot's mean position over the window: motion blur), stamps it at the
window's middle and delivers it at the first tick at or after
``window_end + latency``; until then it repeats the previous frame.

Lockstep watchdog: if ``coil/applied`` of tick k has not arrived within
``graph.stall_timeout_s`` of wall time (the controller died or hangs), the
plant, which knows whether tick k is in flight or held at its gate, publishes
``coil/stall`` stamped t_k, and the coil driver answers tick k itself through
``CoilLimiter.watchdog``: it holds the output until ``coil.command_timeout_s``
of sim time passed without commands, then ramps to zero within the slew limit,
so the loop (and the bag) goes on.  A late command for a tick already
answered is rejected as stale.  (The driver does not follow ``/clock`` in
lockstep: one delivery and one process wake-up less per tick.)

In real-time mode the plant steps on the wall clock at a real-time factor and
applies the latest ``coil/applied`` (zero-order hold); the imager publishes only
fresh frames at its frame rate; observer and controller run on sim-time timers
at the control rate.  Nodes never take time from an input's stamp beyond the
plant's announced tick: a message stamped in the future is rejected without
moving any state, and the coil driver answers on its own sim-time grid.
Every node in the loop counts its missed control periods (deadlines: its work
for a tick ended more than one period after the tick was due, or it skipped the
tick), its lateness and the age of its inputs (``missed_periods``,
``lateness_max_s``, ``input_age_max_s`` on ``/diagnostics``); the plant reports
the average real-time factor held (sim time advanced over the wall time it
took, ``real_time_factor_held``).  The two are reported apart: a run fails if
any loop node missed more than 1 % of its periods, or if the average factor
held fell more than 1 % below the one asked; fewer missed periods are a
warning.
"""

from __future__ import annotations

import importlib
import textwrap
from dataclasses import dataclass, field
from typing import Any, Literal

__all__ = [
    "DEFAULT_NAMESPACE", "FRAME_ID", "CHILD_FRAME_ID", "WIRE_STRINGS", "TopicSpec", "ServiceSpec", "Role", "TOPICS", "SERVICES", "ROLES",
    "RECORDER",
    "SIMULATION_SERVICES", "SIMULATION_NODE", "reset_service_key", "series_service_key", "ViewSpec", "VIEW_CHANNELS", "view_table",
    "LOOP_ROLES", "ALL_ROLES", "NODE_NAMES", "REPLAY_PREFIX", "topic", "service", "role", "resolve", "namespace_of",
    "remap_args", "qos_profile", "import_type", "console_scripts", "markdown_table", "architecture_table", "contract_table",
    "role_contract", "faults_table", "diagnostic_counters", "tick_time", "ns_of_time", "tick_of_ns", "REALTIME_MISSED_LIMIT",
    "REALTIME_FACTOR_LIMIT", "NETWORK_WALL_NS", "loop_roles", "frame_topics",
]

FRAME_ID = "vessel"
#: The estimate's ``child_frame_id``: the robot it tracks.
CHILD_FRAME_ID = "robot"
#: The string fields of the per-tick messages, as the graph fixes them: a message whose strings are these travels
#: by its flat codec (nodes/wire.py); any other (a user's, a malformed one) by rclpy's own (de)serializer.
WIRE_STRINGS = {"header.frame_id": FRAME_ID, "forces.header.frame_id": FRAME_ID, "child_frame_id": CHILD_FRAME_ID}
#: Namespace of the graph's nodes (and so of its relative topic and service names).
DEFAULT_NAMESPACE = "/vesselbot"
#: Where ``replay --into`` puts a re-computed output in its result bag (relative to the namespace).
REPLAY_PREFIX = "replay"
#: Real time: a run fails if any loop node missed more than this fraction of its control periods (deadlines).
REALTIME_MISSED_LIMIT = 0.01
#: Real time: a run fails if the average factor held (sim time advanced / wall time) is below the asked one by more
#: than this fraction of it.
REALTIME_FACTOR_LIMIT = 0.01
#: Namespace of the meshed-wall marker in a vessel network's ``vessel_markers`` (the wall the plant computes with).
NETWORK_WALL_NS = "wall"

Qos = Literal["reliable", "reliable_latched", "clock", "diagnostics"]


@dataclass(frozen=True)
class TopicSpec:
    """One port of the graph (a topic).

    Attributes:
        key: Short handle used in code, e.g. ``"truth"``.
        rel: The name as nodes create it: relative (``coil/applied``), or
            absolute for the ROS-global ``/clock`` and ``/diagnostics``.
        msgtype: ROS type, ``pkg/msg/Name``.
        publisher: Publishing role (``all``: every node).
        subscribers: Subscribing roles (free text for outside readers in parentheses).
        rate: Human-readable rate.
        qos: QoS class (see :func:`qos_profile`).
        units: Units of the payload.
        frame: ``header.frame_id`` (``-`` if none).
        per_tick: Lockstep: exactly one message per tick.
        depth: Writers keep this many samples.  Reliable KEEP_LAST overwrites
            samples not yet acknowledged once the history is full, and a
            sample the transport dropped (a full shared-memory port on a loaded
            machine) is only resent after the reader learns of the gap from a
            heartbeat, seconds later; the recorder and the launcher's monitor
            are not paced by the lockstep loop.  With 1000 (1 s at 1 kHz) a
            recorded lockstep run lost its last few commands on a loaded
            machine; per-tick topics keep 10 s at 1 kHz.
    """

    key: str
    rel: str
    msgtype: str
    publisher: str
    subscribers: tuple[str, ...]
    rate: str
    qos: Qos
    units: str
    frame: str
    per_tick: bool = False
    depth: int = 10_000
    #: What a user's node in a slot must know beyond type and units (printed in its contract).
    note: str = ""
    #: The run series (:data:`vesselbot_ros.nodes.series.SERIES_COLUMNS`) its messages carry: its publisher
    #: keeps them and serves them once on ``<role>/series`` at the end of a run, which is how the launcher
    #: reads them without a per-tick subscription (it subscribes only when a user's node publishes the topic).
    series: tuple[str, ...] = ()
    #: Its publishing role in a graph whose imager delivers MR frames ("": ``publisher``).
    frames_publisher: str = ""
    #: The canonical absolute name (default namespace): what bags and diagnostics use.
    name: str = field(init=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "name", self.rel if self.rel.startswith("/") else f"{DEFAULT_NAMESPACE}/{self.rel}")

    @property
    def is_global(self) -> bool:
        """True for ROS-global names (``/clock``, ``/diagnostics``)."""
        return self.rel.startswith("/")


class _Relative:
    """A name relative to the graph's namespace (``rel``), with its canonical absolute form."""

    rel: str

    @property
    def name(self) -> str:
        """The canonical absolute name (default namespace)."""
        return resolve(self.rel)


@dataclass(frozen=True)
class ServiceSpec(_Relative):
    """One service (or action: ``pkg/action/Name``) of the graph."""

    key: str
    rel: str
    srvtype: str
    server: str
    purpose: str

    @property
    def is_action(self) -> bool:
        """True for an action (``pkg/action/Name``)."""
        return self.srvtype.split("/")[1] == "action"


@dataclass(frozen=True)
class ViewSpec(_Relative):
    """A channel the live view derives from topics (``vesselbot run --live``; not a DDS topic).

    Attributes:
        key: Short handle.
        rel: Name relative to the namespace (``view/markers``).
        msgtype: A ROS message type (sent as CDR with its ``ros2msg`` schema) or ``json``.
        inputs: Topic keys it is computed from (:mod:`vesselbot_ros.live_view`).
        shows: What a viewer sees on it.
    """

    key: str
    rel: str
    msgtype: str
    inputs: tuple[str, ...]
    shows: str


@dataclass(frozen=True)
class Role:
    """One node role: what it is, how it starts, its ports.

    Attributes:
        name: Role name (``--without NAME``).
        node_name: ROS node name.
        node_class: ``module:Class`` of our implementation.
        module: Module with the process's ``main()`` (``python -m`` target).
        inputs: Topic keys it subscribes to (its contract).
        optional_inputs: Topic keys a node in its slot may subscribe to (the
            contract lists them; our implementation need not).
        outputs: Topic keys it publishes (besides ``/diagnostics``).
        services: Service keys it serves.
        counters: Diagnostic keys the launcher adds to the run's metrics.
        safe_stop: Upstream of the coil driver: when it dies, the driver's
            watchdog ramps the gradient to zero before the run stops.
        summary: One line for the architecture table.
        stage: The stage of the pure loop our implementation runs (a field of
            :class:`vesselbot_ros.sim.closed_loop.Stages`): the node builds
            and warms only that one.
        frames_inputs / frames_outputs: Its ports when the scenario's imager
            delivers MR frames (``None``: ``inputs`` / ``outputs``).
        frames_only: The role exists only when the scenario's imager delivers
            MR frames (the tracker).
    """

    name: str
    node_name: str
    node_class: str
    module: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    optional_inputs: tuple[str, ...] = ()
    services: tuple[str, ...] = ()
    counters: tuple[str, ...] = ()
    safe_stop: bool = False
    summary: str = ""
    stage: str = ""
    frames_inputs: tuple[str, ...] | None = None
    frames_outputs: tuple[str, ...] | None = None
    frames_only: bool = False

    def inputs_for(self, frames: bool) -> tuple[str, ...]:
        """Its inputs in a graph whose imager delivers MR frames (``frames``) or positions."""
        return self.frames_inputs if frames and self.frames_inputs is not None else self.inputs

    def outputs_for(self, frames: bool) -> tuple[str, ...]:
        """Its outputs in a graph whose imager delivers MR frames (``frames``) or positions."""
        return self.frames_outputs if frames and self.frames_outputs is not None else self.outputs

    @property
    def console_script(self) -> str:
        """Console entry point name (``vesselbot_<role>``)."""
        return self.node_name


TOPICS: tuple[TopicSpec, ...] = (
    TopicSpec("clock", "/clock", "rosgraph_msgs/msg/Clock", "plant",
              ("all (use_sim_time)", "reference", "(real time: every loop node)"),
              "per tick", "clock", "s", "-", per_tick=True),
    TopicSpec("truth", "truth", "vesselbot_msgs/msg/PlantState", "plant", ("imager", "recorder"),
              "per tick", "reliable", "m, m/s, N, T/m", FRAME_ID, per_tick=True, series=("p_true", "v_true", "in_contact")),
    TopicSpec("vessel_markers", "vessel_markers", "visualization_msgs/msg/MarkerArray", "plant", ("(viewers)",),
              "once (latched)", "reliable_latched", "m", FRAME_ID, depth=1),
    TopicSpec("measurement", "measurement", "geometry_msgs/msg/PointStamped", "imager", ("observer",),
              "per tick (lockstep, ZOH) / frame rate (real time)", "reliable", "m", FRAME_ID, per_tick=True,
              frames_publisher="tracker",
              note="header.stamp = acquisition time (multiplexed: the middle of its tracking window); the frame "
                   "arrives at the first tick at or after window_end + latency, so it is that much old; a newer "
                   "stamp means a fresh frame, the same stamp a repeat; stamp 0 with an empty frame_id: no frame yet"),
    TopicSpec("mr_frame", "imager/frame", "sensor_msgs/msg/Image", "imager", ("tracker", "recorder"),
              "per tick (lockstep; empty without a new frame) / on each frame (real time)", "reliable",
              "complex MR signal (a.u.)", FRAME_ID,
              note="only with an imager that delivers MR frames (imager.kind mr_images); encoding 64FC2 (complex128: "
                   "real, imaginary; little-endian), header.stamp = acquisition time; a slice is matrix x matrix "
                   "(rows: the phase-encode axis, columns: the readout axis, x for readout_axis x), the projections "
                   "3 x matrix (rows: x, y, z); sample n of an axis lies at fov_centre_m + (n - matrix/2) pixel_m "
                   "(docs/imaging.md).  Lockstep: the n-th message belongs to tick n; a tick without a new frame "
                   "has an empty image (height and width 0) stamped t_k"),
    TopicSpec("mr_image", "imager/image", "sensor_msgs/msg/Image", "imager", ("recorder", "(viewers: Image panel)"),
              "on each frame", "reliable", "magnitude (a.u.)", FRAME_ID, depth=1000,
              note="only with an imager that delivers MR frames; the magnitude of each imager/frame (32FC1, the same "
                   "rows and columns), for viewers; header.stamp = acquisition time"),
    TopicSpec("estimate", "estimate", "nav_msgs/msg/Odometry", "observer", ("controller",),
              "per tick", "reliable", "m, m/s", FRAME_ID, per_tick=True, series=("x_hat", "z_hat"),
              note="x_hat in pose.pose.position, z_hat in twist.twist.linear; pose.covariance[35] = seconds since "
                   "the last fresh measurement; twist.covariance[35] = the observer's blood-velocity scale s_hat "
                   "(law (24) with flow_compensation: estimate takes it; 0, unset, reads as 1)"),
    TopicSpec("reference", "reference", "vesselbot_msgs/msg/ReferenceSample", "reference", ("controller",),
              "per tick", "reliable", "m, m/s, m/s^2", FRAME_ID, per_tick=True, series=("p_ref",)),
    TopicSpec("reference_path", "reference/path", "nav_msgs/msg/Path", "reference", ("(viewers)",),
              "once (latched)", "reliable_latched", "m", FRAME_ID, depth=1),
    TopicSpec("gradient_command", "gradient_command", "geometry_msgs/msg/Vector3Stamped", "controller",
              ("coil_driver",), "per tick", "reliable", "T/m", FRAME_ID, per_tick=True),
    TopicSpec("coil_applied", "coil/applied", "geometry_msgs/msg/Vector3Stamped", "coil_driver",
              ("plant", "observer"), "per tick (+ watchdog)", "reliable", "T/m", FRAME_ID, per_tick=True),
    TopicSpec("coil_stall", "coil/stall", "std_msgs/msg/Header", "plant", ("coil_driver", "recorder"),
              "lockstep: when a tick's coil/applied is late", "reliable_latched", "s", FRAME_ID,
              note="the plant waited graph.stall_timeout_s of wall time (then, while commands stay lost, 20 ms) for "
                   "coil/applied of the tick stamped here: the driver answers that tick itself (watchdog); a "
                   "request for a tick already answered crossed the answer and is ignored"),
    TopicSpec("coil_state", "coil/state", "vesselbot_msgs/msg/CoilState", "coil_driver", ("recorder",),
              "per tick (+ watchdog)", "reliable", "T/m, T/m/s", FRAME_ID, per_tick=True,
              series=("g_applied", "saturated", "slew_limited", "cmd_rejected")),
    TopicSpec("sequence_phase", "scanner/phase", "vesselbot_msgs/msg/SequencePhase", "coil_driver",
              ("recorder", "(your observer or controller)"), "on phase change (latched; once when continuous)",
              "reliable_latched", "s", FRAME_ID,
              note="phase CONTINUOUS (0), TRACKING (1: no propulsion gradient, a frame is acquired), DEAD (2) or "
                   "PROPULSION (3: the command is applied) holds on [window_start, window_end) of sim time; the "
                   "phase of t_k+1 is published before coil/applied k; latency (s) and duty_cycle come with it"),
    TopicSpec("diagnostics", "/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", "all", ("launcher", "recorder"),
              "1 Hz wall + on events", "diagnostics", "-", "-"),
)

SERVICES: tuple[ServiceSpec, ...] = (
    ServiceSpec("inject_fault", "imager/inject_fault", "vesselbot_msgs/srv/InjectFault", "imager",
                "inject an outlier burst or a dropout on the imager"),
    ServiceSpec("run_control", "run_control", "vesselbot_msgs/srv/RunControl", "plant",
                "start / pause / resume / stop / status of the run"),
    ServiceSpec("recorder_flush", "recorder/flush", "std_srvs/srv/Trigger", "recorder",
                "flush and fsync the bag; the per-topic counts as JSON"),
    # The simulation_interfaces standard (Jazzy), under its usual names, relative to the graph's namespace.
    ServiceSpec("get_simulator_features", "get_simulator_features", "simulation_interfaces/srv/GetSimulatorFeatures",
                "plant", "simulation_interfaces: what this simulator supports (stepping and reset in lockstep only)"),
    ServiceSpec("get_simulation_state", "get_simulation_state", "simulation_interfaces/srv/GetSimulationState",
                "plant", "simulation_interfaces: stopped / playing / paused"),
    ServiceSpec("set_simulation_state", "set_simulation_state", "simulation_interfaces/srv/SetSimulationState",
                "plant", "simulation_interfaces: play, pause, stop (= pause and reset), quit (end the run)"),
    ServiceSpec("step_simulation", "step_simulation", "simulation_interfaces/srv/StepSimulation", "plant",
                "simulation_interfaces: while paused, run N control ticks; returns when they are done"),
    ServiceSpec("reset_simulation", "reset_simulation", "simulation_interfaces/srv/ResetSimulation", "plant",
                "simulation_interfaces: back to t = 0 with the scenario's initial state (every node; same messages again)"),
    ServiceSpec("simulate_steps", "simulate_steps", "simulation_interfaces/action/SimulateSteps", "plant",
                "simulation_interfaces action: N control ticks while paused, completed/remaining as feedback"),
)

#: What the live view derives for its 3D and plot panels (``config/foxglove/vesselbot.json``), besides forwarding
#: every topic above as it is.  A port added to TOPICS appears in the live view with no view code.
VIEW_CHANNELS: tuple[ViewSpec, ...] = (
    ViewSpec("view_markers", "view/markers", "visualization_msgs/msg/MarkerArray",
             ("truth", "estimate", "coil_state", "reference_path", "vessel_markers"),
             "3D: the straight vessel's walls at +/- D(t)/2 as they pulse (a network's meshed wall, a 3-D tree's wall "
             "mesh: `vessel_markers`), the robot, its estimate, the applied gradient (arrow, 2 mm at the coil limit), "
             "the reference path, with the messages' y (in 3-D in a 3-D tree)"),
    ViewSpec("view_errors", "view/errors", "json", ("truth", "reference", "estimate", "coil_state"),
             "plots: tracking and estimation error (m), the applied gradient norm against its limit U_sat (T/m)"),
)

#: The simulation_interfaces services and action, served by the plant (node :data:`SIMULATION_NODE`).
SIMULATION_SERVICES: tuple[str, ...] = ("get_simulator_features", "get_simulation_state", "set_simulation_state",
                                        "step_simulation", "reset_simulation", "simulate_steps")
#: The plant process's second node: it serves :data:`SIMULATION_SERVICES` on its own thread, so that a
#: StepSimulation call can wait for its ticks while the plant's node goes on stepping.
SIMULATION_NODE = "vesselbot_simulation"


_TOPIC = {t.key: t for t in TOPICS}


def _node(role: str, cls: str, **kw: Any) -> Role:
    if role != "plant":  # every loop node but the plant (which serves ResetSimulation) resets on request
        kw["services"] = (*kw.get("services", ()), reset_service_key(role))
    if any(_TOPIC[k].series for k in kw.get("outputs", ())):  # it serves the run series its outputs carry
        kw["services"] = (*kw.get("services", ()), series_service_key(role))
    return Role(role, f"vesselbot_{role}", f"vesselbot_ros.nodes.{role}_node:{cls}", f"vesselbot_ros.nodes.{role}_node",
                **kw)


def series_service_key(role_name: str) -> str:
    """Key of the service on which node ``role_name`` serves the run series of its outputs (:class:`TopicSpec`)."""
    return f"{role_name}_series"


def reset_service_key(role_name: str) -> str:
    """Key of the service that returns node ``role_name`` to t = 0 (called by the plant's ResetSimulation)."""
    return f"{role_name}_reset"


#: The loop's roles in start order (the plant last: it owns the clock).
ROLES: tuple[Role, ...] = (
    _node("reference", "ReferenceNode", inputs=("clock",), outputs=("reference", "reference_path"), safe_stop=True,
          stage="reference",
          summary="C2 B-spline reference: a path (latched) and one sample per tick"),
    _node("imager", "ImagerNode", inputs=("truth",), outputs=("measurement",), services=("inject_fault",),
          counters=("outlier_frames",), safe_stop=True, stage="imager", frames_outputs=("mr_frame", "mr_image"),
          summary="MRI imager: noisy frames at a frame rate, latency, outliers, dropouts; or MR frames of the bead "
                  "(imager.kind mr_images)"),
    _node("tracker", "TrackerNode", inputs=("mr_frame",), outputs=("measurement",), frames_only=True,
          counters=("imager_frames", "imager_frames_rejected"), safe_stop=True, stage="tracker",
          summary="only with MR frames: the bead's position in each frame (the scenario's tracker kind)"),
    _node("observer", "ObserverNode", inputs=("coil_applied", "measurement"), outputs=("estimate",),
          optional_inputs=("sequence_phase",),
          counters=("observer_rhs_evals", "measurements_used", "measurements_rejected"), safe_stop=True, stage="observer",
          summary="high-gain observer (eq. 25): position and velocity estimate"),
    _node("controller", "ControllerNode", inputs=("reference", "estimate"), outputs=("gradient_command",),
          optional_inputs=("sequence_phase",),
          safe_stop=True, stage="controller", summary="controller of the scenario's kind (law (24) by default): gradient command"),
    _node("coil_driver", "CoilDriverNode", inputs=("gradient_command",), optional_inputs=("coil_stall",),
          outputs=("coil_applied", "coil_state", "sequence_phase"), counters=("watchdog_ticks", "deferred_stalls"), stage="coil",
          summary="gradient coils: saturation, slew and dB/dt limits, watchdog; the scanner's sequence phase"),
    _node("plant", "PlantNode", inputs=("coil_applied",), outputs=("clock", "truth", "vessel_markers", "coil_stall"),
          services=("run_control", *SIMULATION_SERVICES),
          counters=("plant_steps", "plant_rejected_steps", "plant_rhs_evals", "plant_forced_steps"), stage="plant",
          summary="robot dynamics in the vessel; owns /clock"),
)

#: The recorder: subscribes to every topic, started before the loop and stopped after it.
RECORDER = Role("recorder", "vesselbot_recorder", "vesselbot_ros.nodes.recorder_node:RecorderNode",
                "vesselbot_ros.nodes.recorder_node", inputs=tuple(t.key for t in TOPICS), outputs=(),
                services=("recorder_flush",), summary="writes every topic into a rosbag2 MCAP bag, bytes as published")

SERVICES = SERVICES + tuple(
    ServiceSpec(reset_service_key(r.name), f"{r.name}/reset", "std_srvs/srv/Trigger", r.name,
                "lockstep: back to t = 0 with the scenario's initial state (the plant calls it on ResetSimulation)")
    for r in ROLES if reset_service_key(r.name) in r.services)

SERVICES = SERVICES + tuple(
    ServiceSpec(series_service_key(r.name), f"{r.name}/series", "vesselbot_msgs/srv/GetSeries", r.name,
                "the run series of its per-tick outputs, one row per tick (the launcher reads them after the run)")
    for r in ROLES if series_service_key(r.name) in r.services)

LOOP_ROLES: tuple[str, ...] = tuple(r.name for r in ROLES)


def loop_roles(frames: bool) -> tuple[str, ...]:
    """The loop's roles in start order in a graph whose imager delivers MR frames (``frames``: with the tracker)
    or positions (without it)."""
    return tuple(r.name for r in ROLES if frames or not r.frames_only)


def frame_topics() -> tuple[str, ...]:
    """The topic keys only a graph whose imager delivers MR frames publishes."""
    plain = {k for r in ROLES if not r.frames_only for k in r.outputs}
    return tuple(k for r in ROLES for k in r.outputs_for(True) if k not in plain)
ALL_ROLES: tuple[Role, ...] = (*ROLES, RECORDER)
NODE_NAMES: dict[str, str] = {r.name: r.node_name for r in ALL_ROLES}

_SERVICE = {s.key: s for s in SERVICES}
_ROLE = {r.name: r for r in ALL_ROLES}


def tick_time(k: int, dt_s: float) -> float:
    """``t_k = k * dt_s`` (s), exactly as the pure runner computes it."""
    return k * dt_s


def ns_of_time(t_s: float) -> int:
    """Float seconds -> integer nanoseconds (rounded): the stamp of a tick time."""
    return int(round(t_s * 1e9))


def tick_of_ns(ns: int, dt_s: float) -> tuple[int, bool]:
    """The one stamp -> tick helper: nearest tick to a stamp (ns), and whether the stamp lies on it (+/- 1 us)."""
    k = int(round(ns * 1e-9 / dt_s))
    return k, abs(ns - ns_of_time(tick_time(k, dt_s))) <= 1000


def topic(key: str) -> TopicSpec:
    """Look up a topic by its key (e.g. ``"truth"``)."""
    try:
        return _TOPIC[key]
    except KeyError:
        raise KeyError(f"unknown topic key {key!r}; known: {sorted(_TOPIC)}") from None


def service(key: str) -> ServiceSpec:
    """Look up a service by its key (e.g. ``"run_control"``)."""
    try:
        return _SERVICE[key]
    except KeyError:
        raise KeyError(f"unknown service key {key!r}; known: {sorted(_SERVICE)}") from None


def role(name: str) -> Role:
    """Look up a role (loop roles and ``recorder``)."""
    try:
        return _ROLE[name]
    except KeyError:
        raise KeyError(f"unknown role {name!r}; known: {sorted(_ROLE)}") from None


def namespace_of(name: str | None) -> str:
    """``NAME`` / ``/NAME`` / None -> an absolute namespace (None: the default)."""
    if not name:
        return DEFAULT_NAMESPACE
    return name if name.startswith("/") else "/" + name


def resolve(rel: str, namespace: str | None = None) -> str:
    """Absolute name of ``rel`` in ``namespace`` (globals move into a non-default namespace, see :func:`remap_args`)."""
    ns = namespace_of(namespace)
    if rel.startswith("/"):
        return rel if ns == DEFAULT_NAMESPACE else ns.rstrip("/") + rel
    return ns.rstrip("/") + "/" + rel


def remap_args(namespace: str | None = None) -> list[str]:
    """ROS arguments (after ``--ros-args``) that put a node of the graph into ``namespace``."""
    ns = namespace_of(namespace)
    if ns == DEFAULT_NAMESPACE:
        return []
    out = ["-r", f"__ns:={ns}"]
    for t in TOPICS:
        if t.is_global:
            out += ["-r", f"{t.rel}:={resolve(t.rel, ns)}"]
    return out


def qos_profile(spec: TopicSpec) -> Any:
    """The rclpy QoSProfile of a topic (imports rclpy lazily)."""
    # deferred: rclpy; the graph spec is read ROS-free (setup.py, the bag tools, the CLI's help)
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    durability = DurabilityPolicy.TRANSIENT_LOCAL if spec.qos == "reliable_latched" else DurabilityPolicy.VOLATILE
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=spec.depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=durability)


def qos_text(spec: TopicSpec) -> str:
    """The QoS of a topic in words."""
    latched = ", transient local" if spec.qos == "reliable_latched" else ""
    return f"reliable{latched}, keep last {spec.depth}"


def import_type(msgtype: str) -> Any:
    """The Python class of a ROS type ``pkg/msg/Name`` (or ``pkg/srv/Name``, ``pkg/action/Name``)."""
    pkg, kind, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


def console_scripts() -> list[str]:
    """``setup.py`` console entry points: ``vesselbot`` and one per node."""
    return ["vesselbot = vesselbot_ros.cli:main"] + [f"{r.console_script} = {r.module}:main" for r in ALL_ROLES]


def diagnostic_counters() -> dict[str, tuple[str, ...]]:
    """Role -> the diagnostic keys the launcher adds to a run's metrics."""
    return {r.name: r.counters for r in ROLES if r.counters}


def _note_lines(t: TopicSpec, width: int = 100) -> list[str]:
    """A port's note, wrapped and indented under its contract line."""
    return textwrap.wrap(t.note, width, initial_indent="      ", subsequent_indent="      ") if t.note else []


#: How long (s, wall) what the graph shows of a user's node in a slot (its name, its subscriptions) must stay the
#: same, once it publishes, before a run starts (the launcher's wiring; DDS announces publications and
#: subscriptions separately).
SLOT_SETTLE_S = 0.5


def role_contract(name: str, namespace: str | None = None, frames: bool | None = None) -> str:
    """What a user's node in the slot of role ``name`` must do (printed by ``vesselbot run --without``).

    ``frames``: in a graph whose imager delivers MR frames (True) or positions (False); None prints a role's
    ports in a graph of positions and, where they differ, the ports it has with MR frames."""
    r = role(name)
    lines = [f"slot '{name}' is yours: your node must"]
    ports = r.inputs_for(bool(frames)), r.outputs_for(bool(frames))

    def port_lines(inputs: tuple[str, ...], outputs: tuple[str, ...]) -> None:
        for k in inputs:
            t = topic(k)
            lines.append(f"  subscribe {resolve(t.rel, namespace)} [{t.msgtype}] ({t.units}, frame {t.frame})")
            lines.extend(_note_lines(t))
        for k in r.optional_inputs:
            t = topic(k)
            lines.append(f"  may subscribe {resolve(t.rel, namespace)} [{t.msgtype}] {t.rate} ({t.units}, "
                         f"frame {t.frame})")
            lines.extend(_note_lines(t))
        for k in outputs:
            t = topic(k)
            lines.append(f"  publish   {resolve(t.rel, namespace)} [{t.msgtype}] {t.rate} ({t.units}, frame {t.frame})")
            lines.extend(_note_lines(t))

    port_lines(*ports)
    with_frames = r.inputs_for(True), r.outputs_for(True)
    if frames is None and with_frames != ports:
        lines.append("  with an imager that delivers MR frames (imager.kind mr_images), instead:")
        port_lines(with_frames[0], tuple(k for k in with_frames[1] if k not in ports[1]))
    for k in r.services:
        if k == series_service_key(name):  # the launcher reads a user's node's outputs itself
            continue
        s = service(k)
        what = "serve     " if not s.is_action else "action    "
        lines.append(f"  {what}{resolve(s.rel, namespace)} [{s.srvtype}] ({s.purpose})")
    depth = {qos_text(topic(k)) for k in (*ports[0], *r.optional_inputs, *ports[1])
             if topic(k).qos != "reliable_latched"}
    lines.append(f"  with use_sim_time=true; QoS: {', '.join(sorted(depth))} (see docs/graph.md).")
    if name != "plant":
        lines.append("  Lockstep: answer tick k with header.stamp = t_k of the input that triggered it.")
        if ports[1]:
            lines.append(f"  The run starts once your node publishes and what the graph shows of it has not changed for "
                         f"{SLOT_SETTLE_S:g} s: create every subscription before (or within {SLOT_SETTLE_S:g} s of) your "
                         "publishers.")
    return "\n".join(lines)


def markdown_table() -> str:
    """The README's topic and service tables."""
    head = "| topic | type | publisher | subscribers | rate | QoS | units | frame |\n|---|---|---|---|---|---|---|---|\n"
    rows = [f"| `{t.name}` | `{t.msgtype}` | {t.publisher}"
            f"{f' ({t.frames_publisher} with MR frames)' if t.frames_publisher else ''} | {', '.join(t.subscribers)} | {t.rate} | "
            f"{qos_text(t)} | {t.units} | {t.frame} |" for t in TOPICS]
    srv_head = "\n\n| service / action | type | server | purpose |\n|---|---|---|---|\n"
    srv_rows = [f"| `{s.name}` | `{s.srvtype}` | {s.server} | {s.purpose} |" for s in SERVICES]
    return head + "\n".join(rows) + srv_head + "\n".join(srv_rows)


def view_table() -> str:
    """The README's live-view table: every channel the live view serves besides the topics."""
    head = "| channel | type | from | shows |\n|---|---|---|---|\n"
    rows = [f"| `{v.name}` | `{v.msgtype}` | {', '.join(f'`{topic(k).name}`' for k in v.inputs)} | {v.shows} |"
            for v in VIEW_CHANNELS]
    return head + "\n".join(rows)


def architecture_table() -> str:
    """The README's architecture table: one row per role, in start order."""
    head = "| role | node (console script) | does | in | out | services |\n|---|---|---|---|---|---|\n"
    rows = []
    for r in ALL_ROLES:
        ins = "every topic" if r is RECORDER else ", ".join(f"`{topic(k).name}`" for k in r.inputs)
        outs = ", ".join(f"`{topic(k).name}`" for k in r.outputs) or "-"
        srvs = ", ".join(f"`{service(k).name}`" for k in r.services) or "-"
        rows.append(f"| {r.name} | `{r.node_name}` | {r.summary} | {ins} | {outs} | {srvs} |")
    return head + "\n".join(rows)


def faults_table() -> str:
    """The README's node-loss table: what the launcher does when each process dies (from :attr:`Role.safe_stop`)."""
    head = "| process that dies | what `vesselbot run` does |\n|---|---|\n"
    rows = []
    for r in ALL_ROLES:
        if r.safe_stop:
            what = ("the loop goes on until the coil driver's watchdog has held the output for "
                    "`coil.command_timeout_s` and ramped it to zero within the slew limit; then every node stops, "
                    "the bag is finalised, exit 1 naming the node")
        elif r is RECORDER:
            what = "the run stops at once, exit 1 naming the recorder (nothing more could be recorded)"
        else:
            what = "the run stops at once (no sim time passes without it), the bag is finalised, exit 1 naming the node"
        rows.append(f"| {r.name} (`{r.node_name}`) | {what} |")
    rows.append("| the launcher itself (SIGKILL, SIGHUP, a crash) | every node gets SIGTERM from the kernel "
                "(parent-death signal), the recorder finalises the bag; the domain stays leased until the last "
                "node exited |")
    return head + "\n".join(rows)


def contract_table() -> str:
    """The README's ``--without ROLE`` contract: what a user's node in each slot must do."""
    return "\n\n".join("```text\n" + role_contract(r.name) + "\n```" for r in ROLES)
