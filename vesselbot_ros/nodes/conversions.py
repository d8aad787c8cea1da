"""Every message <-> numpy conversion of the node graph, in one place.

Conventions (see :mod:`vesselbot_ros.graph_spec`): frame ``vessel`` with x along
the vessel axis, z vertical and y the scanner's horizontal axis across the
bore.  Messages carry 3-D vectors; the core's arrays have one entry per axis
of the scenario (``Scenario.dims``, :data:`~vesselbot_ros.physics.axes.AXES`): a planar scenario works on
(2,) arrays ``(x, z)`` and its messages carry ``y = 0``; a 3-D vessel tree
works on (3,) arrays ``(x, y, z)`` and y is real.  Every helper that packs or
unpacks a vector takes that one switch, ``dims`` (2 unless given), so a node
passes its scenario's and holds no condition of its own; a planar message is
byte for byte what it was before 3-D trees existed.  In a 3-D tree the coil
state also carries ``slew_limited_y`` (false in planar scenarios), and its
scene (wall mesh, centrelines and route: :func:`network_markers_3d`,
:func:`path_msg` of (n, 3) points) its real y.  Times are float seconds in the
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
from sensor_msgs.msg import Image
from std_msgs.msg import Header
from vesselbot_msgs.msg import CoilState, PlantState, ReferenceSample, SequencePhase
from visualization_msgs.msg import Marker, MarkerArray

from vesselbot_ros.graph_spec import FRAME_ID, NETWORK_WALL_NS, WIRE_STRINGS, ns_of_time, tick_of_ns, tick_time
from vesselbot_ros.nodes.wire import FlatCodec, codec_for, message_builder
from vesselbot_ros.physics.axes import AXES
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
    "vector_array",
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
    "FRAME_ENCODING",
    "MAGNITUDE_ENCODING",
    "frame_image_msg",
    "empty_frame_msg",
    "magnitude_image_msg",
    "frame_samples",
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
_make_clock = codec(Clock).maker("clock.sec", "clock.nanosec")


def _axes(prefix: str, dims: int) -> tuple[str, ...]:
    """The paths of vector ``prefix``'s components the core's (dims,) arrays fill (``point.x``, ``point.z``...)."""
    return tuple(f"{prefix}.{c}" for c in AXES[dims])


def _makers(d: int) -> dict[str, Any]:
    """The flat-form builders of the per-tick messages for ``d``-axis vectors (the others' components stay 0)."""
    return {
        "measurement": codec(PointStamped).maker(*_STAMP, *_axes("point", d)),
        "gradient": codec(Vector3Stamped).maker(*_STAMP, *_axes("vector", d)),
        "estimate": codec(Odometry).maker(*_STAMP, *_axes("pose.pose.position", d), *_axes("twist.twist.linear", d),
                                          f"pose.covariance_{AGE_COVARIANCE_INDEX}",
                                          f"twist.covariance_{FLOW_SCALE_COVARIANCE_INDEX}"),
        "reference": codec(ReferenceSample).maker(*_STAMP, "tick", *_axes("position", d), *_axes("velocity", d),
                                                  *_axes("acceleration", d)),
        "coil_state": codec(CoilState).maker(
            *_STAMP, "tick", *_axes("commanded", d), *_axes("applied", d), "saturation_scale", "saturated",
            *(f"slew_limited_{c}" for c in AXES[d]), "command_rejected", "watchdog_active", "max_gradient",
            "slew_rate", "dbdt_limit", "dbdt_radius"),
        "plant_state": codec(PlantState).maker(
            *_STAMP, "tick", *_axes("position", d), *_axes("velocity", d), *_axes("blood_velocity", d),
            "vessel_diameter", "wall_gap_upper", "wall_gap_lower", "signed_wall_distance", "in_contact",
            "contact_phase", *_axes("applied_gradient", d), "forces.header.stamp.sec", "forces.header.stamp.nanosec",
            *(p for name in TERM_NAMES for p in _axes(f"forces.{name}", d))),
    }


#: per message, dims -> its flat-form builder; a vector of another length than ``dims`` is refused (TypeError: the
#: builder takes exactly ``dims`` components per vector)
_MAKE = {d: _makers(d) for d in AXES}
_MAKE_MEASUREMENT, _MAKE_GRADIENT, _MAKE_ESTIMATE, _MAKE_REFERENCE, _MAKE_COIL_STATE, _MAKE_PLANT_STATE = (
    {d: _MAKE[d][name] for d in AXES}
    for name in ("measurement", "gradient", "estimate", "reference", "coil_state", "plant_state"))


def _xs(a: Any) -> list[float]:
    """A vector's components as Python floats: a float64 array's exactly, in one ``tolist`` call (iterating the
    array costs five times more on the hot path)."""
    if type(a) is np.ndarray and a.dtype.char == "d":
        return a.tolist()
    return [float(v) for v in a]


def _flags(a: Any) -> list[bool]:
    """A per-axis flag array's components as Python bools (one ``tolist`` call for a bool array)."""
    if type(a) is np.ndarray and a.dtype.char == "?":
        return a.tolist()
    return [bool(v) for v in a]


def stamp_ns(v: Any) -> int:
    """Stamp (ns) of a per-tick message with a header, in its flat form."""
    return v.header_stamp_sec * NS_PER_S + v.header_stamp_nanosec


def clock_flat(t_s: float) -> Any:
    """``/clock`` for sim time ``t_s`` (flat form)."""
    return _make_clock(*divmod(ns_of_time(t_s), NS_PER_S))


def measurement_flat(t_acq_s: float, p: npt.ArrayLike, dims: int = 2) -> Any:
    """An imager frame (flat form): stamp = acquisition time, point = measured position (m), ``(dims,)``."""
    return _MAKE_MEASUREMENT[dims](*divmod(ns_of_time(t_acq_s), NS_PER_S), *_xs(p))


def gradient_flat(t_s: float, g: npt.ArrayLike, dims: int = 2) -> Any:
    """A gradient (T/m, ``(dims,)``) stamped ``t_s`` (flat form)."""
    return _MAKE_GRADIENT[dims](*divmod(ns_of_time(t_s), NS_PER_S), *_xs(g))


def estimate_flat(t_s: float, x_hat: npt.ArrayLike, z_hat: npt.ArrayLike, age_s: float, flow_scale: float = 1.0,
                  dims: int = 2) -> Any:
    """Observer estimate at ``t_s`` (flat form): position (m), velocity (m/s), each ``(dims,)``, measurement age (s),
    blood-velocity scale (-)."""
    # inf age (no measurement yet) cannot travel as a finite number: clamp it
    return _MAKE_ESTIMATE[dims](*divmod(ns_of_time(t_s), NS_PER_S), *_xs(x_hat), *_xs(z_hat),
                                float(age_s) if math.isfinite(age_s) else 1e9, float(flow_scale))


def reference_flat(k: int, t_s: float, p: npt.ArrayLike, v: npt.ArrayLike, a: npt.ArrayLike, dims: int = 2) -> Any:
    """Reference sample k (flat form): ``X_ref`` (m), ``Xd_ref`` (m/s), ``Xdd_ref`` (m/s^2), each ``(dims,)``."""
    return _MAKE_REFERENCE[dims](*divmod(ns_of_time(t_s), NS_PER_S), int(k), *_xs(p), *_xs(v), *_xs(a))


def coil_state_flat(k: int, t_s: float, commanded: npt.ArrayLike, out: Any, limits: Any, watchdog: bool,
                    dbdt_limit_T_per_s: float = 0.0, dbdt_radius_m: float = 0.0, dims: int = 2) -> Any:
    """CoilState (flat form) from a :class:`~vesselbot_ros.scanner.actuator_limits.CoilOutput` (dB/dt 0: no limit);
    vectors and slew flags ``(dims,)``."""
    return _MAKE_COIL_STATE[dims](
        *divmod(ns_of_time(t_s), NS_PER_S), int(k), *_xs(commanded), *_xs(out.applied),
        float(out.k_scale), bool(out.saturated), *_flags(out.slew_limited), bool(out.rejected), bool(watchdog),
        float(limits.saturation_T_per_m), float(limits.slew_rate_T_per_m_per_s), float(dbdt_limit_T_per_s),
        float(dbdt_radius_m))


def plant_state_flat(k: int, t_s: float, p: npt.ArrayLike, v: npt.ArrayLike, blood_velocity: tuple[float, ...],
                     diameter_m: float, gap_upper_m: float, gap_lower_m: float, signed_wall_distance_m: float,
                     in_contact: bool, contact_phase: int, applied: npt.ArrayLike, forces: npt.ArrayLike,
                     dims: int = 2) -> Any:
    """The plant's ground truth of tick ``k`` (flat form): vectors ``(dims,)``, ``forces`` (8, dims), rows in the
    kernel's ``TERM_NAMES`` order (N)."""
    sec, nsec = divmod(ns_of_time(t_s), NS_PER_S)
    f = np.asarray(forces, dtype=np.float64)
    if f.shape != (len(TERM_NAMES), dims):
        raise TypeError(f"forces must be ({len(TERM_NAMES)}, {dims}), got {f.shape}")
    return _MAKE_PLANT_STATE[dims](
        sec, nsec, int(k), *_xs(p), *_xs(v), *_xs(blood_velocity), float(diameter_m),
        float(gap_upper_m), float(gap_lower_m), float(signed_wall_distance_m), bool(in_contact), int(contact_phase),
        *_xs(applied), sec, nsec, *f.ravel().tolist())


def clock_msg(t_s: float) -> Clock:
    """``/clock`` message for sim time ``t_s``."""
    return codec(Clock).to_message(clock_flat(t_s))


def measurement_msg(t_acq_s: float, p: npt.ArrayLike, dims: int = 2) -> PointStamped:
    """An imager frame: stamp = acquisition time, point = measured position (m), ``(dims,)``."""
    return codec(PointStamped).to_message(measurement_flat(t_acq_s, p, dims))


def estimate_msg(t_s: float, x_hat: npt.ArrayLike, z_hat: npt.ArrayLike, age_s: float,
                 flow_scale: float = 1.0, dims: int = 2) -> Odometry:
    """Observer estimate at ``t_s``: position (m), velocity (m/s), measurement age (s), blood-velocity scale (-)."""
    return codec(Odometry).to_message(estimate_flat(t_s, x_hat, z_hat, age_s, flow_scale, dims))


def estimate_flow_scale(v: Any) -> float:
    """The blood-velocity scale an estimate (flat form) carries (``twist.covariance[35]``); 1 if unset, non-finite or <= 0."""
    s = float(v.twist_covariance_35)
    return s if math.isfinite(s) and s > 0.0 else 1.0


def vector_array(x: float, y: float, z: float, dims: int = 2) -> npt.NDArray[np.float64]:
    """A message's vector -> the core's array: ``(x, z)`` in a planar scenario (y is 0 there), ``(x, y, z)`` in a
    3-D tree (``dims`` 3)."""
    return np.array([x, y, z] if dims == 3 else [x, z])  # axis count at the wire's edge (physics.axes.AXES)


def estimate_arrays(v: Any, dims: int = 2) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], float]:
    """Estimate (flat form) -> ``(x_hat (dims,) m, z_hat (dims,) m/s, age s)``."""
    return (vector_array(v.pose_pose_position_x, v.pose_pose_position_y, v.pose_pose_position_z, dims),
            vector_array(v.twist_twist_linear_x, v.twist_twist_linear_y, v.twist_twist_linear_z, dims),
            float(v.pose_covariance_35))


