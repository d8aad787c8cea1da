"""Every message <-> numpy conversion of the node graph, in one place.

Conventions (see :mod:`vesselbot_ros.graph_spec`): frame ``vessel`` with x along
the vessel axis and z vertical; the pure core works on (2,) arrays ``(x, z)``,
messages carry 3-D vectors with ``y = 0``.  A 3-D vessel tree's scene (its
wall mesh, centrelines and route: :func:`network_markers_3d`, :func:`path_msg` of
(n, 3) points) carries its real y.  Times are float seconds in the
core and integer nanoseconds (``builtin_interfaces/Time``) on the wire.

Tick times.  Tick ``k`` holds at ``t_k = k * dt`` with ``dt = 1 / control_rate_Hz``
(float, the pure runner's ``np.arange(n) * dt``).  A stamp is ``round(t_k * 1e9)`` ns; receivers do not
convert the stamp back to float (that could differ from ``t_k`` in the last
bit) but recover ``k`` with :func:`tick_of_ns` and recompute ``t_k`` with
:func:`tick_time`: this is what makes a lockstep run over ROS bit-identical to
the pure runner.

Estimates travel as ``nav_msgs/Odometry``.  The core's estimate also carries
the age of the last used measurement (the controller's staleness input); it
is stored in ``pose.covariance[35]`` (the yaw-yaw slot, meaningless in this
planar x-z problem).  The observer's blood-velocity scale ``s_hat``
(:class:`~vesselbot_ros.control.ekf_observer.ExtendedKalmanObserver`; 1 when
not estimated), which law (24) takes with ``controller.flow_compensation:
estimate``, is stored in ``twist.covariance[35]`` (the yaw-rate slot, as
meaningless here); 0 there (a user's observer that does not set it) reads
as 1.  All other covariance entries are 0 (not estimated).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, PointStamped, PoseStamped, Vector3Stamped
from nav_msgs.msg import Odometry, Path
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Header
from vesselbot_msgs.msg import CoilState, PlantState, ReferenceSample, SequencePhase
from visualization_msgs.msg import Marker, MarkerArray

from vesselbot_ros.graph_spec import FRAME_ID, NETWORK_WALL_NS, WIRE_STRINGS, ns_of_time, tick_of_ns, tick_time
from vesselbot_ros.nodes.wire import FlatCodec, codec_for, message_builder
from vesselbot_ros.physics.kernel import TERM_NAMES
from vesselbot_ros.scanner.sequence import PHASE_CODES

__all__ = [
    "AGE_COVARIANCE_INDEX",
    "FLOW_SCALE_COVARIANCE_INDEX",
    "tick_time",
    "ns_of_time",
    "tick_of_ns",
    "stamp_of_ns",
    "ns_of_stamp",
    "header",
    "point",
    "point3",
    "codec",
    "stamp_ns",
    "clock_flat",
    "measurement_flat",
    "gradient_flat",
    "estimate_flat",
    "reference_flat",
    "coil_state_flat",
    "plant_state_flat",
    "clock_msg",
    "measurement_msg",
    "estimate_msg",
    "estimate_arrays",
    "estimate_flow_scale",
    "reference_msg",
    "reference_arrays",
    "gradient_msg",
    "coil_state_msg",
    "plant_state_msg",
    "message_builder",
    "path_msg",
    "vessel_markers",
    "network_markers",
    "network_markers_3d",
    "wall_mesh_marker",
    "WALL_MESH_RGBA",
]

_time = message_builder(Time)
_header = message_builder(Header)
_point = message_builder(Point)

AGE_COVARIANCE_INDEX = 35
#: Index in the estimate's ``twist.covariance`` (the otherwise unused yaw-rate variance) carrying the observer's
#: blood-velocity scale ``s_hat`` (-), which the flow-compensating law reads; 0 (an observer that does not
#: estimate it, a bag recorded before it travelled), or any value not finite and > 0, reads as 1.
FLOW_SCALE_COVARIANCE_INDEX = 35
NS_PER_S = 1_000_000_000
#: Colour (r, g, b, a) of a 3-D vessel's wall mesh: translucent, so the robot, its estimate and the route inside
#: the lumen show through it.
WALL_MESH_RGBA = (0.8, 0.2, 0.2, 0.3)


def stamp_of_ns(ns: int) -> Time:
    """Integer ns -> ``builtin_interfaces/Time``."""
    sec, nsec = divmod(int(ns), NS_PER_S)
    return _time(sec=sec, nanosec=nsec)


def ns_of_stamp(stamp: Any) -> int:
    """``builtin_interfaces/Time`` -> integer ns."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def header(t_s: float) -> Header:
    """Header stamped ``t_s`` in frame ``vessel``."""
    return _header(stamp=stamp_of_ns(ns_of_time(t_s)), frame_id=FRAME_ID)


