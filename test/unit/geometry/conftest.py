"""The 3-D reference walls the geometry tests share, meshed once per session (gmsh, seconds each).

Walls of :mod:`vesselbot_ros.geometry.fixtures` as :class:`~vesselbot_ros.geometry.surface_wall.Wall3D`
(``cylinder``, ``torus``, ``y``), and the Y's sampled wall without and with model and list cells (``y_fast``).
"""

from __future__ import annotations

import math

import pytest

from vesselbot_ros.geometry.field_build import WallField3D, build_wall_field3d
from vesselbot_ros.geometry.fixtures import bent_tube_wall, cylinder_wall, y_wall
from vesselbot_ros.geometry.surface_wall import Wall3D

H = 0.2e-3


@pytest.fixture(scope="session")
def cylinder() -> Wall3D:
    v, t, caps, _n = cylinder_wall(length_m=5e-3)
    return Wall3D(v, t, caps)


@pytest.fixture(scope="session")
def torus() -> Wall3D:
    v, t, caps, _n = bent_tube_wall(angle_rad=math.radians(60))
    return Wall3D(v, t, caps)


@pytest.fixture(scope="session")
def y() -> Wall3D:
    v, t, caps, _n = y_wall()
    return Wall3D(v, t, caps)


@pytest.fixture(scope="session")
def y_fast() -> tuple[WallField3D, WallField3D]:
    """The Y refined, without and with model cells and list cells (their lattice coarser than the plant's, for
    speed)."""
    v, t, caps, _n = y_wall()
    wall = Wall3D(v, t, caps, margin_m=1.05e-3 + 3 * H)
    return (build_wall_field3d(wall, h_m=H, refine=2),
            build_wall_field3d(wall, h_m=H, refine=2, tube=True, list_max=64, list_lattice=9, list_sub=2))