def reference_msg(k: int, t_s: float, p: npt.ArrayLike, v: npt.ArrayLike, a: npt.ArrayLike,
                  dims: int = 2) -> ReferenceSample:
    """Reference sample k: ``X_ref`` (m), ``Xd_ref`` (m/s), ``Xdd_ref`` (m/s^2), each ``(dims,)``."""
    return codec(ReferenceSample).to_message(reference_flat(k, t_s, p, v, a, dims))


def reference_arrays(v: Any, dims: int = 2) -> tuple[npt.NDArray[np.float64], ...]:
    """Reference sample (flat form) -> ``(p, v, a)``, each (dims,)."""
    return (vector_array(v.position_x, v.position_y, v.position_z, dims),
            vector_array(v.velocity_x, v.velocity_y, v.velocity_z, dims),
            vector_array(v.acceleration_x, v.acceleration_y, v.acceleration_z, dims))


def gradient_msg(t_s: float, g: npt.ArrayLike, dims: int = 2) -> Vector3Stamped:
    """A gradient (T/m, ``(dims,)``) stamped ``t_s``."""
    return codec(Vector3Stamped).to_message(gradient_flat(t_s, g, dims))


def coil_state_msg(k: int, t_s: float, commanded: npt.ArrayLike, out: Any, limits: Any, watchdog: bool,
                   dbdt_limit_T_per_s: float = 0.0, dbdt_radius_m: float = 0.0, dims: int = 2) -> CoilState:
    """CoilState from a :class:`~vesselbot_ros.scanner.actuator_limits.CoilOutput` (dB/dt 0: no dB/dt limit)."""
    return codec(CoilState).to_message(coil_state_flat(k, t_s, commanded, out, limits, watchdog, dbdt_limit_T_per_s,
                                                       dbdt_radius_m, dims))


