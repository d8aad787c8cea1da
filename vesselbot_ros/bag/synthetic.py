"""A synthetic, closed-form stream of the graph's messages (for tests and the recorder bench).

:func:`tick_messages` returns, for tick ``k``, one message per per-tick topic
of :data:`vesselbot_ros.graph_spec.TOPICS`, in the lockstep order, with contents
that are closed-form functions of ``t = k * dt_s`` (documented below) so that
tests can compute expected figures and metrics by hand:

* reference ``p_ref = (v_x t, 0, z0)``, ``v_ref = (v_x, 0, 0)``, ``a_ref = 0``
  with ``v_x = 4.5e-3`` m/s and ``z0 = 1e-3`` m;
* truth ``p = p_ref + (e0 exp(-t / tau), 0, e_z)`` with ``e0 = 300e-6`` m,
  ``tau = 0.2`` s, ``e_z = 40e-6`` m; ``v = (v_x - e0/tau exp(-t/tau), 0, 0)``;
  vessel diameter ``D = 2.5e-3`` m; every force term ``F_i = (i+1) 1e-9`` N on x;
* estimate ``p_hat = p + (6e-6, 0, 0)``, ``v_hat = v + (1e-4, 0, 0)``;
* measurement = truth + ``(2e-6 sin(k), 0, 2e-6 cos(k))``, plus ``1e-3`` m on
  x while ``t`` is in :data:`OUTLIER_WINDOW_S`;
* gradient command ``(0.1 sin(2 pi t), 0, 0.05)`` T/m; the coil applies it
  clipped to +/- 0.08 T/m per axis and flags ``saturated`` when clipping;
* ``/diagnostics`` every 100 ticks.
"""

from __future__ import annotations

import math
from typing import Any

from vesselbot_ros.graph_spec import topic

__all__ = ["tick_messages", "latched_messages", "OUTLIER_WINDOW_S", "PARAMS"]

PARAMS = {"v_x": 4.5e-3, "z0": 1e-3, "e0": 300e-6, "tau": 0.2, "e_z": 40e-6, "D": 2.5e-3,
          "est_dx": 6e-6, "est_dvx": 1e-4, "u_sat": 0.08}
OUTLIER_WINDOW_S = (0.5, 0.52)


def _stamp(header: Any, t_s: float, frame: str = "vessel") -> None:
    ns = int(round(t_s * 1e9))
    header.stamp.sec, header.stamp.nanosec = divmod(ns, 1_000_000_000)
    header.frame_id = frame