def point(a: npt.ArrayLike) -> Point:
    """(2,) ``(x, z)`` -> Point with y = 0."""
    return _point(x=float(a[0]), y=0.0, z=float(a[1]))  # type: ignore[index, arg-type]  # ArrayLike: callers pass arrays or tuples


def point3(a: npt.ArrayLike) -> Point:
    """(3,) ``(x, y, z)`` -> Point."""
    return _point(x=float(a[0]), y=float(a[1]), z=float(a[2]))  # type: ignore[index, arg-type]  # ArrayLike: callers pass arrays or tuples


def codec(cls: Any) -> FlatCodec:
    """The flat codec of per-tick message type ``cls`` with the graph's strings (every per-tick type has one)."""
    c = codec_for(cls, WIRE_STRINGS)
    if c is None:
        raise TypeError(f"{cls.__name__} has no flat layout")
    return c


# The per-tick messages are built in their flat form (nodes/wire.py: a named tuple of the CDR's values, which one
# struct call turns into the CDR); ``*_msg`` turns one into the rclpy message, for tools and tests.
_STAMP = ("header.stamp.sec", "header.stamp.nanosec")
_XZ = (".x", ".z")
_make_clock = codec(Clock).maker("clock.sec", "clock.nanosec")
_make_measurement = codec(PointStamped).maker(*_STAMP, "point.x", "point.z")
_make_gradient = codec(Vector3Stamped).maker(*_STAMP, "vector.x", "vector.z")
_make_estimate = codec(Odometry).maker(*_STAMP, "pose.pose.position.x", "pose.pose.position.z",
                                       "twist.twist.linear.x", "twist.twist.linear.z",
                                       f"pose.covariance_{AGE_COVARIANCE_INDEX}",
                                       f"twist.covariance_{FLOW_SCALE_COVARIANCE_INDEX}")
_make_reference = codec(ReferenceSample).maker(*_STAMP, "tick", *(f"{v}{c}" for v in ("position", "velocity",
                                                                                     "acceleration") for c in _XZ))
_make_coil_state = codec(CoilState).maker(
    *_STAMP, "tick", "commanded.x", "commanded.z", "applied.x", "applied.z", "saturation_scale", "saturated",
    "slew_limited_x", "slew_limited_z", "command_rejected", "watchdog_active", "max_gradient", "slew_rate",
    "dbdt_limit", "dbdt_radius")
_make_plant_state = codec(PlantState).maker(
    *_STAMP, "tick", "position.x", "position.z", "velocity.x", "velocity.z", "blood_velocity.x", "blood_velocity.z",
    "vessel_diameter", "wall_gap_upper", "wall_gap_lower", "signed_wall_distance", "in_contact", "contact_phase",
    "applied_gradient.x", "applied_gradient.z", "forces.header.stamp.sec", "forces.header.stamp.nanosec",
    *(f"forces.{name}{c}" for name in TERM_NAMES for c in _XZ))


def stamp_ns(v: Any) -> int:
    """Stamp (ns) of a per-tick message with a header, in its flat form."""
    return v.header_stamp_sec * NS_PER_S + v.header_stamp_nanosec


def clock_flat(t_s: float) -> Any:
    """``/clock`` for sim time ``t_s`` (flat form)."""
    return _make_clock(*divmod(ns_of_time(t_s), NS_PER_S))


