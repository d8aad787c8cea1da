"""The sampled 3-D wall (vesselbot_ros.geometry.field_build) against the exact query and analytic walls.

Small gmsh surfaces (0.1 mm triangles) on a 0.2 mm grid, so the builds take seconds; the standard (5 um,
2 deg within 1 mm of the wall) must hold on it too.  Points: uniform in the grid's box, kept within 1 mm
of the wall (the exact query's distance), inside and outside, the Y's junction and crease included.  The
fixtures ``cylinder``, ``torus`` and ``y`` here are sampled walls (they stand in for conftest.py's exact ones).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from vesselbot_ros.geometry.field_build import WallField3D, build_wall_field3d, grid_box
from vesselbot_ros.geometry.field_lookup import NODE_STRIDE, field_points3d
from vesselbot_ros.geometry.fixtures import bent_tube_wall, cylinder_wall, y_solids, y_wall
from vesselbot_ros.geometry.surface import Cap
from vesselbot_ros.geometry.surface_wall import Wall3D

R = 1.5e-3
H = 0.2e-3
Array = npt.NDArray[np.float64]


def _angle(a: Array, b: Array) -> Array:
    return np.degrees(np.arccos(np.clip((a * b).sum(axis=1), -1.0, 1.0)))


def _near_wall(field: WallField3D, n: int, seed: int) -> Array:
    rng = np.random.default_rng(seed)
    o = field.head[:3]
    top = o + field.head[3] * (np.array(field.shape) - 1)
    q = rng.uniform(o, top, size=(n, 3))
    return np.ascontiguousarray(q[np.abs(field.wall.query(q)["sdist"]) <= 1e-3])


def _build(v: Array, t: npt.NDArray[np.int64], caps: list[Cap], refine: int = 1) -> WallField3D:
    return build_wall_field3d(Wall3D(v, t, caps, margin_m=1.05e-3 + 3 * H), h_m=H, refine=refine)


@pytest.fixture(scope="module")
def cylinder() -> WallField3D:
    v, t, caps, _n = cylinder_wall(length_m=5e-3)
    return _build(v, t, caps)


@pytest.fixture(scope="module")
def torus() -> WallField3D:
    v, t, caps, _n = bent_tube_wall(angle_rad=math.radians(60))
    return _build(v, t, caps)


@pytest.fixture(scope="module")
def y() -> WallField3D:
    v, t, caps, _n = y_wall()
    return _build(v, t, caps, refine=2)


def test_cylinder_meets_the_standard_against_the_analytic_wall(cylinder: WallField3D) -> None:
    q = _near_wall(cylinder, 60000, 1)
    q = q[(q[:, 0] > 0.5e-3) & (q[:, 0] < 4.5e-3)]
    rho = np.hypot(q[:, 1], q[:, 2])
    r = cylinder.query(q)
    assert len(q) > 10000
    assert np.abs(r["sdist"] - (R - rho)).max() < 5e-6
    n_true = -np.column_stack([0 * rho, q[:, 1] / rho, q[:, 2] / rho])
    assert _angle(r["normal"], n_true).max() < 2.0
    lumen = rho < R
    assert np.abs(r["diameter"][lumen] - 2 * R).max() < 1e-5


def test_bent_tube_meets_the_standard_against_the_analytic_wall(torus: WallField3D) -> None:
    q = _near_wall(torus, 80000, 2)
    ph = np.arctan2(q[:, 1], q[:, 0])
    q = q[(ph > math.radians(8)) & (ph < math.radians(52))]
    ph = ph[(ph > math.radians(8)) & (ph < math.radians(52))]
    dvec = q - 6e-3 * np.column_stack([np.cos(ph), np.sin(ph), 0 * ph])
    rho = np.linalg.norm(dvec, axis=1)
    r = torus.query(q)
    assert len(q) > 10000
    assert np.abs(r["sdist"] - (R - rho)).max() < 5e-6
    assert _angle(r["normal"], -dvec / rho[:, None]).max() < 2.0


def test_y_meets_the_standard_against_the_exact_query_junction_included(y: WallField3D) -> None:
    """Anywhere within 1 mm of the Y's wall (crease, apex and caps included): the fallback takes the cells
    interpolation cannot answer; the sign is the exact query's more than 5 um from the wall."""
    q = _near_wall(y, 150000, 3)
    r, e = y.query(q), y.wall.query(q)
    assert len(q) > 30000
    assert np.abs(r["sdist"] - e["sdist"]).max() < 5e-6
    assert _angle(r["normal"], e["normal"]).max() < 2.0
    far = np.abs(e["sdist"]) > 5e-6
    np.testing.assert_array_equal(r["sdist"][far] > 0, e["sdist"][far] > 0)
    assert 0.0 < y.stats["flagged_fraction"] < 0.1


def test_y_sign_is_the_analytic_unions(y: WallField3D) -> None:
    rng = np.random.default_rng(4)
    q = rng.uniform([-5.8e-3, -4.5e-3, -2.0e-3], [4.5e-3, 4.5e-3, 2.0e-3], size=(20000, 3))
    inside, near, beyond = y_solids(q)
    ok = (near > 5e-6) & ~beyond
    s = y.query(q)["sdist"]
    np.testing.assert_array_equal(s[ok] > 0, inside[ok])


