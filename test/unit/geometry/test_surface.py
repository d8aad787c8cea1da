"""The 3-D wall surface (vesselbot_ros.geometry.surface): continued beyond its caps, and its caps' rule."""

from __future__ import annotations

import numpy as np
import pytest

from vesselbot_ros.geometry.fixtures import cylinder_wall
from vesselbot_ros.geometry.surface import wall_surface
from vesselbot_ros.geometry.surface_wall import Wall3D

R = 1.5e-3


def test_cylinder_continues_beyond_its_caps_as_a_tube(cylinder: Wall3D) -> None:
    """Beyond an open end the wall is the rim extruded along the cap's outward normal."""
    q = np.array([[-0.5e-3, 0.0, 0.0], [-0.8e-3, 1.0e-3, 0.0], [5.6e-3, 0.0, -1.2e-3], [-0.5e-3, 0.0, 1.8e-3]])
    s = cylinder.query(q)["sdist"]
    np.testing.assert_allclose(s, [R, R - 1.0e-3, R - 1.2e-3, R - 1.8e-3], atol=2e-6)


def test_every_wall_boundary_edge_must_lie_on_a_cap() -> None:
    v, t, caps, _n = cylinder_wall(length_m=2e-3, h_m=0.3e-3)
    with pytest.raises(ValueError, match="lie on no cap"):
        wall_surface(v, t, caps[:1], 1e-3)