def measurement_flat(t_acq_s: float, p: npt.ArrayLike) -> Any:
    """An imager frame (flat form): stamp = acquisition time, point = measured position (m)."""
    return _make_measurement(*divmod(ns_of_time(t_acq_s), NS_PER_S), float(p[0]), float(p[1]))  # type: ignore[index, arg-type]  # ArrayLike: callers pass arrays or tuples


def gradient_flat(t_s: float, g: npt.ArrayLike) -> Any:
    """A gradient (T/m) stamped ``t_s`` (flat form)."""
    return _make_gradient(*divmod(ns_of_time(t_s), NS_PER_S), float(g[0]), float(g[1]))  # type: ignore[index, arg-type]  # ArrayLike: callers pass arrays or tuples


def estimate_flat(t_s: float, x_hat: npt.ArrayLike, z_hat: npt.ArrayLike, age_s: float, flow_scale: float = 1.0) -> Any:
    """Observer estimate at ``t_s`` (flat form): position (m), velocity (m/s), measurement age (s), blood-velocity scale (-)."""
    # inf age (no measurement yet) cannot travel as a finite number: clamp it
    return _make_estimate(*divmod(ns_of_time(t_s), NS_PER_S), float(x_hat[0]), float(x_hat[1]),  # type: ignore[index, arg-type]  # ArrayLike: callers pass arrays or tuples
                          float(z_hat[0]), float(z_hat[1]), float(age_s) if math.isfinite(age_s) else 1e9,  # type: ignore[index, arg-type]  # ArrayLike: callers pass arrays or tuples
                          float(flow_scale))


def reference_flat(k: int, t_s: float, p: npt.ArrayLike, v: npt.ArrayLike, a: npt.ArrayLike) -> Any:
    """Reference sample k (flat form): ``X_ref`` (m), ``Xd_ref`` (m/s), ``Xdd_ref`` (m/s^2)."""
    return _make_reference(*divmod(ns_of_time(t_s), NS_PER_S), int(k), float(p[0]), float(p[1]),  # type: ignore[index, arg-type]  # ArrayLike: callers pass arrays or tuples
                           float(v[0]), float(v[1]), float(a[0]), float(a[1]))  # type: ignore[index, arg-type]  # ArrayLike: callers pass arrays or tuples


def coil_state_flat(k: int, t_s: float, commanded: npt.ArrayLike, out: Any, limits: Any, watchdog: bool,
                    dbdt_limit_T_per_s: float = 0.0, dbdt_radius_m: float = 0.0) -> Any:
    """CoilState (flat form) from a :class:`~vesselbot_ros.control.actuator_limits.CoilOutput` (dB/dt 0: no limit)."""
    slew = out.slew_limited
    return _make_coil_state(
        *divmod(ns_of_time(t_s), NS_PER_S), int(k), float(commanded[0]), float(commanded[1]),  # type: ignore[index, arg-type]  # ArrayLike: callers pass arrays or tuples
        float(out.applied[0]), float(out.applied[1]), float(out.k_scale), bool(out.saturated), bool(slew[0]),
        bool(slew[1]), bool(out.rejected), bool(watchdog), float(limits.saturation_T_per_m),
        float(limits.slew_rate_T_per_m_per_s), float(dbdt_limit_T_per_s), float(dbdt_radius_m))


def plant_state_flat(k: int, t_s: float, p: npt.ArrayLike, v: npt.ArrayLike, blood_velocity: tuple[float, float],
                     diameter_m: float, gap_upper_m: float, gap_lower_m: float, signed_wall_distance_m: float,
                     in_contact: bool, contact_phase: int, applied: npt.ArrayLike, forces: npt.ArrayLike) -> Any:
    """The plant's ground truth of tick ``k`` (flat form): ``forces`` is (8, 2), rows in the kernel's ``TERM_NAMES`` order (N)."""
    sec, nsec = divmod(ns_of_time(t_s), NS_PER_S)
    return _make_plant_state(
        sec, nsec, int(k), float(p[0]), float(p[1]), float(v[0]), float(v[1]),  # type: ignore[index, arg-type]  # ArrayLike: callers pass arrays or tuples
        float(blood_velocity[0]), float(blood_velocity[1]), float(diameter_m), float(gap_upper_m), float(gap_lower_m),
        float(signed_wall_distance_m), bool(in_contact), int(contact_phase), float(applied[0]),  # type: ignore[index, arg-type]  # ArrayLike: callers pass arrays or tuples
        float(applied[1]), sec, nsec, *np.asarray(forces, dtype=np.float64).ravel().tolist())  # type: ignore[index, arg-type]  # ArrayLike: callers pass arrays or tuples