def plant_state_msg(k: int, t_s: float, p: npt.ArrayLike, v: npt.ArrayLike, blood_velocity: tuple[float, ...],
                    diameter_m: float, gap_upper_m: float, gap_lower_m: float, signed_wall_distance_m: float,
                    in_contact: bool, contact_phase: int, applied: npt.ArrayLike, forces: npt.ArrayLike,
                    dims: int = 2) -> PlantState:
    """The plant's ground truth of tick ``k``: vectors ``(dims,)``, ``forces`` (8, dims), rows in the kernel's
    ``TERM_NAMES`` order (N)."""
    return codec(PlantState).to_message(plant_state_flat(k, t_s, p, v, blood_velocity, diameter_m, gap_upper_m,
                                                         gap_lower_m, signed_wall_distance_m, in_contact,
                                                         contact_phase, applied, forces, dims))


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
    to_point = point if pts.shape[1] == 2 else point3  # axis count at the wire's edge (a planar point's y is 0)
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

    ``geom`` is a :class:`vesselbot_ros.vessels.tube_geometry.NetworkGeometry` (the centrelines, a LINE_STRIP per
    branch, points every ``step_m``); ``wall_segments_m`` (k, 4) rows ``(ax, az, bx, bz)`` (m) are the meshed
    wall's segments (:attr:`vesselbot_ros.geometry.polyline_wall.WallQuery.segments`), the wall whose exact distance the
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

    ``geom`` is a :class:`vesselbot_ros.vessels.tube_geometry.NetworkGeometry` (the 3-D centrelines, a LINE_STRIP
    per branch with its real y, a point every ``step_m``); ``vertices_m`` (n, 3) and ``triangles`` (k, 3)
    are the meshed lumen wall (open ends, the inlet and outlet caps, left out).  The same namespaces and
    ids as :func:`network_markers` (the planar network's), so a viewer's settings apply to both.
    """
    out = MarkerArray()
    out.markers.append(wall_mesh_marker(vertices_m, triangles))
    _centreline_markers(out, ((name, pts[:, 0], pts[:, 1], pts[:, 2]) for name, (pts, _r, _s) in
                              geom.branches.items()), geom.net.sample_spacing_m, robot_radius_m, step_m)
    return out


#: ``imager/frame``'s encoding: complex128 samples, real and imaginary parts (little-endian float64 each).
FRAME_ENCODING = "64FC2"
#: ``imager/image``'s encoding: the magnitude, float32 (what Foxglove's Image panel shows).
MAGNITUDE_ENCODING = "32FC1"


def frame_image_msg(t_acq_s: float, samples: npt.ArrayLike) -> Image:
    """``imager/frame``: an MR frame's complex samples (2-D: rows x columns) as a 64FC2 image stamped ``t_acq_s``."""
    a = np.ascontiguousarray(samples, dtype="<c16")
    rows, cols = a.shape
    return Image(header=header(t_acq_s), height=rows, width=cols, encoding=FRAME_ENCODING, is_bigendian=0,
                 step=16 * cols, data=a.tobytes())


def empty_frame_msg(t_s: float) -> Image:
    """``imager/frame`` of a tick without a new frame (lockstep): an empty image stamped ``t_s``."""
    return Image(header=header(t_s), height=0, width=0, encoding=FRAME_ENCODING, is_bigendian=0, step=0)


def magnitude_image_msg(t_acq_s: float, samples: npt.ArrayLike) -> Image:
    """``imager/image``: the magnitude of an MR frame's samples (32FC1), for viewers."""
    m = np.ascontiguousarray(np.abs(np.asarray(samples)), dtype="<f4")
    rows, cols = m.shape
    return Image(header=header(t_acq_s), height=rows, width=cols, encoding=MAGNITUDE_ENCODING, is_bigendian=0,
                 step=4 * cols, data=m.tobytes())


def frame_samples(msg: Any) -> npt.NDArray[np.complex128] | None:
    """The complex samples of an ``imager/frame`` message (rows, columns), or None if it is empty (no frame).

    Raises:
        ValueError: not a 64FC2 little-endian image, or its data do not hold height x width samples.
    """
    if msg.height == 0 or msg.width == 0:
        return None
    if msg.encoding != FRAME_ENCODING or msg.is_bigendian or msg.step != 16 * msg.width:
        raise ValueError(f"expected a little-endian {FRAME_ENCODING} image with step 16 x width, got encoding "
                         f"{msg.encoding!r}, big-endian {bool(msg.is_bigendian)}, step {msg.step} for width {msg.width}")
    data = bytes(msg.data)
    if len(data) != 16 * msg.height * msg.width:
        raise ValueError(f"{len(data)} bytes for a {msg.height} x {msg.width} {FRAME_ENCODING} image")
    return np.frombuffer(data, dtype="<c16").reshape(msg.height, msg.width).astype(np.complex128)
