"""The interface contract of the vesselbot graph: one table, used everywhere.

Nodes take topic names and QoS from here, the recorder subscribes to every
topic listed here, and the README's topic table is generated from (and tested
against) :data:`TOPICS`.  Importing this module does not import rclpy;
:func:`qos_profile` does, lazily.

Frame ``vessel``: x along the vessel axis (blood flows towards +x), z vertical
(gravity along -z), centreline at z = 0, walls at z = +/- D(t)/2.  y is unused
and always 0.

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
3. reference, on ``/clock`` k, publishes ``reference`` sample k;
4. observer, once it has ``measurement`` k and ``coil/applied`` k-1, publishes
   ``estimate`` (stamp t_k);
5. controller, once it has ``estimate`` k and ``reference`` k, publishes
   ``gradient_command`` (stamp t_k);
6. coil driver publishes ``coil/applied`` and ``coil/state`` (stamp t_k);
7. plant, once it has ``coil/applied`` k, integrates [t_k, t_k+1] and goes to 1.

Tick times are rebuilt as ``k * dt`` from the stamps (never by summing floats),
which is why a lockstep run reproduces the ROS-free runner bit for bit.

The estimate is a ``nav_msgs/Odometry`` in the XZ plane; its otherwise unused
yaw-yaw variance ``pose.covariance[35]`` carries the observer's time since the
last fresh measurement (s), which the controller's stale-estimate safe
behaviour reads.

Lockstep watchdog: if the command for tick k has not arrived within
``graph.stall_timeout_s`` of wall time (the controller died or hangs), the coil
driver answers tick k itself through ``CoilLimiter.watchdog``: it holds the
output until ``coil.command_timeout_s`` of sim time passed without commands,
then ramps to zero within the slew limit, so the loop (and the bag) goes on.
A late command for a tick already answered is rejected as stale.

In real-time mode the plant steps on the wall clock at a real-time factor and
applies the latest ``coil/applied`` (zero-order hold); the imager publishes only
fresh frames at its frame rate; observer and controller run on sim-time timers
at the control rate.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

__all__ = ["TopicSpec", "ServiceSpec", "TOPICS", "SERVICES", "FRAME_ID", "NODE_NAMES", "topic", "qos_profile"]

FRAME_ID = "vessel"
NS = "/vesselbot"

# node role -> ROS node name (used by the launcher, diagnostics and --without)
NODE_NAMES: dict[str, str] = {
    "plant": "vesselbot_plant",
    "imager": "vesselbot_imager",
    "observer": "vesselbot_observer",
    "controller": "vesselbot_controller",
    "coil_driver": "vesselbot_coil_driver",
    "reference": "vesselbot_reference",
    "recorder": "vesselbot_recorder",
}


@dataclass(frozen=True)
class TopicSpec:
    """One row of the topic table."""

    key: str  # short handle used in code, e.g. "truth"
    name: str  # absolute topic name
    msgtype: str  # ROS type, "pkg/msg/Name"
    publisher: str  # node role
    subscribers: tuple[str, ...]
    rate: str  # human-readable rate
    qos: Literal["reliable", "reliable_latched", "clock", "diagnostics"]
    units: str
    frame: str
    # Writers keep this many samples.  Reliable KEEP_LAST overwrites samples not
    # yet acknowledged once the history is full, and the recorder and the
    # launcher's monitor are not paced by the lockstep loop, so per-tick topics
    # keep 1 s at 1 kHz: a reader may fall that far behind without losing data.
    depth: int = 1000


@dataclass(frozen=True)
class ServiceSpec:
    """One row of the service table."""

    key: str
    name: str
    srvtype: str
    server: str
    purpose: str


TOPICS: tuple[TopicSpec, ...] = (
    TopicSpec("clock", "/clock", "rosgraph_msgs/msg/Clock", "plant", ("all (use_sim_time)", "reference"),
              "per tick", "clock", "s", "-"),
    TopicSpec("truth", f"{NS}/truth", "vesselbot_msgs/msg/PlantState", "plant", ("imager", "recorder"),
              "per tick", "reliable", "m, m/s, N, T/m", FRAME_ID),
    TopicSpec("vessel_markers", f"{NS}/vessel_markers", "visualization_msgs/msg/MarkerArray", "plant", ("viewers",),
              "once (latched)", "reliable_latched", "m", FRAME_ID, depth=1),
    TopicSpec("measurement", f"{NS}/measurement", "geometry_msgs/msg/PointStamped", "imager", ("observer",),
              "per tick (lockstep, ZOH) / frame rate (real time)", "reliable", "m", FRAME_ID),
    TopicSpec("estimate", f"{NS}/estimate", "nav_msgs/msg/Odometry", "observer", ("controller",),
              "per tick", "reliable", "m, m/s", FRAME_ID),
    TopicSpec("reference", f"{NS}/reference", "vesselbot_msgs/msg/ReferenceSample", "reference", ("controller",),
              "per tick", "reliable", "m, m/s, m/s^2", FRAME_ID),
    TopicSpec("reference_path", f"{NS}/reference/path", "nav_msgs/msg/Path", "reference", ("viewers",),
              "once (latched)", "reliable_latched", "m", FRAME_ID, depth=1),
    TopicSpec("gradient_command", f"{NS}/gradient_command", "geometry_msgs/msg/Vector3Stamped", "controller",
              ("coil_driver",), "per tick", "reliable", "T/m", FRAME_ID),
    TopicSpec("coil_applied", f"{NS}/coil/applied", "geometry_msgs/msg/Vector3Stamped", "coil_driver",
              ("plant", "observer"), "per tick (+ watchdog)", "reliable", "T/m", FRAME_ID),
    TopicSpec("coil_state", f"{NS}/coil/state", "vesselbot_msgs/msg/CoilState", "coil_driver", ("recorder",),
              "per tick (+ watchdog)", "reliable", "T/m, T/m/s", FRAME_ID),
    TopicSpec("diagnostics", "/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", "all", ("launcher", "recorder"),
              "1 Hz wall + on events", "diagnostics", "-", "-"),
)

SERVICES: tuple[ServiceSpec, ...] = (
    ServiceSpec("inject_fault", f"{NS}/imager/inject_fault", "vesselbot_msgs/srv/InjectFault", "imager",
                "inject an outlier burst or a dropout on the imager"),
    ServiceSpec("run_control", f"{NS}/run_control", "vesselbot_msgs/srv/RunControl", "plant",
                "start / pause / resume / stop / status of the run"),
)

_BY_KEY = {t.key: t for t in TOPICS}


def topic(key: str) -> TopicSpec:
    """Look up a topic row by its short key (e.g. ``"truth"``)."""
    try:
        return _BY_KEY[key]
    except KeyError:
        raise KeyError(f"unknown topic key {key!r}; known: {sorted(_BY_KEY)}") from None


def qos_profile(spec: TopicSpec) -> Any:
    """The rclpy QoSProfile for a topic row (imports rclpy lazily)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    durability = DurabilityPolicy.TRANSIENT_LOCAL if spec.qos == "reliable_latched" else DurabilityPolicy.VOLATILE
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=spec.depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=durability,
    )


def markdown_table() -> str:
    """The README's topic table (tested to match README.md)."""
    head = "| topic | type | publisher | subscribers | rate | QoS | units | frame |\n|---|---|---|---|---|---|---|---|\n"
    qos_txt = {
        "reliable": "reliable, keep last {d}",
        "reliable_latched": "reliable, transient local, keep last {d}",
        "clock": "reliable, keep last {d}",
        "diagnostics": "reliable, keep last {d}",
    }
    rows = [
        f"| `{t.name}` | `{t.msgtype}` | {t.publisher} | {', '.join(t.subscribers)} | {t.rate} | "
        f"{qos_txt[t.qos].format(d=t.depth)} | {t.units} | {t.frame} |"
        for t in TOPICS
    ]
    srv_head = "\n\n| service | type | server | purpose |\n|---|---|---|---|\n"
    srv_rows = [f"| `{s.name}` | `{s.srvtype}` | {s.server} | {s.purpose} |" for s in SERVICES]
    return head + "\n".join(rows) + srv_head + "\n".join(srv_rows)
