"""The 3-D wall's local diameter (vesselbot_ros.geometry.surface_wall): 2 R in a tube, the branch's in a Y."""

from __future__ import annotations

import numpy as np

from vesselbot_ros.geometry.fixtures import Y_BRANCHES
from vesselbot_ros.geometry.surface_wall import Wall3D

R = 1.5e-3


def test_local_diameter_is_2r_in_a_cylinder_and_follows_the_branch_in_the_y(cylinder: Wall3D, y: Wall3D) -> None:
    h = 0.15e-3
    d = cylinder.local_diameter([2e-3, -1.8e-3, -1.8e-3], h, (25, 25, 9))
    Z, Y, _X = np.meshgrid(-1.8e-3 + h * np.arange(25), -1.8e-3 + h * np.arange(25), 2e-3 + h * np.arange(9), indexing="ij")
    lumen = np.hypot(Y, Z) < R - 1e-5
    assert np.abs(d[lumen] - 2 * R).max() < 5e-6
    assert np.abs(d[~lumen] - 2 * R).max() < 5e-6  # outside: the nearest lumen node's
    # in the Y: a daughter's width in the daughter, the parent's in the parent
    s0, u, _L, r = Y_BRANCHES[1]
    p = s0 + 4.5e-3 * u
    dd = y.local_diameter(p - 0.45e-3, 0.3e-3, (4, 4, 4))
    assert np.abs(dd - 2 * r).max() < 3e-5
    dp = y.local_diameter(np.array([-4e-3, -0.45e-3, -0.45e-3]), 0.3e-3, (4, 4, 4))
    assert np.abs(dp - 2 * R).max() < 3e-5


def test_ball_above_a_seams_ridge_reads_the_lumen_not_its_own_distance(y: Wall3D) -> None:
    """Where a daughter's tube leaves the node's ball the wall folds into the lumen (a ridge, as where the carotid's
    common carotid meets its external carotid).  Above the ridge the nearest wall point is on it and the smooth normal
    is one face's: the ball through the point it gives was held by the ridge at the point's own distance (0.3-0.95 mm
    here); the ball through the nearest wall point along the direction to it is the lumen's (docs/vessels.md)."""
    s0, u, _L, r = Y_BRANCHES[1]
    t = np.sqrt(R * R - r * r)  # the seam: the daughter's cylinder meets the node's ball
    for phi in np.radians([0.0, 45.0, 90.0, 135.0]):
        w = np.cos(phi) * np.array([-u[1], u[0], 0.0]) + np.sin(phi) * np.array([0.0, 0.0, 1.0])
        ridge = s0 + t * u + r * w
        up = -ridge / R - w  # between the two faces' inward normals
        q = ridge + 0.25e-3 * up / np.linalg.norm(up)
        d = y.local_diameter(q, 1e-4, (1, 1, 1)).ravel()[0]
        assert 1.6e-3 < d < 2 * R + 1e-5, (np.degrees(phi), d)