def clock_msg(t_s: float) -> Clock:
    """``/clock`` message for sim time ``t_s``."""
    return codec(Clock).to_message(clock_flat(t_s))


def measurement_msg(t_acq_s: float, p: npt.ArrayLike) -> PointStamped:
    """An imager frame: stamp = acquisition time, point = measured position (m)."""
    return codec(PointStamped).to_message(measurement_flat(t_acq_s, p))


def estimate_msg(t_s: float, x_hat: npt.ArrayLike, z_hat: npt.ArrayLike, age_s: float,
                 flow_scale: float = 1.0) -> Odometry:
    """Observer estimate at ``t_s``: position (m), velocity (m/s), measurement age (s), blood-velocity scale (-)."""
    return codec(Odometry).to_message(estimate_flat(t_s, x_hat, z_hat, age_s, flow_scale))


def estimate_flow_scale(v: Any) -> float:
    """The blood-velocity scale an estimate (flat form) carries (``twist.covariance[35]``); 1 if unset, non-finite or <= 0."""
    s = float(v.twist_covariance_35)
    return s if math.isfinite(s) and s > 0.0 else 1.0


def estimate_arrays(v: Any) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], float]:
    """Estimate (flat form) -> ``(x_hat (2,) m, z_hat (2,) m/s, age s)``."""
    return (np.array([v.pose_pose_position_x, v.pose_pose_position_z]),
            np.array([v.twist_twist_linear_x, v.twist_twist_linear_z]), float(v.pose_covariance_35))


def reference_msg(k: int, t_s: float, p: npt.ArrayLike, v: npt.ArrayLike, a: npt.ArrayLike) -> ReferenceSample:
    """Reference sample k: ``X_ref`` (m), ``Xd_ref`` (m/s), ``Xdd_ref`` (m/s^2)."""
    return codec(ReferenceSample).to_message(reference_flat(k, t_s, p, v, a))


def reference_arrays(v: Any) -> tuple[npt.NDArray[np.float64], ...]:
    """Reference sample (flat form) -> ``(p, v, a)``, each (2,)."""
    return (np.array([v.position_x, v.position_z]), np.array([v.velocity_x, v.velocity_z]),
            np.array([v.acceleration_x, v.acceleration_z]))


def gradient_msg(t_s: float, g: npt.ArrayLike) -> Vector3Stamped:
    """A gradient (T/m) stamped ``t_s``."""
    return codec(Vector3Stamped).to_message(gradient_flat(t_s, g))


def coil_state_msg(k: int, t_s: float, commanded: npt.ArrayLike, out: Any, limits: Any, watchdog: bool,
                   dbdt_limit_T_per_s: float = 0.0, dbdt_radius_m: float = 0.0) -> CoilState:
    """CoilState from a :class:`~vesselbot_ros.control.actuator_limits.CoilOutput` (dB/dt 0: no dB/dt limit)."""
    return codec(CoilState).to_message(coil_state_flat(k, t_s, commanded, out, limits, watchdog, dbdt_limit_T_per_s,
                                                       dbdt_radius_m))


def plant_state_msg(k: int, t_s: float, p: npt.ArrayLike, v: npt.ArrayLike, blood_velocity: tuple[float, float],
                    diameter_m: float, gap_upper_m: float, gap_lower_m: float, signed_wall_distance_m: float,
                    in_contact: bool, contact_phase: int, applied: npt.ArrayLike, forces: npt.ArrayLike) -> PlantState:
    """The plant's ground truth of tick ``k``: ``forces`` is (8, 2), rows in the kernel's ``TERM_NAMES`` order (N)."""
    return codec(PlantState).to_message(plant_state_flat(k, t_s, p, v, blood_velocity, diameter_m, gap_upper_m,
                                                         gap_lower_m, signed_wall_distance_m, in_contact,
                                                         contact_phase, applied, forces))


