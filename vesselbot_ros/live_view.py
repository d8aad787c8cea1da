"""What the live view derives from the graph's topics: the scene as markers, and the error time series.

The live view (:mod:`vesselbot_ros.live`) forwards every topic of the graph
spec, each at most at the live rate.  On top of that it offers the channels of
:data:`vesselbot_ros.graph_spec.VIEW_CHANNELS`, computed here from the latest
messages of the topics each one names, at most :data:`VIEW_RATE_HZ` times per
wall second (a viewer needs no more, and the run pays nothing per tick: the
bytes are kept, and decoded only when a view update is due).  The
numbers of one update are of one tick: the truth, reference, estimate and coil
state of the stamp the coil state closed (the newest tick whose truth and
reference both came, when a subscription's queue lags another's: the recorder
takes each topic's messages on its own subscription, so a loaded machine
delivers them out of step), from the last :data:`TICK_RING` messages of each:

* ``view/markers`` (``visualization_msgs/MarkerArray``, a standard message
  Foxglove's 3D panel draws): in the straight vessel both walls at +/- D(t)/2
  as they pulse (a vessel network's meshed wall is the plant's latched
  ``vessel_markers``, drawn once, so the view adds no straight walls there,
  and deletes those it drew before the plant's markers came: they arrive on
  a topic of their own, a large 3-D mesh after the first ticks' messages),
  the robot (its true radius, from the wall gaps), the estimate, the applied
  gradient as an arrow from the robot (2 mm at the coil limit), and the
  reference path, each where its message puts it: in the plane y = 0 in a
  planar run, in 3-D in a 3-D vessel tree (the messages carry their y);
* ``view/errors`` (JSON): ``t_s``, ``tracking_error_m`` (|p - p_ref|),
  ``estimation_error_m`` (|p - p_hat|), ``gradient_norm_T_per_m`` (|G|
  applied) and ``gradient_limit_T_per_m`` (U_sat in force), for Foxglove's
  Plot panel.

:func:`scene_numbers` is the pure part (plain numbers in, plain numbers out).
"""

from __future__ import annotations

import json
import math
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

from vesselbot_ros.graph_spec import FRAME_ID, NETWORK_WALL_NS, VIEW_CHANNELS, import_type, topic

__all__ = ["VIEW_RATE_HZ", "SceneNumbers", "scene_numbers", "DerivedView", "ERRORS_SCHEMA", "ERRORS_SCHEMA_NAME",
           "ARROW_AT_LIMIT_M"]

#: View updates per wall second, at most.
VIEW_RATE_HZ = 20.0
#: The reference path (static, hundreds of points) rides along with a view update at most this often (wall s);
#: Foxglove keeps a marker until the same namespace and id come again, so the others need not repeat it.
PATH_PERIOD_S = 1.0
#: Messages kept per tick-stamped input (truth, reference, estimate, coil state) to pair them by stamp.
TICK_RING = 64
#: The inputs of one tick, paired by their header's stamp.
TICK_KEYS = ("truth", "reference", "estimate", "coil_state")
#: Length of the gradient arrow at the coil limit (m).
ARROW_AT_LIMIT_M = 2e-3
#: Name of the JSON schema of ``view/errors`` (what Foxglove shows as the channel's type).
ERRORS_SCHEMA_NAME = "vesselbot.ViewErrors"
#: JSON schema of ``view/errors``.
ERRORS_SCHEMA = {
    "title": ERRORS_SCHEMA_NAME,
    "type": "object",
    "properties": {k: {"type": "number"} for k in
                   ("t_s", "tracking_error_m", "estimation_error_m", "gradient_norm_T_per_m", "gradient_limit_T_per_m")},
}


#: A point or vector of the scene: ``(x, y, z)``, or ``(x, z)`` for one in the plane y = 0.
Vec = tuple[float, float, float] | tuple[float, float]
Vec3 = tuple[float, float, float]


