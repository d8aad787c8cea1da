"""Route planning through a vessel network (pure): branch sequence, anchors, reference; where the robot went.

Given the start point (the injection point ``initial.p0_m``) and a target
outlet, the branch sequence is the path over the centreline tree from the inlet
branch to that outlet (:func:`~vesselbot_ros.vessels.network.route_to_outlet`).
Anchors are placed every ``reference.route_anchor_spacing_m`` of centreline
arc length from the point of the route nearest the start to
``reference.route_end_margin_m`` before the outlet (``reference.route_end``:
the last one exactly there, the spacing shortened evenly to fit, or up to one
spacing short of it), with the design-map rule of
Section III-A (docs/control.md): in an artery the robot rides near the *upper*
wall, where the flow is slow, at the wall-safe height
:func:`~vesselbot_ros.control.reference_design.wall_safe_delta_m` of the local
diameter (margin ``reference.route_wall_margin_m`` outside the band where the
observer error is unstable); where that height is not positive (small vessels)
the anchor is on the centreline.  Within one local diameter of a bifurcation
node the height ramps linearly down to the centreline (the side of the wall
changes there, and a route waiting at the upper wall in front of the wrong
daughter's entrance loses the robot into it).  "Upper" is the side of the
centreline whose normal points up (+z).  The first anchor is the start point itself.  The C2
B-spline through the anchors and its timing are those of
:class:`~vesselbot_ros.control.bspline_reference.ReferenceTrajectory`.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.reference_design import wall_safe_delta_m
from vesselbot_ros.control.route3d import anchor_arcs, route_anchors_3d
from vesselbot_ros.geometry.field_lookup import field_points3d
from vesselbot_ros.physics.params import BloodParams
from vesselbot_ros.vessels.cfd import network_wall
from vesselbot_ros.vessels.network import NetworkGeometry, load_network, route_to_outlet
from vesselbot_ros.vessels.plant_field3d import wall_arrays

__all__ = ["planned_reference", "route_branches", "branch_at", "navigation_metrics", "navigation_outcome", "draw_network"]


def route_branches(network: str, outlet: str) -> list[str]:
    """Branch names from the inlet to ``outlet`` in network file ``network``."""
    return route_to_outlet(load_network(network), outlet)


def _anchors(scenario) -> npt.NDArray[np.float64]:  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    return _anchors_cached(scenario.physics, scenario.observer, scenario.reference, tuple(scenario.initial.p0_m))


@functools.lru_cache(maxsize=64)
def _anchors_cached(phys, observer, ref, p0_m) -> npt.NDArray[np.float64]:  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The planned anchors (k, 2) (m), or (k, 3) in a 3-D tree; cached per (frozen) inputs: the wall-safe heights
    cost ~0.3 s each."""
    net = load_network(phys.vessel.network)
    base = dataclasses.replace(phys, vessel=dataclasses.replace(phys.vessel, network=""))
    if net.is_3d:  # the same rule along a route in space (control/route3d.py): up is the cross-section's vertical

        def height_of(d: float) -> float:
            pd = dataclasses.replace(base, vessel=dataclasses.replace(base.vessel, diameter_m=d))
            return wall_safe_delta_m(pd, observer, ref.route_wall_margin_m)

        arr3 = route_anchors_3d(net, ref.route_outlet, p0_m, ref.route_anchor_spacing_m, ref.route_end_margin_m, height_of,
                                end=ref.route_end)
        arr3.setflags(write=False)
        return arr3
    geom = NetworkGeometry(net)
    names = route_to_outlet(net, ref.route_outlet)
    path = geom.centreline_path(names)
    seg = np.hypot(*np.diff(path, axis=0).T)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    p0 = np.asarray(p0_m, dtype=np.float64)
    s0 = float(arc[int(np.argmin(np.hypot(*(path - p0).T)))])
    s_list = anchor_arcs(s0, arc[-1] - ref.route_end_margin_m, ref.route_anchor_spacing_m, ref.route_end)
    tang = np.gradient(path, axis=0)
    tang /= np.hypot(tang[:, 0], tang[:, 1])[:, None]
    up = np.column_stack([-tang[:, 1], tang[:, 0]])
    up[up[:, 1] < 0] *= -1.0  # the normal that points up
    q = geom.query(path)
    # arc lengths of the bifurcation nodes the route passes (the ends of all but its last branch)
    lengths = [geom.branches[n][2][-1] for n in names]
    nodes = np.cumsum(lengths)[:-1]
    heights: dict[float, float] = {}
    out = [p0]
    for s in s_list:
        i = int(np.clip(np.searchsorted(arc, s), 0, len(path) - 1))
        d = float(np.round(q["diameter"][i], 9))
        if d not in heights:
            pd = dataclasses.replace(base, vessel=dataclasses.replace(base.vessel, diameter_m=d))
            heights[d] = max(0.0, wall_safe_delta_m(pd, observer, ref.route_wall_margin_m))
        # within one local diameter of a node the height ramps down to the centreline, so the route never
        # waits in front of the other daughter's entrance (the wall side of a bend changes there)
        ramp = 1.0 if nodes.size == 0 else min(1.0, float(np.min(np.abs(nodes - s))) / d)
        out.append(path[i] + ramp * heights[d] * up[i])
    arr = np.array(out)
    arr.setflags(write=False)
    return arr