def sequence_phase_msg(t_s: float, window: Any, latency_s: float, duty_cycle: float) -> SequencePhase:
    """SequencePhase (stamp ``t_s``, the first tick it applies to) from a :class:`~vesselbot_ros.scanner.sequence.PhaseWindow`."""
    return SequencePhase(header=header(t_s), phase=PHASE_CODES[window.phase], period_index=int(window.index),
                         window_start=float(window.start_s), window_end=float(window.end_s),
                         latency=float(latency_s), duty_cycle=float(duty_cycle))


def path_msg(points_m: npt.ArrayLike, t_s: float = 0.0) -> Path:
    """(n, 2) points ``(x, z)`` (m; y = 0) or (n, 3) points ``(x, y, z)`` (a 3-D route) -> nav_msgs/Path in frame vessel."""
    pts = np.asarray(points_m, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] not in (2, 3):
        raise ValueError(f"points_m must be (n, 2) or (n, 3), got shape {pts.shape}")
    to_point = point if pts.shape[1] == 2 else point3
    msg = Path(header=header(t_s))
    for p in pts:
        ps = PoseStamped(header=header(t_s))
        ps.pose.position = to_point(p)
        ps.pose.orientation.w = 1.0
        msg.poses.append(ps)
    return msg


def vessel_markers(x_min_m: float, x_max_m: float, diameter_m: float, robot_radius_m: float) -> MarkerArray:
    """Two LINE_STRIP walls at ``z = +/- D/2`` (nominal diameter), for viewers."""
    out = MarkerArray()
    for i, (name, z) in enumerate((("upper_wall", 0.5 * diameter_m), ("lower_wall", -0.5 * diameter_m))):
        m = Marker(header=header(0.0), ns=name, id=i, type=Marker.LINE_STRIP, action=Marker.ADD)
        m.scale.x = 0.1 * robot_radius_m
        m.color.r, m.color.g, m.color.b, m.color.a = 0.8, 0.2, 0.2, 1.0
        m.pose.orientation.w = 1.0
        m.points = [point((x_min_m, z)), point((x_max_m, z))]
        out.markers.append(m)
    return out


def network_markers(geom: Any, wall_segments_m: npt.NDArray[np.float64], robot_radius_m: float,
                    step_m: float = 2.0e-4) -> MarkerArray:
    """A vessel network for viewers: the meshed wall the plant sees (one LINE_LIST) and each branch's centreline.

    ``geom`` is a :class:`vesselbot_ros.vessels.network.NetworkGeometry` (the centrelines, a LINE_STRIP per
    branch, points every ``step_m``); ``wall_segments_m`` (k, 4) rows ``(ax, az, bx, bz)`` (m) are the meshed
    wall's segments (:attr:`vesselbot_ros.physics.meshed_wall.WallQuery.segments`), the wall whose exact distance the
    plant computes, junctions included, open ends (inlet and outlet caps) left out.
    """
    out = MarkerArray()
    wall = Marker(header=header(0.0), ns=NETWORK_WALL_NS, id=0, type=Marker.LINE_LIST, action=Marker.ADD)
    wall.scale.x = 0.1 * robot_radius_m
    wall.color.r, wall.color.g, wall.color.b, wall.color.a = 0.8, 0.2, 0.2, 1.0
    wall.pose.orientation.w = 1.0
    segs = np.asarray(wall_segments_m, dtype=np.float64).reshape(-1, 2)
    wall.points = [point((float(x), float(z))) for x, z in segs]
    out.markers.append(wall)
    _centreline_markers(out, ((name, pts[:, 0], np.zeros(len(pts)), pts[:, 1]) for name, (pts, _r, _s) in
                              geom.branches.items()), geom.net.sample_spacing_m, robot_radius_m, step_m)
    return out