def _xyz(v: Vec) -> Vec3:
    """``(x, y, z)`` of a scene point given as ``(x, y, z)`` or as ``(x, z)`` (y = 0)."""
    if len(v) == 2:  # axis count at the scene's edge: a planar point's y is 0
        return (float(v[0]), 0.0, float(v[1]))
    return (float(v[0]), float(v[1]), float(v[2]))


@dataclass(frozen=True)
class SceneNumbers:
    """One view update in numbers (SI units, frame ``vessel``; points ``(x, y, z)``, y = 0 in a planar run)."""

    t_s: float
    robot: Vec3
    robot_radius_m: float
    wall_z_m: float  # the walls at +/- wall_z_m
    estimate: Vec3 | None
    gradient: Vec3
    gradient_limit: float
    tracking_error_m: float | None
    estimation_error_m: float | None


def scene_numbers(t_s: float, robot: Vec, diameter_m: float, gap_upper_m: float, gap_lower_m: float,
                  gradient: Vec, gradient_limit: float, estimate: Vec | None, reference: Vec | None) -> SceneNumbers:
    """The view of one moment: robot radius from the two wall gaps, errors as Euclidean norms (in 3-D).

    Points and the gradient are ``(x, y, z)`` or, in the plane, ``(x, z)``.  The gaps to the two walls and
    the robot's diameter fill the local lumen diameter D(t), in the straight vessel (D/2 - z - r and
    z + D/2 - r) as in a network (the nearest wall and the opposite one), so
    ``r = (D - gap_upper - gap_lower) / 2`` holds in both.  (A norm with y = 0 is the planar norm bit for bit.)
    """
    p = _xyz(robot)
    est_p = _xyz(estimate) if estimate is not None else None
    radius = 0.5 * (diameter_m - gap_upper_m - gap_lower_m)
    track = math.dist(p, _xyz(reference)) if reference is not None else None
    est = math.dist(p, est_p) if est_p is not None else None
    return SceneNumbers(t_s, p, radius, 0.5 * diameter_m, est_p, _xyz(gradient), gradient_limit, track, est)


def _stamp_ns(msg: Any) -> int:
    """A message's header stamp (ns)."""
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def _vec(v: Any) -> Vec3:
    """``(x, y, z)`` of a ``geometry_msgs`` Point or Vector3."""
    return (v.x, v.y, v.z)


