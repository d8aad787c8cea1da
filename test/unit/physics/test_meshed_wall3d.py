"""The 3-D meshed wall (vesselbot_ros.physics.meshed_wall3d) against analytic walls and brute force.

Surfaces meshed here with gmsh's OpenCASCADE kernel (surface mesh only, caps left out).  The references
are independent of the module: analytic distances and normals of a cylinder, a torus section and a Y of
cylinders, and the union's inside test; the candidate lists against every triangle (bit-equal).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from vesselbot_ros.physics import meshed_wall3d as mw

R = 1.5e-3
Array = npt.NDArray[np.float64]


def _angle(a: Array, b: Array) -> Array:
    return np.degrees(np.arccos(np.clip((a * b).sum(axis=1), -1.0, 1.0)))


@pytest.fixture(scope="module")
def cylinder() -> mw.Wall3D:
    v, t, caps, _n = mw.cylinder_wall(length_m=5e-3)
    return mw.Wall3D(v, t, caps)


@pytest.fixture(scope="module")
def torus() -> mw.Wall3D:
    v, t, caps, _n = mw.bent_tube_wall(angle_rad=math.radians(60))
    return mw.Wall3D(v, t, caps)


@pytest.fixture(scope="module")
def y() -> mw.Wall3D:
    v, t, caps, _n = mw.y_wall()
    return mw.Wall3D(v, t, caps)


def test_cylinder_distance_within_5_um_and_smooth_normal_within_2_deg(cylinder: mw.Wall3D) -> None:
    rng = np.random.default_rng(1)
    n = 6000
    x = rng.uniform(0.5e-3, 4.5e-3, n)
    th = rng.uniform(0, 2 * np.pi, n)
    rho = rng.uniform(R - 1e-3, R + 1e-3, n)
    q = np.column_stack([x, rho * np.cos(th), rho * np.sin(th)])
    n_true = -np.column_stack([0 * x, np.cos(th), np.sin(th)])
    r = cylinder.query(q)
    facets = cylinder.query(q, smooth=False)
    assert np.abs(r["sdist"] - (R - rho)).max() < 5e-6
    np.testing.assert_array_equal(r["sdist"], facets["sdist"])  # the smooth query keeps the exact distance
    assert _angle(r["normal"], n_true).max() < 2.0
    # the facets' own normal is off by up to about h / (2 R) = 1.9 deg: the smooth one is several times better
    assert _angle(r["normal"], n_true).mean() < 0.25 * _angle(facets["normal"], n_true).mean()


def test_cylinder_continues_beyond_its_caps_as_a_tube(cylinder: mw.Wall3D) -> None:
    """Beyond an open end the wall is the rim extruded along the cap's outward normal."""
    q = np.array([[-0.5e-3, 0.0, 0.0], [-0.8e-3, 1.0e-3, 0.0], [5.6e-3, 0.0, -1.2e-3], [-0.5e-3, 0.0, 1.8e-3]])
    s = cylinder.query(q)["sdist"]
    np.testing.assert_allclose(s, [R, R - 1.0e-3, R - 1.2e-3, R - 1.8e-3], atol=2e-6)


def test_torus_distance_and_normal(torus: mw.Wall3D) -> None:
    rng = np.random.default_rng(2)
    n = 6000
    bend = 6e-3
    ph = rng.uniform(math.radians(8), math.radians(52), n)
    ps = rng.uniform(0, 2 * np.pi, n)
    rho = rng.uniform(R - 1e-3, R + 1e-3, n)
    er = np.column_stack([np.cos(ph), np.sin(ph), 0 * ph])
    u = np.cos(ps)[:, None] * er + np.sin(ps)[:, None] * np.array([0.0, 0.0, 1.0])
    q = bend * er + rho[:, None] * u
    r = torus.query(q)
    assert np.abs(r["sdist"] - (R - rho)).max() < 5e-6
    assert _angle(r["normal"], -u).max() < 2.0


