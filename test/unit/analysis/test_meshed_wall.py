"""A network's or a tree's floor as the planner rests a bead on it: found below a point, and a bead put on it."""

from __future__ import annotations

import numpy as np
import pytest

from vesselbot_ros.analysis.meshed_wall import MeshedWall
from vesselbot_ros.sim.scenario import load_scenario


@pytest.fixture(scope="module")
def tree():
    return MeshedWall(load_scenario("paper_iiic_network_upper_3d"))


def test_the_floor_below_a_point_of_the_trunk_is_one_radius_and_a_brush_above_its_lower_wall(tree):
    # the trunk: a 3 mm tube along x at y = z = 0
    floor = tree.floor_below(np.array([1.0e-3, 0.2e-3, 0.5e-3]))
    assert floor is not None
    assert floor[0] == pytest.approx(1.0e-3) and floor[1] == pytest.approx(0.2e-3)
    lower_wall = -np.sqrt(1.5e-3**2 - 0.2e-3**2)
    assert floor[2] == pytest.approx(lower_wall + tree.gap_m, abs=5e-6)
    s, n, _d = tree.frames(0.0, floor, still=True)
    assert s[0] == pytest.approx(tree.gap_m, abs=1e-9) and n[0][2] > 0.9
    pressed = tree.floor_below(np.array([1.0e-3, 0.2e-3, 0.5e-3]), press_m=25e-6)
    assert np.linalg.norm(pressed - floor) == pytest.approx(25e-6, rel=1e-6)
    assert tree.floor_below(np.array([1.0e-3, 0.0, 5.0e-3])) is None  # outside the lumen


def test_points_in_the_wall_or_meant_to_rest_within_reach_are_put_on_the_pulsating_resting_surface(tree):
    t = np.array([0.25, 0.75, 0.75, 0.25])  # eps(t) = 0.1 cos(2 pi t) = 0: the wall where it rests
    base = tree.floor_below(np.array([1.0e-3, 0.0, 0.0]))
    p = np.repeat(base[None, :], 4, axis=0)
    p[:, 2] += np.array([-40e-6, -40e-6, 60e-6, 60e-6])  # two in the wall; two above it
    v = np.zeros_like(p)
    loose = tree.snap(t, p, v)
    meant = tree.snap(t, p, v, resting=np.array([True, True, True, False]))
    s_loose = tree.frames(t, loose.p)[0]
    assert list(loose.on_wall[:2]) == [True, True]
    np.testing.assert_allclose(s_loose[:2], tree.gap_m, atol=1e-9)  # out of the wall onto the surface
    np.testing.assert_allclose(meant.p[3], p[3])  # not meant to rest, 60 um above the surface: left where it is
    s_meant = tree.frames(t, meant.p)[0]
    assert meant.on_wall[2]
    assert s_meant[2] == pytest.approx(tree.gap_m, abs=1e-9)
    # a point on the wall moves with it along its normal: the pulsation's wall velocity, -D eps'(t) / 2
    _e, de = tree.eps(t[:1])
    assert abs(de[0]) > 0.5 and loose.v[0][2] == pytest.approx(-0.5 * 3.0e-3 * de[0], rel=0.02)
