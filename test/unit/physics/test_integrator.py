"""The compiled integrator's wall helpers (``vesselbot_ros.physics.integrator``): the wall's normal in any vessel."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from vesselbot_ros.control.model import DynamicsModel
from vesselbot_ros.physics.integrator import onto_lumen_at, wall_frames, wall_normal_into
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios


@numba.njit(cache=False)
def _normals(ts, points, geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    out = np.empty_like(points)
    for i in range(points.shape[0]):
        wall_normal_into(ts[i], points[i], geom, out[i])
    return out


@numba.njit(cache=False)
def _projected(t, y, geom, gap):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    moved = onto_lumen_at(t, y, geom, gap)
    return moved, y


def _model(name: str) -> DynamicsModel:
    sc = load_scenario(shipped_scenarios()[name])
    return DynamicsModel(sc.model_physics(), sc.sim.integrator)


def test_the_straight_vessels_wall_normal_is_the_one_the_projection_pushes_along() -> None:
    """Below the centreline the lower wall's inward normal is +z, above it the upper wall's is -z: the direction in
    which :func:`onto_lumen_at` puts a bead sunk into that wall back."""
    model = _model("sound_small_artery_ekf")
    pts = np.array([[0.0, -0.25e-3], [1e-3, 0.25e-3]])  # below and above the centreline
    n = _normals(np.zeros(2), pts, model.geom)
    np.testing.assert_array_equal(n, [[0.0, 1.0], [0.0, -1.0]])
    for point, normal in zip(pts, n, strict=True):  # a bead far into that wall comes back along the normal
        y = np.array([point[0], np.sign(point[1]) * 5e-3, 0.0, 0.0])
        moved, back = _projected(0.0, y.copy(), model.geom, 0.0)
        assert moved and back[0] == y[0]
        assert np.sign(back[1] - y[1]) == np.sign(normal[1])


@pytest.mark.parametrize("name", ["paper_iiic_network_upper", "paper_iiic_network_upper_3d"])
def test_a_network_or_trees_wall_normal_is_its_wall_frames(name: str) -> None:
    model = _model(name)
    geom = model.geom
    sc = load_scenario(shipped_scenarios()[name])
    from vesselbot_ros.control.bspline_reference import ReferenceTrajectory
    from vesselbot_ros.control.route import planned_reference

    pts = np.ascontiguousarray(np.asarray(ReferenceTrajectory(planned_reference(sc)).path(25))[:, :model.dims])
    ts = np.linspace(0.0, 0.5, len(pts))
    _s, frames, _d = wall_frames(ts, pts, geom)
    n = _normals(ts, pts, geom)
    np.testing.assert_array_equal(n, frames)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, rtol=1e-12)
