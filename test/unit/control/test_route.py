"""Route planning (vesselbot_ros.control.route) and the scenario checks of a network; routes in a 3-D tree: the
planar route's anchors in a tree in the plane, the cross-section's vertical in space."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control import route
from vesselbot_ros.control.reference_design import wall_safe_delta_m
from vesselbot_ros.control.route import VERTICAL_SINE, anchor_arcs, planned_reference, route_branches, up_directions
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios
from vesselbot_ros.vessels.network import load_network
from vesselbot_ros.vessels.tube_geometry import NetworkGeometry

UPPER = shipped_scenarios()["paper_iiic_network_upper"]


def test_route_follows_the_tree_and_anchors_follow_the_design_map_rule() -> None:
    sc = load_scenario(UPPER)
    assert route_branches(sc.physics.vessel.network, "upper") == ["trunk_a", "trunk_b", "trunk_c", "upper"]
    ref = planned_reference(sc)
    a = np.column_stack([ref.anchors_x_m, ref.anchors_z_m])
    assert tuple(a[0]) == tuple(sc.initial.p0_m)
    geom = NetworkGeometry(load_network(sc.physics.vessel.network))
    q = geom.query(a[1:])
    names = [geom.names[i] for i in q["branch"]]
    assert names[-1] == "upper"
    # every anchor inside the lumen, at most the wall-safe height above its centreline (upper side) ...
    assert np.all(q["sdist"] > sc.physics.robot.radius_m)
    assert np.all(q["sdist"] >= 0.5 * q["diameter"] - 0.859e-3 - 1e-6)
    # ... and on the centreline at the major node (x = 10 mm), where the route changes wall side
    at_node = np.abs(a[1:, 0] - 10e-3) < 0.1e-3
    assert at_node.any() and np.all(q["sdist"][at_node] > 0.5 * q["diameter"][at_node] - 0.05e-3)
    # the reference passes through the anchors
    from vesselbot_ros.control.bspline_reference import ReferenceTrajectory

    path = ReferenceTrajectory(ref).path(400)
    assert np.all(geom.signed_distance(path) > sc.physics.robot.radius_m)


def test_scenario_checks_of_a_network_name_key_and_value() -> None:
    with pytest.raises(ConfigError, match=r"reference.route_outlet must be an outlet of network 'paper_iiic_artery' .* got 'trunk_b'"):
        load_scenario(UPPER, sets=["reference.route_outlet=trunk_b"])
    with pytest.raises(ConfigError, match=r"initial.p0_m must lie inside the vessel network 'paper_iiic_artery', got \[0.0, -0.0016\]"):
        load_scenario(UPPER, sets=["initial.p0_m=[0.0, -1.6e-3]"])
    with pytest.raises(ConfigError, match="physics.vessel.network: vessel network 'nosuch' does not exist"):
        load_scenario(UPPER, sets=["physics.vessel.network=nosuch"])
    with pytest.raises(ConfigError, match="reference.route_outlet needs physics.vessel.network"):
        load_scenario(shipped_scenarios()["sound_small_artery"], sets=["reference.route_outlet=upper"])
    with pytest.raises(ConfigError, match="major_bifurcation.enabled must be false with a network"):
        load_scenario(UPPER, sets=["physics.vessel.major_bifurcation.enabled=true"])


# --- routes in a 3-D tree -------------------------------------------------------------------------------------

def test_in_the_plane_the_3d_route_is_the_planar_route() -> None:
    """The III-C tree given in 3-D (y = 0): the anchors are the planar route's, x and z, to rounding; y = 0."""
    sc = load_scenario(shipped_scenarios()["paper_iiic_network_upper"])
    ref = sc.reference
    base = dataclasses.replace(sc.physics, vessel=dataclasses.replace(sc.physics.vessel, network=""))

    def height_of(d: float) -> float:
        pd = dataclasses.replace(base, vessel=dataclasses.replace(base.vessel, diameter_m=d))
        return wall_safe_delta_m(pd, sc.observer, ref.route_wall_margin_m)

    planar = route._anchors(sc)
    p0 = np.array([sc.initial.p0_m[0], 0.0, sc.initial.p0_m[1]])
    spatial = route.route_anchors(load_network("paper_iiic_artery_3d"), ref.route_outlet, p0, ref.route_anchor_spacing_m,
                                  ref.route_end_margin_m, height_of)
    assert spatial.shape == (len(planar), 3)
    np.testing.assert_allclose(spatial[:, [0, 2]], planar, rtol=0, atol=1e-12)
    assert np.all(spatial[:, 1] == 0.0)


