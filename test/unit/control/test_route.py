"""Route planning (vesselbot_ros.control.route) and the scenario checks of a network."""

from __future__ import annotations

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.route import planned_reference, route_branches
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios
from vesselbot_ros.vessels.network import NetworkGeometry, load_network

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
