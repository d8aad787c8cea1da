"""Vessel-network format, validation and pure geometry (vesselbot_ros.vessels.network, .route)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vesselbot_ros.config import ConfigError, load_dataclass
from vesselbot_ros.vessels.network import NetworkGeometry, VesselNetworkParams, load_network, route_to_outlet


def _net(branches, **kw):  # type: ignore[no-untyped-def]
    return load_dataclass(VesselNetworkParams, {"name": "t", "branches": branches, **kw}, "")


Y = [
    {"name": "a", "parent": "", "x_m": [0.0, 5e-3], "z_m": [0.0, 0.0], "radius_m": [1e-3]},
    {"name": "b", "parent": "a", "x_m": [5e-3, 12e-3], "z_m": [0.0, 5e-3], "radius_m": [0.8e-3]},
    {"name": "c", "parent": "a", "x_m": [5e-3, 12e-3], "z_m": [0.0, -5e-3], "radius_m": [0.8e-3]},
]


def test_non_positive_radius_names_the_key_and_the_value() -> None:
    bad = [dict(Y[0], radius_m=[1e-3, -2e-4])]
    with pytest.raises(ConfigError, match=r"branches\[0\]\.radius_m\[1\] must be > 0, got -0\.0002"):
        _net(bad)


def test_unknown_key_and_missing_parent_are_errors() -> None:
    with pytest.raises(ConfigError, match="unknown key branches\\[0\\].diameter_m"):
        _net([dict(Y[0], diameter_m=1.0)])
    with pytest.raises(ConfigError, match="parent 'zz' is not a branch name"):
        _net([Y[0], dict(Y[1], parent="zz")])


def test_daughter_must_start_at_its_parents_end() -> None:
    with pytest.raises(ConfigError, match=r"branches\[1\] \('b'\) must start at the last point of its parent 'a'"):
        _net([Y[0], dict(Y[1], x_m=[5.5e-3, 12e-3])])


def test_overlapping_branches_are_named_with_where() -> None:
    # two siblings that run side by side 1 mm apart with radii summing to 1.6 mm
    close = [Y[0], dict(Y[1], x_m=[5e-3, 8e-3, 20e-3], z_m=[0.0, 0.5e-3, 0.5e-3]),
             dict(Y[2], x_m=[5e-3, 8e-3, 20e-3], z_m=[0.0, -0.5e-3, -0.5e-3])]
    with pytest.raises(ConfigError, match=r"branches 'b' and 'c' overlap near \(x, z\) = .* radii sum 0\.0016"):
        _net(close)
    _net(Y)  # the same daughters diverging are fine


def test_straight_branch_geometry_is_exact() -> None:
    g = NetworkGeometry(_net([Y[0]]))
    z = np.linspace(-0.9e-3, 0.9e-3, 7)
    q = g.query(np.column_stack([np.full(7, 2e-3), z]))
    np.testing.assert_allclose(q["sdist"], 1e-3 - np.abs(z), atol=1e-15)
    np.testing.assert_allclose(q["diameter"], 2e-3)
    up = z > 0
    np.testing.assert_allclose(q["normal"][up], [[0.0, -1.0]] * int(up.sum()), atol=1e-12)  # inward: away from the upper wall


def test_geometry_picks_the_branch_and_routes_over_the_tree() -> None:
    net = _net(Y)
    g = NetworkGeometry(net)
    q = g.query(np.array([[10e-3, 3.57e-3], [10e-3, -3.57e-3], [1e-3, 0.0], [1e-3, 3e-3]]))
    assert [g.names[i] for i in q["branch"][:3]] == ["b", "c", "a"]
    assert q["sdist"][3] < 0  # outside
    assert route_to_outlet(net, "c") == ["a", "c"]
    assert net.outlets == ["b", "c"]
    with pytest.raises(ConfigError, match="route outlet 'x'"):
        route_to_outlet(net, "x")


def test_shipped_networks_load() -> None:
    net = load_network("paper_iiic_artery")
    assert net.outlets == ["side_down", "side_up", "upper", "lower"]
    assert load_network("config/vessels/straight_table3.yaml").root.name == "trunk"


@settings(max_examples=150, deadline=None)
@given(name=st.sampled_from(["paper_iiic_artery", "small_artery_4gen", "straight_table3"]),
       u=st.floats(-0.1, 1.1), v=st.floats(-0.1, 1.1))
def test_point_clearance_equals_the_vectorised_query_bit_for_bit(name: str, u: float, v: float) -> None:
    g = NetworkGeometry(load_network(name))
    x0, x1, z0, z1 = g.bbox  # points in and around the lumen's bounding box, 10 % beyond each side
    x, z = x0 + u * (x1 - x0), z0 + v * (z1 - z0)
    q = g.query(np.array([[x, z]]))
    assert g.clearance(x, z) == (q["sdist"][0], q["diameter"][0])