@settings(max_examples=80, deadline=None)
@given(st.floats(0, 2 * math.pi), st.floats(-1.0, 1.0))
def test_up_is_the_cross_sections_vertical(azimuth: float, sz: float) -> None:
    """Up is a unit vector across the centreline, with the most +z of any such; none along a vertical centreline."""
    t = np.array([math.sqrt(1 - sz * sz) * math.cos(azimuth), math.sqrt(1 - sz * sz) * math.sin(azimuth), sz])
    up, ok = up_directions(t)
    if math.sqrt(1 - sz * sz) <= VERTICAL_SINE:
        assert not ok[0] and np.all(up == 0.0)
        return
    assert ok[0]
    assert abs(np.linalg.norm(up[0]) - 1.0) < 1e-12 and abs(up[0] @ t) < 1e-12
    assert abs(up[0, 2] - math.sqrt(1 - sz * sz)) < 1e-12  # the largest vertical component across t


def test_a_tree_in_space_puts_every_anchor_inside_its_tube_above_the_centreline() -> None:
    """The synthetic 4-generation tree: every anchor lies inside the lumen's tubes, at the wall-safe height above the
    centreline's cross-section vertical (or on it near a node), and the route ends near its outlet."""
    net = load_network("synthetic_tree_3d")
    geom = NetworkGeometry(net, dims=3)
    outlet = [b.name for b in net.branches if not any(c.parent == b.name for c in net.branches)][-1]
    root = next(b for b in net.branches if not b.parent)
    p0 = geom.centreline(root.name)[0]
    anchors = route.route_anchors(net, outlet, p0, 2.0e-3, 1.0e-3, lambda d: 0.25 * d)
    q = geom.query(anchors)
    assert np.all(q["sdist"] > 0.2 * q["radius"])  # inside, a quarter diameter off the axis at most
    end = geom.centreline(outlet)[-1]
    assert np.linalg.norm(anchors[-1] - end) < 3.5e-3


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 5e-3), st.floats(1e-4, 30e-3), st.floats(0.5e-3, 4e-3))
def test_the_route_ends_at_its_margin_or_up_to_one_spacing_short(s0: float, length: float, spacing: float) -> None:
    """``spaced``: every spacing from the start, the last within one spacing of the end; ``at_margin``: evenly
    spaced at most one spacing apart, the last exactly at the end."""
    s_end = s0 + length
    spaced = anchor_arcs(s0, s_end, spacing, "spaced")
    assert np.allclose(np.diff(np.concatenate([[s0], spaced])), spacing)
    if length >= spacing:
        assert s_end - spacing - 1e-12 < spaced[-1] <= s_end + 1e-12
    at = anchor_arcs(s0, s_end, spacing, "at_margin")
    gaps = np.diff(np.concatenate([[s0], at]))
    assert at[-1] == pytest.approx(s_end, abs=1e-15) and np.allclose(gaps, gaps[0])
    assert gaps[0] <= spacing * (1 + 1e-9)
    assert gaps[0] >= spacing * (at.size - 1) / at.size * (1 - 1e-9)  # one anchor fewer would space them wider


def test_route_end_is_validated_and_left_out_of_the_mapping_when_spaced() -> None:
    from vesselbot_ros.config import ConfigError, to_mapping
    from vesselbot_ros.control.bspline_reference import ReferenceParams

    with pytest.raises(ConfigError, match="route_end.*'last'"):
        ReferenceParams(route_end="last")  # type: ignore[arg-type]
    assert "route_end" not in to_mapping(ReferenceParams())
    assert to_mapping(ReferenceParams(route_end="at_margin"))["route_end"] == "at_margin"


def test_a_planned_anchor_spacing_whose_spline_would_not_fit_is_refused_with_the_estimate() -> None:
    """10 cm of route at 10 nm: 10 million planned anchors (the old planner made them, then the dense spline)."""
    from vesselbot_ros.config import ConfigError

    with pytest.raises(ConfigError, match=r"^reference\.route_anchor_spacing_m=1e-08: the reference's B-spline set-up "
                                          r"through 1e\+07 planned anchors needs about [0-9.]+ TiB of memory"):
        anchor_arcs(0.0, 0.1, 1e-8)
    assert len(anchor_arcs(0.0, 0.1, 2.5e-3)) == 40


def test_a_route_to_a_short_side_branch_ends_inside_it() -> None:
    """side_down of the 3-D III-C tree is 4 mm long: the 2 mm end margin with 2.5 mm spacing left the route's last
    anchor in the trunk, before the junction (the run's target unreachable by any loop); it ends inside it now."""
    from vesselbot_ros.control.route import branch_at

    sc = load_scenario(shipped_scenarios()["paper_iiic_network_upper_3d"], sets=["reference.route_outlet=side_down"])
    ref = planned_reference(sc)
    names, sdist = branch_at(sc.physics.vessel.network, ref.anchor_points()[-1:])
    assert names == ["side_down"] and sdist[0] > 0.0