def planned_reference(scenario):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The scenario's :class:`ReferenceParams` with planned anchors when ``reference.route_outlet`` is set."""
    ref = scenario.reference
    if not ref.route_outlet:
        return ref
    a = _anchors(scenario)
    if a.shape[1] == 3:
        return dataclasses.replace(ref, anchors_x_m=tuple(float(v) for v in a[:, 0]),
                                   anchors_y_m=tuple(float(v) for v in a[:, 1]),
                                   anchors_z_m=tuple(float(v) for v in a[:, 2]))
    return dataclasses.replace(ref, anchors_x_m=tuple(float(v) for v in a[:, 0]),
                               anchors_z_m=tuple(float(v) for v in a[:, 1]))


def branch_at(network: str, points_m: npt.ArrayLike) -> tuple[list[str], npt.NDArray[np.float64]]:
    """(branch name, signed distance to the meshed wall (m)) of each point (m, 2) in the network.

    The branch is the centreline tube holding the point; the distance is the meshed wall's
    (:func:`vesselbot_ros.vessels.cfd.network_wall`), exact in the junctions too.
    """
    net = load_network(network)
    geom = NetworkGeometry(net)
    q = geom.query(points_m)
    return [geom.names[i] for i in q["branch"]], network_wall(net).query(points_m)["sdist"]


def navigation_metrics(scenario, t_s: npt.ArrayLike, p_true: npt.ArrayLike) -> dict[str, object]:  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Where the robot went in a network run.

    Keys: ``branch_final`` (branch holding the final true position),
    ``route_outlet`` (target, ``""`` if none), ``reached_target`` (1 if the final
    position lies inside the lumen of the target branch, further into it than
    the parent's radius at the node), ``outside_lumen_time_s`` (time the robot's
    centre spent outside the steady lumen, s) and ``outside_lumen_first_s``
    (first tick outside, s, -1 if never): leaving the lumen is an event every
    run reports.
    """
    return navigation_outcome(scenario.physics.vessel.network, scenario.reference.route_outlet, t_s, p_true,
                              blood=scenario.physics.blood)


def navigation_outcome(network: str, target: str, t_s: npt.ArrayLike, p_true: npt.ArrayLike, *,
                       blood: BloodParams | None = None) -> dict[str, object]:
    """:func:`navigation_metrics` from plain values (network file, target outlet or "").

    "Outside the lumen" is outside the meshed wall (:func:`vesselbot_ros.vessels.cfd.network_wall`, read
    from the field of ``blood``, default the shipped scenarios' blood: the wall does not depend on it);
    the branch holding a point is its centreline tube's.
    """
    t = np.asarray(t_s, dtype=np.float64)
    p = np.asarray(p_true, dtype=np.float64)
    net = load_network(network)
    geom = NetworkGeometry(net)
    q = geom.query(p)
    if net.is_3d:  # the 3-D plant's wall (its compiled lookup)
        out = field_points3d(np.ascontiguousarray(p), *wall_arrays(net, blood).args)[:, 0] < 0.0
    else:
        # the lumen dilates by the diameter pulsation; the steady wall is the conservative test
        out = network_wall(net, blood).query(p)["sdist"] < 0.0
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    final_branch = geom.names[int(q["branch"][-1])]
    reached = False
    if target and final_branch == target and not out[-1]:
        parent = next(b for b in net.branches if b.name == target).parent
        # past the bifurcation: the centre lies further into the branch than the parent's end radius
        min_arc = float(next(b for b in net.branches if b.name == parent).radii()[-1]) if parent else 0.0
        reached = float(q["arc"][-1]) >= min_arc
    return {
        "branch_final": final_branch,
        "route_outlet": target,
        "reached_target": int(reached),
        "outside_lumen_time_s": float(np.count_nonzero(out) * dt),
        "outside_lumen_first_s": float(t[np.argmax(out)]) if out.any() else -1.0,
    }


def draw_network(ax, network: str, mm: float = 1e3) -> None:  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Draw the network on a matplotlib axis, in mm by default: the tubes filled grey, the meshed wall
    (the one the plant sees, :func:`vesselbot_ros.vessels.cfd.network_wall`) as a dark outline, the
    centrelines dotted."""
    from matplotlib.collections import LineCollection  # deferred: matplotlib is a heavy optional dependency (reports only)

    net = load_network(network)
    geom = NetworkGeometry(net)
    for name, (pts, rad, _arc) in geom.branches.items():
        t = np.gradient(pts, axis=0)
        t /= np.hypot(t[:, 0], t[:, 1])[:, None]
        nrm = np.column_stack([-t[:, 1], t[:, 0]])
        poly = np.concatenate([pts + rad[:, None] * nrm, (pts - rad[:, None] * nrm)[::-1]]) * mm
        ax.fill(poly[:, 0], poly[:, 1], color="0.92", lw=0, zorder=0)
        ax.plot(*pts.T * mm, color="0.6", lw=0.5, ls=":", zorder=1)
        ax.annotate(name, pts[-1] * mm, fontsize=7, color="0.3")
    segs = network_wall(net).segments * mm
    ax.add_collection(LineCollection(segs.reshape(-1, 2, 2), colors="0.3", linewidths=0.8, zorder=1))