class DerivedView:
    """Keeps the last bytes of the tick-stamped topics the view channels need; emits view updates at
    :data:`VIEW_RATE_HZ`.

    Args:
        send: ``send(view_key, payload: bytes, t_ns)``: hands one view message to the server.
        wanted: ``wanted() -> bool``: whether anyone subscribes to a view channel (no work otherwise).
    """

    def __init__(self, send: Any, wanted: Any = lambda: True) -> None:
        self._send = send
        self._wanted = wanted
        self.inputs = sorted({k for v in VIEW_CHANNELS for k in v.inputs})
        #: per tick-stamped input, its last TICK_RING messages as ``[bytes, decoded or None]``, oldest first
        self._recent: dict[str, deque[list[Any]]] = {k: deque(maxlen=TICK_RING) for k in TICK_KEYS}
        self._types = {k: import_type(topic(k).msgtype) for k in self.inputs}
        self._names = {topic(k).name: k for k in self.inputs}
        self._last_wall = 0.0
        self._path_points: list[Any] = []
        self._path_marker: Any = None  # built once per path (and robot radius), sent every PATH_PERIOD_S
        self._path_key: tuple[int, float] | None = None
        self._path_wall = -math.inf
        #: True once the plant's vessel markers show a vessel network (then the view draws no straight walls).
        self.network = False
        self._walls_drawn = False  # straight walls sent (a viewer keeps them until they are deleted)

    def offer(self, name: str, data: bytes, t_ns: int) -> None:
        """A message of topic ``name`` (canonical name) arrived; maybe emit a view update."""
        key = self._names.get(name)
        if key is None:
            return
        if key in self._recent:
            self._recent[key].append([data, None])
        if key == "reference_path":
            self._path_points = [p.pose.position for p in self._decode(key, data).poses]
        elif key == "vessel_markers":
            # a vessel network draws its meshed wall itself (the plant's latched markers): no straight walls then
            self.network = any(m.ns == NETWORK_WALL_NS for m in self._decode(key, data).markers)
        now = time.monotonic()
        # the coil state closes a tick (lockstep order): truth, reference and estimate of that tick are all in
        if key == "coil_state" and now - self._last_wall >= 1.0 / VIEW_RATE_HZ and self._wanted():
            self._last_wall = now
            self.emit(t_ns)

    def _decode(self, key: str, data: bytes) -> Any:
        # deferred: rclpy; the module's scene numbers are used and tested ROS-free, and live imports it for its defaults
        from rclpy.serialization import deserialize_message

        return deserialize_message(data, self._types[key])

    def _messages(self, key: str) -> Any:
        """``key``'s kept messages, newest first, decoded as they are reached (each once)."""
        for entry in reversed(self._recent[key]):
            if entry[1] is None:
                entry[1] = self._decode(key, entry[0])
            yield entry[1]

    def _at(self, key: str, stamp_ns: int, exact: bool = True) -> Any:
        """``key``'s kept message stamped ``stamp_ns`` (``exact=False``: the newest stamped at or before it);
        None if it has not come, or has left the ring."""
        for m in self._messages(key):
            s = _stamp_ns(m)
            if s <= stamp_ns:
                return m if s == stamp_ns or not exact else None
        return None

    def tick(self) -> tuple[Any, Any, Any, Any] | None:
        """Truth, reference, estimate and coil state of one tick (the estimate and coil state: the newest up to it).

        The tick is the coil state's newest when its truth and reference came; else the newest tick before it
        whose truth and reference both came; else the newest truth with the newest of the others.  Messages are
        decoded newest first, as far as the search goes (one or two of each when the queues keep step).
        """
        coil = next(self._messages("coil_state"), None)
        has_ref = bool(self._recent["reference"])
        first = None
        for truth in self._messages("truth"):
            if first is None:
                first = truth
            s = _stamp_ns(truth)
            if coil is not None and s > _stamp_ns(coil):
                continue
            ref = self._at("reference", s) if has_ref else None
            if ref is not None or not has_ref:
                return truth, ref, self._at("estimate", s, exact=False), self._at("coil_state", s, exact=False) or coil
        if first is None:
            return None
        return first, next(self._messages("reference"), None), next(self._messages("estimate"), None), coil

    def emit(self, t_ns: int) -> None:
        """Send one update of every view channel from the messages of one tick (needs a truth message)."""
        got = self.tick()
        if got is None:
            return
        truth, ref, est, coil = got
        t = truth.header.stamp.sec + truth.header.stamp.nanosec * 1e-9
        sn = scene_numbers(
            t, _vec(truth.position), truth.vessel_diameter, truth.wall_gap_upper, truth.wall_gap_lower,
            _vec(truth.applied_gradient), coil.max_gradient if coil is not None else math.nan,
            _vec(est.pose.pose.position) if est is not None else None, _vec(ref.position) if ref is not None else None)
        # deferred: rclpy (see _decode)
        from rclpy.serialization import serialize_message

        now = time.monotonic()
        # the path's period starts when it is sent: an update before the path arrived does not use up the period
        with_path = bool(self._path_points) and now - self._path_wall >= PATH_PERIOD_S
        if with_path:
            self._path_wall = now
        scene = self.markers(sn, truth.header, with_path)
        if self.network and self._walls_drawn:  # drawn before the plant's markers showed a network: delete them
            scene.markers[:0] = [self._deleted(name, truth.header) for name in ("upper_wall", "lower_wall")]
        self._walls_drawn = not self.network
        self._send("view_markers", serialize_message(scene), t_ns)
        errors = {"t_s": sn.t_s, "gradient_norm_T_per_m": math.hypot(*sn.gradient)}
        if not math.isnan(sn.gradient_limit):
            errors["gradient_limit_T_per_m"] = sn.gradient_limit
        if sn.tracking_error_m is not None:
            errors["tracking_error_m"] = sn.tracking_error_m
        if sn.estimation_error_m is not None:
            errors["estimation_error_m"] = sn.estimation_error_m
        self._send("view_errors", json.dumps(errors).encode("utf-8"), t_ns)

    @staticmethod
    def _deleted(ns: str, header: Any) -> Any:
        """A marker that deletes the view's marker ``ns`` (id 0) from a viewer."""
        # deferred: ROS message packages (see _decode)
        from visualization_msgs.msg import Marker

        m = Marker(header=header, ns=ns, id=0, action=Marker.DELETE)
        m.header.frame_id = FRAME_ID
        return m

    def markers(self, sn: SceneNumbers, header: Any, with_path: bool = True) -> Any:
        """The MarkerArray of one view update (the reference path only ``with_path``)."""
        # deferred: ROS message packages (see _decode)
        from geometry_msgs.msg import Point
        from visualization_msgs.msg import Marker, MarkerArray

        def marker(ns: str, kind: int, rgba: tuple[float, float, float, float]) -> Any:
            m = Marker(header=header, ns=ns, id=0, type=kind, action=Marker.ADD)
            m.header.frame_id = FRAME_ID
            m.pose.orientation.w = 1.0
            m.color.r, m.color.g, m.color.b, m.color.a = rgba
            return m

        out = MarkerArray()
        xs = [p.x for p in self._path_points] or [sn.robot[0] - 5e-3, sn.robot[0] + 5e-3]
        x0, x1 = min(xs) - 1e-3, max(xs) + 1e-3
        r = max(sn.robot_radius_m, 1e-6)
        for name, z in () if self.network else (("upper_wall", sn.wall_z_m), ("lower_wall", -sn.wall_z_m)):
            m = marker(name, Marker.CUBE, (0.8, 0.2, 0.2, 0.6))
            m.pose.position.x, m.pose.position.z = 0.5 * (x0 + x1), z + (0.25 * r if z > 0 else -0.25 * r)
            m.scale.x, m.scale.y, m.scale.z = x1 - x0, 4 * r, 0.5 * r
            out.markers.append(m)
        robot = marker("robot", Marker.SPHERE, (0.9, 0.7, 0.1, 1.0))
        robot.pose.position.x, robot.pose.position.y, robot.pose.position.z = sn.robot
        robot.scale.x = robot.scale.y = robot.scale.z = 2 * r
        out.markers.append(robot)
        if sn.estimate is not None:
            est = marker("estimate", Marker.SPHERE, (0.2, 0.5, 1.0, 0.5))
            est.pose.position.x, est.pose.position.y, est.pose.position.z = sn.estimate
            est.scale.x = est.scale.y = est.scale.z = 2 * r
            out.markers.append(est)
        g = math.hypot(*sn.gradient)
        if g > 0 and sn.gradient_limit > 0:
            arrow = marker("gradient", Marker.ARROW, (0.1, 0.8, 0.3, 1.0))
            scale = ARROW_AT_LIMIT_M / sn.gradient_limit
            (x, y, z), (gx, gy, gz) = sn.robot, sn.gradient
            arrow.points = [Point(x=x, y=y, z=z), Point(x=x + scale * gx, y=y + scale * gy, z=z + scale * gz)]
            arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.2 * r, 0.4 * r, 0.4 * r
            out.markers.append(arrow)
        if with_path and self._path_points:
            key = (id(self._path_points), round(r, 8))  # r comes from the wall gaps: equal to ~1e-12
            if self._path_key != key:
                path = marker("reference_path", Marker.LINE_STRIP, (0.3, 0.3, 0.3, 1.0))
                path.points = [Point(x=p.x, y=p.y, z=p.z) for p in self._path_points]
                path.scale.x = 0.1 * r
                self._path_marker, self._path_key = path, key
            self._path_marker.header = header
            out.markers.append(self._path_marker)
        return out
