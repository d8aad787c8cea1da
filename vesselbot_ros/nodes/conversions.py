"""Every message <-> numpy conversion of the node graph, in one place.

Conventions (see :mod:`vesselbot_ros.graph_spec`): frame ``vessel`` with x along
the vessel axis and z vertical; the pure core works on (2,) arrays ``(x, z)``,
messages carry 3-D vectors with ``y = 0``.  Times are float seconds in the
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
from collections.abc import Iterable
from typing import Any

import numpy as np
import numpy.typing as npt
from builtin_interfaces.msg import Time
from geometry_msgs.msg import (
    Point,
    PointStamped,
    Pose,
    PoseStamped,
    PoseWithCovariance,
    Quaternion,
    Twist,
    TwistWithCovariance,
    Vector3,
    Vector3Stamped,
)
from nav_msgs.msg import Odometry, Path
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Header
from visualization_msgs.msg import Marker, MarkerArray

from vesselbot_msgs.msg import CoilState, ForceBreakdown, PlantState, ReferenceSample, SequencePhase
from vesselbot_ros.graph_spec import CHILD_FRAME_ID, FRAME_ID, ns_of_time, tick_of_ns, tick_time
from vesselbot_ros.nodes.wire import message_builder
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
    "vector3",
    "point",
    "xz",
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
    "all_finite",
]

_time = message_builder(Time)
_header = message_builder(Header)
_vector3 = message_builder(Vector3)
_point = message_builder(Point)
_quaternion = message_builder(Quaternion)
_clock = message_builder(Clock)
_point_stamped = message_builder(PointStamped)
_vector3_stamped = message_builder(Vector3Stamped)
_pose = message_builder(Pose)
_twist = message_builder(Twist)
_pose_cov = message_builder(PoseWithCovariance)
_twist_cov = message_builder(TwistWithCovariance)
_odometry = message_builder(Odometry)
_reference_sample = message_builder(ReferenceSample)
_coil_state = message_builder(CoilState)
_plant_state = message_builder(PlantState)
_force_breakdown = message_builder(ForceBreakdown)

AGE_COVARIANCE_INDEX = 35
#: Index in the estimate's ``twist.covariance`` (the otherwise unused yaw-rate variance) carrying the observer's
#: blood-velocity scale ``s_hat`` (-), which the flow-compensating law reads; 0 (an observer that does not
#: estimate it, a bag recorded before it travelled), or any value not finite and > 0, reads as 1.
FLOW_SCALE_COVARIANCE_INDEX = 35
NS_PER_S = 1_000_000_000


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


def vector3(a: npt.ArrayLike) -> Vector3:
    """(2,) ``(x, z)`` -> Vector3 with y = 0."""
    return _vector3(x=float(a[0]), y=0.0, z=float(a[1]))  # type: ignore[index]


def point(a: npt.ArrayLike) -> Point:
    """(2,) ``(x, z)`` -> Point with y = 0."""
    return _point(x=float(a[0]), y=0.0, z=float(a[1]))  # type: ignore[index]


def xz(v: Any) -> npt.NDArray[np.float64]:
    """Point or Vector3 -> (2,) ``(x, z)``."""
    return np.array([v.x, v.z], dtype=np.float64)


def all_finite(values: Iterable[float]) -> bool:
    """True if every value is a finite float."""
    return all(math.isfinite(v) for v in values)


def clock_msg(t_s: float) -> Clock:
    """``/clock`` message for sim time ``t_s``."""
    return _clock(clock=stamp_of_ns(ns_of_time(t_s)))


def measurement_msg(t_acq_s: float, p: npt.ArrayLike) -> PointStamped:
    """An imager frame: stamp = acquisition time, point = measured position (m)."""
    return _point_stamped(header=header(t_acq_s), point=point(p))


def estimate_msg(t_s: float, x_hat: npt.ArrayLike, z_hat: npt.ArrayLike, age_s: float,
                 flow_scale: float = 1.0) -> Odometry:
    """Observer estimate at ``t_s``: position (m), velocity (m/s), measurement age (s), blood-velocity scale (-)."""
    cov = np.zeros(36)
    # inf age (no measurement yet) cannot travel as a finite number: clamp it
    cov[AGE_COVARIANCE_INDEX] = float(age_s) if math.isfinite(age_s) else 1e9
    tcov = np.zeros(36)
    tcov[FLOW_SCALE_COVARIANCE_INDEX] = float(flow_scale)
    pose = _pose(position=point(x_hat), orientation=_quaternion(x=0.0, y=0.0, z=0.0, w=1.0))
    twist = _twist(linear=vector3(z_hat), angular=_vector3(x=0.0, y=0.0, z=0.0))
    return _odometry(header=header(t_s), child_frame_id=CHILD_FRAME_ID, pose=_pose_cov(pose=pose, covariance=cov),
                     twist=_twist_cov(twist=twist, covariance=tcov))


def estimate_flow_scale(msg: Odometry) -> float:
    """The blood-velocity scale an estimate carries (``twist.covariance[35]``); 1 if unset, non-finite or <= 0."""
    s = float(msg.twist.covariance[FLOW_SCALE_COVARIANCE_INDEX])
    return s if math.isfinite(s) and s > 0.0 else 1.0


def estimate_arrays(msg: Odometry) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], float]:
    """Odometry -> ``(x_hat (2,) m, z_hat (2,) m/s, age s)``."""
    return xz(msg.pose.pose.position), xz(msg.twist.twist.linear), float(msg.pose.covariance[AGE_COVARIANCE_INDEX])


def reference_msg(k: int, t_s: float, p: npt.ArrayLike, v: npt.ArrayLike, a: npt.ArrayLike) -> ReferenceSample:
    """Reference sample k: ``X_ref`` (m), ``Xd_ref`` (m/s), ``Xdd_ref`` (m/s^2)."""
    return _reference_sample(header=header(t_s), tick=int(k), position=point(p), velocity=vector3(v),
                             acceleration=vector3(a))


def reference_arrays(msg: ReferenceSample) -> tuple[npt.NDArray[np.float64], ...]:
    """ReferenceSample -> ``(p, v, a)``, each (2,)."""
    return xz(msg.position), xz(msg.velocity), xz(msg.acceleration)


def gradient_msg(t_s: float, g: npt.ArrayLike) -> Vector3Stamped:
    """A gradient (T/m) stamped ``t_s``."""
    return _vector3_stamped(header=header(t_s), vector=vector3(g))


def coil_state_msg(k: int, t_s: float, commanded: npt.ArrayLike, out: Any, limits: Any, watchdog: bool,
                   dbdt_limit_T_per_s: float = 0.0, dbdt_radius_m: float = 0.0) -> CoilState:
    """CoilState from a :class:`~vesselbot_ros.control.actuator_limits.CoilOutput` (dB/dt 0: no dB/dt limit)."""
    slew = out.slew_limited
    return _coil_state(
        header=header(t_s),
        tick=int(k),
        commanded=vector3(commanded),
        applied=vector3(out.applied),
        saturation_scale=float(out.k_scale),
        saturated=bool(out.saturated),
        slew_limited_x=bool(slew[0]),
        slew_limited_z=bool(slew[1]),
        command_rejected=bool(out.rejected),
        watchdog_active=bool(watchdog),
        max_gradient=float(limits.saturation_T_per_m),
        slew_rate=float(limits.slew_rate_T_per_m_per_s),
        dbdt_limit=float(dbdt_limit_T_per_s),
        dbdt_radius=float(dbdt_radius_m),
    )


def plant_state_msg(k: int, t_s: float, p: npt.ArrayLike, v: npt.ArrayLike, blood_velocity: tuple[float, float],
                    diameter_m: float, gap_upper_m: float, gap_lower_m: float, signed_wall_distance_m: float,
                    in_contact: bool, contact_phase: int, applied: npt.ArrayLike, forces: npt.ArrayLike) -> PlantState:
    """The plant's ground truth of tick ``k``: ``forces`` is (8, 2), rows in the kernel's ``TERM_NAMES`` order (N)."""
    h = header(t_s)
    fb = _force_breakdown(header=h, **{name: vector3(forces[i]) for i, name in enumerate(TERM_NAMES)})  # type: ignore[index]
    return _plant_state(header=h, tick=int(k), position=point(p), velocity=vector3(v), blood_velocity=vector3(blood_velocity),
                        vessel_diameter=float(diameter_m), wall_gap_upper=float(gap_upper_m),
                        wall_gap_lower=float(gap_lower_m), signed_wall_distance=float(signed_wall_distance_m),
                        in_contact=bool(in_contact), contact_phase=int(contact_phase), applied_gradient=vector3(applied),
                        forces=fb)


def sequence_phase_msg(t_s: float, window: Any, latency_s: float, duty_cycle: float) -> SequencePhase:
    """SequencePhase (stamp ``t_s``, the first tick it applies to) from a :class:`~vesselbot_ros.scanner.sequence.PhaseWindow`."""
    return SequencePhase(header=header(t_s), phase=PHASE_CODES[window.phase], period_index=int(window.index),
                         window_start=float(window.start_s), window_end=float(window.end_s),
                         latency=float(latency_s), duty_cycle=float(duty_cycle))


def path_msg(points_m: npt.ArrayLike, t_s: float = 0.0) -> Path:
    """(n, 2) points (m) -> nav_msgs/Path in frame vessel."""
    pts = np.asarray(points_m, dtype=np.float64)
    msg = Path(header=header(t_s))
    for x, z in pts:
        ps = PoseStamped(header=header(t_s))
        ps.pose.position = point((x, z))
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


def network_markers(geom: Any, robot_radius_m: float, step_m: float = 2.0e-4) -> MarkerArray:
    """A vessel network for viewers: per branch, its two walls and its centreline (LINE_STRIPs).

    ``geom`` is a :class:`vesselbot_ros.vessels.network.NetworkGeometry`; points every ``step_m``.
    """
    out = MarkerArray()
    mid = 0
    for name, (pts, rad, _arc) in geom.branches.items():
        stride = max(1, int(round(step_m / geom.net.sample_spacing_m)))
        idx = np.unique(np.r_[np.arange(0, len(pts), stride), len(pts) - 1])
        t = np.gradient(pts, axis=0)
        t /= np.hypot(t[:, 0], t[:, 1])[:, None]
        nrm = np.column_stack([-t[:, 1], t[:, 0]])
        lines = (("wall_left", pts + rad[:, None] * nrm, (0.8, 0.2, 0.2)),
                 ("wall_right", pts - rad[:, None] * nrm, (0.8, 0.2, 0.2)),
                 ("centreline", pts, (0.5, 0.5, 0.5)))
        for label, line, (r, g, b) in lines:
            m = Marker(header=header(0.0), ns=f"{name}/{label}", id=mid, type=Marker.LINE_STRIP, action=Marker.ADD)
            mid += 1
            m.scale.x = 0.1 * robot_radius_m
            m.color.r, m.color.g, m.color.b, m.color.a = r, g, b, 1.0
            m.pose.orientation.w = 1.0
            m.points = [point((float(x), float(z))) for x, z in line[idx]]
            out.markers.append(m)
    return out