def tick_messages(k: int, dt_s: float = 1e-3) -> list[tuple[str, Any]]:
    """(topic name, rclpy message) of tick ``k`` in lockstep order (see module doc)."""
    # deferred: the ROS message packages; PARAMS and the closed forms are read ROS-free (bag and report tests)
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from geometry_msgs.msg import PointStamped, Vector3Stamped
    from nav_msgs.msg import Odometry
    from rosgraph_msgs.msg import Clock
    from vesselbot_msgs.msg import CoilState, PlantState, ReferenceSample

    P = PARAMS
    t = k * dt_s
    out: list[tuple[str, Any]] = []
    c = Clock()
    c.clock.sec, c.clock.nanosec = divmod(int(round(t * 1e9)), 1_000_000_000)
    out.append((topic("clock").name, c))

    decay = math.exp(-t / P["tau"])
    px, pz = P["v_x"] * t + P["e0"] * decay, P["z0"] + P["e_z"]
    vx = P["v_x"] - P["e0"] / P["tau"] * decay
    tr = PlantState()
    _stamp(tr.header, t)
    tr.tick = k
    tr.position.x, tr.position.z = px, pz
    tr.velocity.x = vx
    tr.blood_velocity.x = 0.025
    tr.vessel_diameter = P["D"]
    tr.wall_gap_upper = P["D"] / 2 - pz - 125e-6
    tr.wall_gap_lower = P["D"] / 2 + pz - 125e-6
    tr.signed_wall_distance = -min(tr.wall_gap_upper, tr.wall_gap_lower)
    tr.in_contact = False
    u = (0.1 * math.sin(2 * math.pi * t), 0.05)
    applied = tuple(max(-P["u_sat"], min(P["u_sat"], a)) for a in u)
    tr.applied_gradient.x, tr.applied_gradient.z = applied
    for i, term in enumerate(("magnetic", "drag", "apparent_weight", "contact", "van_der_waals", "electrostatic",
                              "steric", "total")):
        getattr(tr.forces, term).x = (i + 1) * 1e-9
    _stamp(tr.forces.header, t)
    out.append((topic("truth").name, tr))

    me = PointStamped()
    _stamp(me.header, t)
    me.point.x = px + 2e-6 * math.sin(k) + (1e-3 if OUTLIER_WINDOW_S[0] <= t < OUTLIER_WINDOW_S[1] else 0.0)
    me.point.z = pz + 2e-6 * math.cos(k)
    out.append((topic("measurement").name, me))

    rf = ReferenceSample()
    _stamp(rf.header, t)
    rf.tick = k
    rf.position.x, rf.position.z = P["v_x"] * t, P["z0"]
    rf.velocity.x = P["v_x"]
    out.append((topic("reference").name, rf))

    es = Odometry()
    _stamp(es.header, t)
    es.child_frame_id = "robot"
    es.pose.pose.position.x, es.pose.pose.position.z = px + P["est_dx"], pz
    es.pose.pose.orientation.w = 1.0
    es.twist.twist.linear.x = vx + P["est_dvx"]
    out.append((topic("estimate").name, es))

    cmd = Vector3Stamped()
    _stamp(cmd.header, t)
    cmd.vector.x, cmd.vector.z = u
    out.append((topic("gradient_command").name, cmd))

    ap = Vector3Stamped()
    _stamp(ap.header, t)
    ap.vector.x, ap.vector.z = applied
    out.append((topic("coil_applied").name, ap))

    cs = CoilState()
    _stamp(cs.header, t)
    cs.tick = k
    cs.commanded.x, cs.commanded.z = u
    cs.applied.x, cs.applied.z = applied
    cs.saturated = abs(u[0]) > P["u_sat"]
    cs.saturation_scale = max(1.0, abs(u[0]) / P["u_sat"])
    cs.max_gradient = P["u_sat"]
    cs.slew_rate = 0.1
    out.append((topic("coil_state").name, cs))

    if k % 100 == 0:
        d = DiagnosticArray()
        _stamp(d.header, t, frame="")
        st = DiagnosticStatus(level=DiagnosticStatus.OK, name="synthetic_graph", message=f"tick {k}")
        st.values = [KeyValue(key="tick", value=str(k))]
        d.status = [st]
        out.append((topic("diagnostics").name, d))
    return out


def latched_messages() -> list[tuple[str, Any]]:
    """The latched topics (vessel markers, reference path, the scanner's phase: continuous), published once."""
    # deferred: the ROS message packages (see tick_messages)
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Path as PathMsg
    from vesselbot_msgs.msg import SequencePhase
    from visualization_msgs.msg import Marker, MarkerArray

    ma = MarkerArray()
    for i, z in enumerate((PARAMS["D"] / 2, -PARAMS["D"] / 2)):
        mk = Marker()
        _stamp(mk.header, 0.0)
        mk.ns, mk.id, mk.type = "wall", i, Marker.LINE_STRIP
        mk.scale.x = 1e-5
        mk.color.a = 1.0
        ma.markers.append(mk)
        mk.pose.position.z = z
    path = PathMsg()
    _stamp(path.header, 0.0)
    for j in range(5):
        ps = PoseStamped()
        _stamp(ps.header, 0.5 * j)
        ps.pose.position.x, ps.pose.position.z = PARAMS["v_x"] * 0.5 * j, PARAMS["z0"]
        path.poses.append(ps)
    phase = SequencePhase()  # the paper's continuous loop: one message, as the coil driver publishes it
    _stamp(phase.header, 0.0)
    phase.phase, phase.period_index, phase.window_start, phase.window_end = 0, -1, 0.0, float("inf")
    return [(topic("vessel_markers").name, ma), (topic("reference_path").name, path),
            (topic("sequence_phase").name, phase)]
