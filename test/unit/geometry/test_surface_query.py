"""The exact 3-D query (vesselbot_ros.geometry.surface_query) against analytic walls.

Surfaces meshed with gmsh's OpenCASCADE kernel (surface mesh only, caps left out; test/unit/geometry/conftest.py).
The references are independent of the module: analytic distances and normals of a cylinder, a torus section
and the branches of a Y of cylinders.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from vesselbot_ros.geometry.fixtures import Y_BRANCHES
from vesselbot_ros.geometry.surface_wall import Wall3D

R = 1.5e-3
Array = npt.NDArray[np.float64]


def _angle(a: Array, b: Array) -> Array:
    return np.degrees(np.arccos(np.clip((a * b).sum(axis=1), -1.0, 1.0)))


def test_cylinder_distance_within_5_um_and_smooth_normal_within_2_deg(cylinder: Wall3D) -> None:
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


def test_torus_distance_and_normal(torus: Wall3D) -> None:
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


def test_y_branches_meet_the_standard_away_from_the_crease(y: Wall3D) -> None:
    """Within 1 mm of a branch's wall, 3 mm or more from the node: 5 um and 2 deg (points 0.3 mm or more off
    the branch's axis: nearer, in the daughters of radius 1.2 mm, a point is ill-conditioned and the smooth
    normal can be 2.2 deg off, 1 point in 10^5)."""
    rng = np.random.default_rng(4)
    for s0, u, L, r in Y_BRANCHES:
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
