"""Route planning through a vessel network, planar or in 3-D (pure): branch sequence, anchors, reference; where
the robot went.

Anchors every ``reference.route_anchor_spacing_m`` of centreline arc length from the start to the outlet, each
the wall-safe height of the local diameter (Section III-A's design map) above the centreline on the side that
points up, ramped to the centreline within one local diameter of a bifurcation node.  The rule, and what "up" is
in the plane and in space, are in docs/vessels.md ("Routes").
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.reference_design import wall_safe_delta_m
from vesselbot_ros.physics.axes import AXES
from vesselbot_ros.physics.params import BloodParams, FlowParams
from vesselbot_ros.resources import require_fits, spline_setup_cost
from vesselbot_ros.vessels.cfd import network_wall
from vesselbot_ros.vessels.network import VesselNetworkParams, load_network, route_to_outlet
from vesselbot_ros.vessels.tree_field import meshed_wall
from vesselbot_ros.vessels.tube_geometry import NetworkGeometry

__all__ = ["planned_reference", "route_branches", "route_anchors", "up_directions", "anchor_arcs", "VERTICAL_SINE",
           "branch_at", "navigation_metrics", "navigation_outcome", "pulsation_of", "draw_network"]

#: Below this sine of the angle between the centreline and the vertical, a cross-section in space has no up.
VERTICAL_SINE = 0.05


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

    def height_of(d: float) -> float:
        pd = dataclasses.replace(base, vessel=dataclasses.replace(base.vessel, diameter_m=d))
        return wall_safe_delta_m(pd, observer, ref.route_wall_margin_m)

    arr = route_anchors(net, ref.route_outlet, p0_m, ref.route_anchor_spacing_m, ref.route_end_margin_m, height_of,
                        end=ref.route_end)
    arr.setflags(write=False)
    return arr


def _row_norms(v: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """|v| of each row: ``hypot`` in the plane, ``linalg.norm`` in space (axis count at the geometry's edge: each
    keeps the anchors, and so the reference, it always gave)."""
    if v.shape[1] == 2:
        return np.asarray(np.hypot(v[:, 0], v[:, 1]))
    return np.asarray(np.linalg.norm(v, axis=1))


def up_directions(tangents: npt.ArrayLike) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Unit up direction in the cross-section at each unit tangent (k, d), and where it exists (k,).

    In space: the vertical ``+z`` with its component along the tangent removed, normalised; where the centreline
    is within :data:`VERTICAL_SINE` of vertical there is none (0).  In the plane: the tangent's normal that
    points up (the same direction, written as the plane's rule, so the planar anchors keep their bits).
    """
    t = np.atleast_2d(np.asarray(tangents, dtype=np.float64))
    if t.shape[1] == 2:  # axis count at the geometry's edge: the plane's normal of the tangent, pointing up
        up = np.column_stack([-t[:, 1], t[:, 0]])
        up[up[:, 1] < 0] *= -1.0
        return up, np.ones(len(t), dtype=bool)
    up = np.zeros_like(t)
    up[:, 2] = 1.0
    up -= t[:, 2:3] * t
    norm = np.linalg.norm(up, axis=1)
    ok = norm > VERTICAL_SINE
    up[ok] /= norm[ok, None]
    up[~ok] = 0.0
    return up, ok