def _centreline_markers(out: MarkerArray, branches: Any, spacing_m: float, robot_radius_m: float,
                        step_m: float) -> None:
    """Append one LINE_STRIP per branch (``(name, x, y, z)`` sample arrays, m), a point every ``step_m`` and the last."""
    stride = max(1, int(round(step_m / spacing_m)))
    for mid, (name, xs, ys, zs) in enumerate(branches, start=len(out.markers)):
        idx = np.unique(np.r_[np.arange(0, len(xs), stride), len(xs) - 1])
        m = Marker(header=header(0.0), ns=f"{name}/centreline", id=mid, type=Marker.LINE_STRIP, action=Marker.ADD)
        m.scale.x = 0.1 * robot_radius_m
        m.color.r, m.color.g, m.color.b, m.color.a = 0.5, 0.5, 0.5, 1.0
        m.pose.orientation.w = 1.0
        m.points = [_point(x=x, y=y, z=z) for x, y, z in zip(xs[idx].tolist(), ys[idx].tolist(), zs[idx].tolist())]
        out.markers.append(m)


def wall_mesh_marker(vertices_m: npt.ArrayLike, triangles: npt.ArrayLike,
                     rgba: tuple[float, float, float, float] = WALL_MESH_RGBA) -> Marker:
    """A triangle mesh (a 3-D vessel's lumen wall) as one TRIANGLE_LIST marker in frame ``vessel``.

    ``vertices_m`` (n, 3) (m) and ``triangles`` (k, 3) (vertex indices) give 3 k points: triangle i's vertices
    are points 3 i, 3 i + 1, 3 i + 2, in the triangles' order and each triangle's own vertex order (its
    winding, hence the side a viewer takes as its front).  One colour for the whole marker (``rgba``,
    translucent by default; no per-vertex colours); namespace :data:`~vesselbot_ros.graph_spec.NETWORK_WALL_NS`,
    id 0, which tells the live view it is a network's wall (it adds no straight walls then).

    Raises:
        ValueError: not (n, 3) vertices and (k, 3) triangles, an index outside the vertices, a vertex not finite.
    """
    v = np.asarray(vertices_m, dtype=np.float64)
    t = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices_m must be (n, 3), got shape {v.shape}")
    if t.ndim != 2 or t.shape[1] != 3 or not np.issubdtype(t.dtype, np.integer):
        raise ValueError(f"triangles must be (k, 3) integer vertex indices, got shape {t.shape}, dtype {t.dtype}")
    if t.size and (int(t.min()) < 0 or int(t.max()) >= len(v)):
        raise ValueError(f"triangles index vertices 0..{len(v) - 1}, got {int(t.min())}..{int(t.max())}")
    if not np.isfinite(v).all():
        raise ValueError(f"vertices_m must be finite, got {int((~np.isfinite(v)).any(axis=1).sum())} vertices that are not")
    m = Marker(header=header(0.0), ns=NETWORK_WALL_NS, id=0, type=Marker.TRIANGLE_LIST, action=Marker.ADD)
    m.pose.orientation.w = 1.0
    m.scale.x = m.scale.y = m.scale.z = 1.0  # a TRIANGLE_LIST's points are scaled by it
    m.color.r, m.color.g, m.color.b, m.color.a = (float(c) for c in rgba)
    m.points = [_point(x=x, y=y, z=z) for x, y, z in v[t.reshape(-1)].tolist()]
    return m


def network_markers_3d(geom: Any, vertices_m: npt.ArrayLike, triangles: npt.ArrayLike, robot_radius_m: float,
                       step_m: float = 2.0e-4) -> MarkerArray:
    """A 3-D vessel tree for viewers: its wall mesh (one TRIANGLE_LIST, :func:`wall_mesh_marker`) and each branch's centreline.

    ``geom`` is a :class:`vesselbot_ros.vessels.network.NetworkGeometry3D` (the 3-D centrelines, a LINE_STRIP
    per branch with its real y, a point every ``step_m``); ``vertices_m`` (n, 3) and ``triangles`` (k, 3)
    are the meshed lumen wall (open ends, the inlet and outlet caps, left out).  The same namespaces and
    ids as :func:`network_markers` (the planar network's), so a viewer's settings apply to both.
    """
    out = MarkerArray()
    out.markers.append(wall_mesh_marker(vertices_m, triangles))
    _centreline_markers(out, ((name, pts[:, 0], pts[:, 1], pts[:, 2]) for name, (pts, _r, _s) in
                              geom.branches.items()), geom.net.sample_spacing_m, robot_radius_m, step_m)
    return out