def test_y_candidates_are_complete_and_the_sign_is_the_unions(y: mw.Wall3D) -> None:
    """Everywhere in the Y's box, junction and crease included: the candidate lists give the answer of brute
    force over every triangle bit for bit, and the sign is the analytic union's (cylinders and the node's ball)
    wherever the point is more than 5 um from every solid's surface."""
    rng = np.random.default_rng(3)
    q = rng.uniform([-5.8e-3, -4.5e-3, -2.0e-3], [4.5e-3, 4.5e-3, 2.0e-3], size=(3000, 3))
    inside, near, beyond = mw.y_solids(q)
    q = np.ascontiguousarray(q[~beyond])
    inside, near = inside[~beyond], near[~beyond]
    for smooth in (False, True):
        a, b = y.query(q, smooth=smooth), y.brute_force(q, smooth=smooth)
        np.testing.assert_array_equal(a["sdist"], b["sdist"])
        np.testing.assert_array_equal(a["normal"], b["normal"])
    s = y.query(q)["sdist"]
    far = near > 5e-6
    assert far.sum() > 2000
    np.testing.assert_array_equal(s[far] > 0, inside[far])


def test_y_branches_meet_the_standard_away_from_the_crease(y: mw.Wall3D) -> None:
    """Within 1 mm of a branch's wall, 3 mm or more from the node: 5 um and 2 deg (points 0.3 mm or more off
    the branch's axis: nearer, in the daughters of radius 1.2 mm, a point is ill-conditioned and the smooth
    normal can be 2.2 deg off, 1 point in 10^5)."""
    rng = np.random.default_rng(4)
    for s0, u, L, r in mw.Y_BRANCHES:
        e1 = np.cross(u, [0.0, 0.0, 1.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(u, e1)
        start, stop = (0.5e-3, L - 3e-3) if s0[0] < 0 else (3e-3, L - 0.5e-3)
        t = rng.uniform(start, stop, 3000)
        ps = rng.uniform(0, 2 * np.pi, 3000)
        rho = rng.uniform(max(r - 1e-3, 0.3e-3), r + 1e-3, 3000)
        radial = np.cos(ps)[:, None] * e1 + np.sin(ps)[:, None] * e2
        q = s0 + t[:, None] * u + rho[:, None] * radial
        res = y.query(q)
        assert np.abs(res["sdist"] - (r - rho)).max() < 5e-6
        assert _angle(res["normal"], -radial).max() < 2.0


def test_local_diameter_is_2r_in_a_cylinder_and_follows_the_branch_in_the_y(cylinder: mw.Wall3D, y: mw.Wall3D) -> None:
    h = 0.15e-3
    d = cylinder.local_diameter([2e-3, -1.8e-3, -1.8e-3], h, (25, 25, 9))
    Z, Y, _X = np.meshgrid(-1.8e-3 + h * np.arange(25), -1.8e-3 + h * np.arange(25), 2e-3 + h * np.arange(9), indexing="ij")
    lumen = np.hypot(Y, Z) < R - 1e-5
    assert np.abs(d[lumen] - 2 * R).max() < 5e-6
    assert np.abs(d[~lumen] - 2 * R).max() < 5e-6  # outside: the nearest lumen node's
    # in the Y: a daughter's width in the daughter, the parent's in the parent
    s0, u, _L, r = mw.Y_BRANCHES[1]
    p = s0 + 4.5e-3 * u
    dd = y.local_diameter(p - 0.45e-3, 0.3e-3, (4, 4, 4))
    assert np.abs(dd - 2 * r).max() < 3e-5
    dp = y.local_diameter(np.array([-4e-3, -0.45e-3, -0.45e-3]), 0.3e-3, (4, 4, 4))
    assert np.abs(dp - 2 * R).max() < 3e-5


def test_every_wall_boundary_edge_must_lie_on_a_cap() -> None:
    v, t, caps, _n = mw.cylinder_wall(length_m=2e-3, h_m=0.3e-3)
    with pytest.raises(ValueError, match="lie on no cap"):
        mw.wall_surface(v, t, caps[:1], 1e-3)