def anchor_arcs(s0: float, s_end: float, spacing_m: float, end: str = "spaced") -> npt.NDArray[np.float64]:
    """Arc lengths of the anchors after the start ``s0`` along a route planned to ``s_end`` (m).

    ``spaced``: every ``spacing_m`` from ``s0``, the last in ``(s_end - spacing_m, s_end]`` (at least one).
    ``at_margin``: the fewest evenly spaced anchors at most ``spacing_m`` apart, the last at ``s_end``.
    """
    n_max = max(1.0, (s_end - s0) / spacing_m + 1.0)  # the reference's spline then solves through them
    require_fits("reference.route_anchor_spacing_m", spacing_m, *spline_setup_cost(int(min(n_max, 2**31))),
                 what=f"the reference's B-spline set-up through {n_max:.3g} planned anchors",
                 hint="space the planned anchors wider")
    if end == "at_margin":
        n = max(1, int(np.ceil((s_end - s0) / spacing_m - 1e-9)))
        return s0 + (s_end - s0) * np.arange(1, n + 1, dtype=np.float64) / n
    n = max(1, int(np.floor((s_end - s0) / spacing_m + 1e-9)))
    return np.asarray(s0 + spacing_m * np.arange(1, n + 1), dtype=np.float64)


def route_anchors(net: VesselNetworkParams, outlet: str, p0_m: npt.ArrayLike, spacing_m: float, end_margin_m: float,
                  height_of: Callable[[float], float], *, end: str = "spaced") -> npt.NDArray[np.float64]:
    """The anchors (k, d) (m) of a reference from the start point ``p0_m`` (d,) to ``outlet``, on the network's
    axes (2 for a planar file, 3 for a tree that gives ``y_m``).

    Args:
        net: The network.
        outlet: The target outlet branch.
        p0_m: The start (injection) point (m); the first anchor.
        spacing_m: Arc length between anchors (m).
        end_margin_m: The last anchor lies this far before the outlet (m), but inside the outlet's branch (an
            anchor half way along it is added where the spaced ones stop short of a quarter of it).
        height_of: The wall-safe height above the centreline of a vessel of diameter ``d`` (m -> m; negative
            or zero: on the centreline), e.g. Section III-A's design map
            (:func:`~vesselbot_ros.control.reference_design.wall_safe_delta_m`).
        end: Where the last anchor lies (:func:`anchor_arcs`: ``spaced`` or ``at_margin``).
    """
    geom = NetworkGeometry(net)
    names = route_to_outlet(net, outlet)
    path = geom.centreline_path(names)
    arc = np.concatenate([[0.0], np.cumsum(_row_norms(np.diff(path, axis=0)))])
    p0 = np.asarray(p0_m, dtype=np.float64)
    s0 = float(arc[int(np.argmin(_row_norms(path - p0)))])
    # arc lengths of the bifurcation nodes the route passes (the ends of all but its last branch)
    lengths = [geom.length_m(b) for b in names]
    nodes = np.cumsum(lengths)[:-1]
    # the last anchor end_margin_m before the outlet, but inside the outlet branch: at least half way along it (a
    # short side branch would leave the route's end in its parent, and the run's target unreachable)
    s_end = arc[-1] - end_margin_m
    if nodes.size:
        s_end = max(s_end, float(nodes[-1]) + 0.5 * lengths[-1])
    s_list = anchor_arcs(s0, s_end, spacing_m, end)
    if nodes.size and s_list[-1] < float(nodes[-1]) + 0.25 * lengths[-1]:
        s_list = np.append(s_list, s_end)  # the spaced anchors stop short of the outlet's branch: one more, in it
    tang = np.gradient(path, axis=0)
    tang /= _row_norms(tang)[:, None]
    up, _has_up = up_directions(tang)
    diam = geom.query(path)["diameter"]
    heights: dict[float, float] = {}
    out = [p0]
    for s in s_list:
        i = int(np.clip(np.searchsorted(arc, s), 0, len(path) - 1))
        d = float(np.round(diam[i], 9))
        if d not in heights:
            heights[d] = max(0.0, float(height_of(d)))
        # within one local diameter of a node the height ramps down to the centreline, so the route never
        # waits in front of the other daughter's entrance (the wall side of a bend changes there)
        ramp = 1.0 if nodes.size == 0 else min(1.0, float(np.min(np.abs(nodes - s))) / d)
        out.append(path[i] + ramp * heights[d] * up[i])
    return np.array(out)


