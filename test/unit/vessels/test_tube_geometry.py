"""The centreline tubes: which tube holds a point, vectorised and compiled, on two axes or three
(vesselbot_ros.vessels.tube_geometry)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from vesselbot_ros.vessels.network import BranchParams, VesselNetworkParams, load_network
from vesselbot_ros.vessels.tube_geometry import NetworkGeometry

#: A straight trunk along x (r = 1 mm) and two daughters leaving its end at +/- 35.5 deg (r = 0.8 mm).
TRUNK = BranchParams("a", x_m=(0.0, 5e-3), z_m=(0.0, 0.0), radius_m=(1e-3,))
DAUGHTERS = (BranchParams("b", parent="a", x_m=(5e-3, 12e-3), z_m=(0.0, 5e-3), radius_m=(0.8e-3,)),
             BranchParams("c", parent="a", x_m=(5e-3, 12e-3), z_m=(0.0, -5e-3), radius_m=(0.8e-3,)))


def test_straight_branch_geometry_is_exact() -> None:
    g = NetworkGeometry(VesselNetworkParams("t", (TRUNK,)))
    z = np.linspace(-0.9e-3, 0.9e-3, 7)
    q = g.query(np.column_stack([np.full(7, 2e-3), z]))
    np.testing.assert_allclose(q["sdist"], 1e-3 - np.abs(z), atol=1e-15)
    np.testing.assert_allclose(q["diameter"], 2e-3)
    up = z > 0
    np.testing.assert_allclose(q["normal"][up], [[0.0, -1.0]] * int(up.sum()), atol=1e-12)  # inward: away from the upper wall


def test_query_picks_the_branch_a_point_is_deepest_in() -> None:
    g = NetworkGeometry(VesselNetworkParams("t", (TRUNK, *DAUGHTERS)))
    q = g.query(np.array([[10e-3, 3.57e-3], [10e-3, -3.57e-3], [1e-3, 0.0], [1e-3, 3e-3]]))
    assert [g.names[i] for i in q["branch"][:3]] == ["b", "c", "a"]
    assert q["sdist"][3] < 0  # outside


@settings(max_examples=150, deadline=None)
@given(name=st.sampled_from(["paper_iiic_artery", "small_artery_4gen", "straight_table3"]),
       u=st.floats(-0.1, 1.1), v=st.floats(-0.1, 1.1))
def test_point_clearance_equals_the_vectorised_query_bit_for_bit(name: str, u: float, v: float) -> None:
    g = NetworkGeometry(load_network(name))
    x0, x1, z0, z1 = g.bbox  # points in and around the lumen's bounding box, 10 % beyond each side
    x, z = x0 + u * (x1 - x0), z0 + v * (z1 - z0)
    q = g.query(np.array([[x, z]]))
    assert g.clearance(x, z) == (q["sdist"][0], q["diameter"][0])


@settings(max_examples=100, deadline=None)
@given(name=st.sampled_from(["paper_iiic_artery", "small_artery_4gen", "carotid_bifurcation_3d", "synthetic_tree_3d"]),
       u=st.floats(-0.1, 1.1), v=st.floats(-0.1, 1.1), w=st.floats(-0.1, 1.1))
def test_one_geometry_on_any_axes_the_plane_is_space_at_y_zero(name: str, u: float, v: float, w: float) -> None:
    # one class: a planar network on two axes gives the bits of the same network on three at y = 0
    net = load_network(name)
    g3 = NetworkGeometry(net, dims=3)
    x0, x1, y0, y1, z0, z1 = g3.bbox
    p3 = np.array([x0 + u * (x1 - x0), y0 + v * (y1 - y0) if not net.is_planar else 0.0, z0 + w * (z1 - z0)])
    q3 = g3.query(p3[None])
    assert g3.clearance(*p3) == (q3["sdist"][0], q3["diameter"][0])
    assert abs(np.linalg.norm(q3["normal"][0]) - 1.0) < 1e-12
    if net.is_planar:
        g2 = NetworkGeometry(net)
        assert g2.dims == 2 and g2.bbox == (x0, x1, z0, z1)
        q2 = g2.query(p3[None, ::2])
        for key in ("sdist", "diameter", "radius", "branch", "arc"):
            assert np.array_equal(q2[key], q3[key]), key
        assert np.array_equal(q2["normal"], q3["normal"][:, ::2]) and q3["normal"][0, 1] == 0.0
        assert np.array_equal(q2["foot"], q3["foot"][:, ::2])
        assert g2.clearance(*p3[::2]) == g3.clearance(*p3)
