"""Route anchors through a 3-D vessel tree (pure): the planar route's rule along a route in space.

The planar route (:mod:`vesselbot_ros.control.route`) puts anchors every
``spacing_m`` of centreline arc length from the point of the route nearest the
start to ``end_margin_m`` before the outlet, each one the wall-safe height of
the local diameter (Section III-A's design map) above the centreline on the
side whose normal points up, ramped down to the centreline within one local
diameter of a bifurcation node.  In a tree in space the same rule needs one
new notion, *up*: at a centreline point of unit tangent ``t`` it is the
scanner's vertical ``+z`` with its component along ``t`` removed,
``(z - (z . t) t) / |...|``, the direction in the vessel's cross-section in
which the upper wall lies (where the blood is slowest and the bead's weight
lifts it least); along a vertical stretch (``|z x t|`` below
``VERTICAL_SINE``) there is no upper wall and the anchor is on the centreline.
So the design map's height becomes a distance from the centreline along the
cross-section's vertical, hence from the upper wall along its normal: the
wall-safe gap of the 2-D rule.  In a tree in the plane y = 0 this is the
planar route's up (tested).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from vesselbot_ros.resources import require_fits, spline_setup_cost
from vesselbot_ros.vessels.network import NetworkGeometry, VesselNetworkParams, route_to_outlet

__all__ = ["VERTICAL_SINE", "up_directions", "anchor_arcs", "route_anchors_3d"]

#: Below this sine of the angle between the centreline and the vertical, the cross-section has no up.
VERTICAL_SINE = 0.05


def up_directions(tangents: npt.ArrayLike) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """Unit up direction in the cross-section at each unit tangent (k, 3), and where it exists (k,) (see module
    docstring; where the centreline is within ``VERTICAL_SINE`` of vertical the direction is 0)."""
    t = np.atleast_2d(np.asarray(tangents, dtype=np.float64))
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


def route_anchors_3d(net: VesselNetworkParams, outlet: str, p0_m: npt.ArrayLike, spacing_m: float,
                     end_margin_m: float, height_of: Callable[[float], float], *,
                     end: str = "spaced") -> npt.NDArray[np.float64]:
    """The anchors (k, 3) (m) of a reference from the start point ``p0_m`` (3,) to ``outlet``.

    Args:
        net: The tree (planar or not).
        outlet: The target outlet branch.
        p0_m: The start (injection) point (m); the first anchor.
        spacing_m: Arc length between anchors (m).
        end_margin_m: The last anchor lies this far before the outlet (m).
        height_of: The wall-safe height above the centreline of a vessel of diameter ``d`` (m -> m; negative
            or zero: on the centreline), e.g. Section III-A's design map
            (:func:`~vesselbot_ros.control.reference_design.wall_safe_delta_m`).
        end: Where the last anchor lies (:func:`anchor_arcs`: ``spaced`` or ``at_margin``).
    """
    geom = NetworkGeometry(net, dims=3)
    names = route_to_outlet(net, outlet)
    path = geom.centreline_path(names)
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    p0 = np.asarray(p0_m, dtype=np.float64)
    s0 = float(arc[int(np.argmin(np.linalg.norm(path - p0, axis=1)))])
    s_list = anchor_arcs(s0, arc[-1] - end_margin_m, spacing_m, end)
    tang = np.gradient(path, axis=0)
    tang /= np.linalg.norm(tang, axis=1)[:, None]
    up, _has_up = up_directions(tang)
    diam = 2.0 * geom.query(path)["radius"]
    nodes = np.cumsum([geom.length_m(b) for b in names])[:-1]  # the route's bifurcation nodes (arc length)
    heights: dict[float, float] = {}
    out = [p0]
    for s in s_list:
        i = int(np.clip(np.searchsorted(arc, s), 0, len(path) - 1))
        d = float(np.round(diam[i], 9))
        if d not in heights:
            heights[d] = max(0.0, float(height_of(d)))
        ramp = 1.0 if nodes.size == 0 else min(1.0, float(np.min(np.abs(nodes - s))) / d)
        out.append(path[i] + ramp * heights[d] * up[i])
    return np.array(out)