def planned_reference(scenario):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The scenario's :class:`ReferenceParams` with planned anchors when ``reference.route_outlet`` is set (and
    ``reference.route_anchors`` is ``planned``: a plan's anchors are ``given``)."""
    ref = scenario.reference
    if not ref.route_outlet or ref.route_anchors == "given":
        return ref
    a = _anchors(scenario)
    return dataclasses.replace(ref, **{f"anchors_{axis}_m": tuple(float(v) for v in a[:, j])
                                       for j, axis in enumerate(AXES[a.shape[1]])})


def branch_at(network: str, points_m: npt.ArrayLike) -> tuple[list[str], npt.NDArray[np.float64]]:
    """(branch name, signed distance to the meshed wall (m)) of each point (m, d), on the network's axes.

    The branch is the centreline tube holding the point; the distance is the plant's meshed wall's
    (:func:`vesselbot_ros.vessels.tree_field.meshed_wall`), exact in the junctions too.
    """
    net = load_network(network)
    geom = NetworkGeometry(net)
    q = geom.query(points_m)
    return [geom.names[i] for i in q["branch"]], meshed_wall(net).query(points_m)["sdist"]


def navigation_metrics(scenario, t_s: npt.ArrayLike, p_true: npt.ArrayLike) -> dict[str, object]:  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Where the robot went in a network run.

    Keys: ``branch_final`` (branch holding the final true position),
    ``route_outlet`` (target, ``""`` if none), ``reached_target`` (1 if the final
    position lies inside the lumen of the target branch, further into it than
    the parent's radius at the node), ``outside_lumen_time_s`` (time the robot's
    centre spent outside the lumen, s: the pulsating lumen of eq. (13), where the plant's wall was at that
    time) and ``outside_lumen_first_s``
    (first tick outside, s, -1 if never): leaving the lumen is an event every
    run reports.
    """
    return navigation_outcome(scenario.physics.vessel.network, scenario.reference.route_outlet, t_s, p_true,
                              blood=scenario.physics.blood, pulsation=pulsation_of(scenario.physics.flow))


def pulsation_of(flow: FlowParams) -> tuple[float, float, float]:
    """``(A, omega, phi)`` of the wall's eq. (13) pulsation ``D(t) = D (1 + A sin(omega t + phi))`` of a flow section."""
    return (flow.diameter_pulsation, flow.angular_frequency_rad_per_s, flow.phase_rad)


def navigation_outcome(network: str, target: str, t_s: npt.ArrayLike, p_true: npt.ArrayLike, *,
                       blood: BloodParams | None = None,
                       pulsation: tuple[float, float, float] | None = None) -> dict[str, object]:
    """:func:`navigation_metrics` from plain values (network file, target outlet or "").

    "Outside the lumen" is outside the meshed wall (:func:`vesselbot_ros.vessels.tree_field.meshed_wall`, read
    from the field of ``blood``, default the shipped scenarios' blood: the wall does not depend on it) as it
    was at each tick: ``pulsation`` ``(A, omega, phi)`` (:func:`pulsation_of`) moves it as the plant does
    (``s_t = s + D eps(t) / 2``, ``eps(t) = A sin(omega t + phi)``, ``D`` the local diameter); ``None`` judges
    against the wall at rest.  The branch holding a point is its centreline tube's.
    """
    t = np.asarray(t_s, dtype=np.float64)
    p = np.asarray(p_true, dtype=np.float64)
    net = load_network(network)
    geom = NetworkGeometry(net)
    q = geom.query(p)
    # the plant's meshed wall, where it was at each tick (the plant's s_t): a bead resting on a dilated floor is
    # inside the lumen, one pressed past a contracted wall is not
    wq = meshed_wall(net, blood).query(p)
    s = wq["sdist"]
    if pulsation is not None:
        amp, omega, phase = pulsation
        s = s + 0.5 * wq["diameter"] * (amp * np.sin(omega * t + phase))
    out = s < 0.0
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