def test_flagged_cells_and_points_off_the_grid_answer_exactly(y: WallField3D) -> None:
    """Where the lookup says it falls back (flagged cells, flagged sub-cells, off the grid), the answer is the
    exact query's bit for bit; refined blocks hold some cells and leave some sub-cells exact."""
    rng = np.random.default_rng(5)
    kk, jj, ii = np.nonzero(y.flags() != 0)
    pick = rng.choice(len(kk), size=min(4000, len(kk)), replace=False)
    h = y.head[3]
    q = y.head[:3] + h * (np.column_stack([ii[pick], jj[pick], kk[pick]]) + rng.uniform(0.01, 0.99, size=(len(pick), 3)))
    q = np.concatenate([q, [[-20e-3, 0.0, 0.0], [7.37e-3, 5.16e-3, 0.0]]])  # off the grid, in the lumen beyond two caps
    ex = y.exact_mask(q)
    assert ex[-2:].all() and 0 < ex.sum() < len(q)
    assert y.stats["refined_blocks"] > 0 and y.stats["exact_subcells"] > 0
    r, e = y.query(q[ex]), y.wall.query(q[ex])
    np.testing.assert_array_equal(r["sdist"], e["sdist"])
    np.testing.assert_array_equal(r["normal"], e["normal"])
    r = y.query(q[~ex])
    assert not np.array_equal(r["sdist"], y.wall.query(q[~ex])["sdist"])  # interpolated there


def test_the_pruned_exact_query_answers_as_the_whole_tree_wherever_the_lookup_asks_it(y: WallField3D) -> None:
    """The lookup carries the exact query pruned to the leaves of its exact cells and off the grid (split finer
    there, a fraction of the wall's tree): bit for bit the whole tree's answer everywhere in the grid and off it
    but far outside the lumen, where it is signed outside and no nearer than the wall."""
    full = (*y.args[:3], *y.wall._args)
    assert y.args[8].dtype == np.int32 and y.args[7].dtype == np.int32
    assert y.args[8].size < 0.5 * y.wall.tree.index.size
    rng = np.random.default_rng(8)
    o, h = y.head[:3], y.head[3]
    top = o + h * (np.array(y.shape) - 1)
    q = np.ascontiguousarray(rng.uniform(o, top, size=(40000, 3)))
    np.testing.assert_array_equal(field_points3d(q, *y.args), field_points3d(q, *full))
    g = y.wall.tree.grid  # off the grid, in the tree's box (beyond it the lists do not hold)
    off = np.ascontiguousarray(rng.uniform(g[0:3], g[0:3] + g[3] * g[4:7], size=(40000, 3)))
    off = off[((off < o) | (off >= top)).any(axis=1)]
    a, b = field_points3d(off, *y.args), field_points3d(off, *full)
    same = (a == b).all(axis=1)
    assert same.any() and (b[~same, 0] < 0).all()  # sealed leaves: wholly outside the lumen
    assert (a[~same, 0] <= b[~same, 0] + 1e-12).all()


def test_grid_nodes_lie_on_multiples_of_the_spacing_and_must_stay_in_the_candidate_tree() -> None:
    origin, n = grid_box([0.05e-3, -1.0e-3, 0.0], [1.0e-3, 1.0e-3, 0.3e-3], 0.1e-3, 0.2e-3)
    np.testing.assert_allclose(origin / 0.1e-3, np.round(origin / 0.1e-3), atol=1e-9)
    top = origin + 0.1e-3 * (np.array(n) - 1)
    assert (origin <= [-0.15e-3, -1.2e-3, -0.2e-3]).all() and (top >= [1.2e-3, 1.2e-3, 0.5e-3]).all()
    v, t, caps, _n = cylinder_wall(length_m=2e-3, h_m=0.3e-3)
    wall = Wall3D(v, t, caps, margin_m=0.3e-3, root_m=0.4e-3)
    with pytest.raises(ValueError, match="candidate tree"):
        build_wall_field3d(wall, h_m=0.2e-3, margin_m=1.0e-3)


def _well_conditioned(wall: Wall3D, q: Array, n: Array, rng: np.random.Generator) -> npt.NDArray[np.bool_]:
    turn = np.zeros(len(q))
    for _ in range(6):
        step = rng.normal(size=q.shape)
        step *= 5e-6 / np.linalg.norm(step, axis=1)[:, None]
        turn = np.maximum(turn, _angle(wall.query(q + step)["normal"], n))
    return turn <= 2.0


def test_list_cells_answer_as_the_exact_query(y_fast: tuple[WallField3D, WallField3D]) -> None:
    """Exact cells wholly in the lumen whose nearest triangles are few: the lookup scans the cell's list (checked
    at build against the exact query at 1000 points per cell), not the candidate tree; at random points of those
    cells it answers as the exact query bit for bit almost everywhere, and within the standard everywhere."""
    _plain, y = y_fast
    assert y.stats["list_cells"] > y.stats["list_cells_fine"] > 0 and 0 < y.stats["list_mean_len"] <= 64
    nx, ny, nz = y.shape
    rec = y.field.reshape(nz, ny, nx, NODE_STRIDE)[:-1, :-1, :-1]
    kk, jj, ii = np.nonzero(rec[:, :, :, 7] > 0)
    rng = np.random.default_rng(13)
    pick = rng.integers(0, len(kk), 20000)
    q = np.ascontiguousarray(y.head[:3] + H * (np.column_stack([ii[pick], jj[pick], kk[pick]]) + rng.uniform(0, 1, (len(pick), 3))))
    listed = y.list_mask(q)
    assert listed.mean() > 0.3 and not y.exact_mask(q[listed]).any()
    q = q[listed]
    r, e = y.query(q), y.wall.query(q)
    same = (r["sdist"] == e["sdist"]) & (r["normal"] == e["normal"]).all(axis=1)
    assert same.mean() > 0.99
    assert np.abs(r["sdist"] - e["sdist"]).max() < 5e-6
    ok = _well_conditioned(y.wall, q, e["normal"], rng)
    assert _angle(r["normal"], e["normal"])[ok].max() < 2.0
