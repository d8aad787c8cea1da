"""The sampled 3-D wall (vesselbot_ros.physics.wall_field3d) against the exact query and analytic walls.

Small gmsh surfaces (0.1 mm triangles) on a 0.2 mm grid, so the builds take seconds; the standard (5 um,
2 deg within 1 mm of the wall) must hold on it too.  Points: uniform in the grid's box, kept within 1 mm
of the wall (the exact query's distance), inside and outside, the Y's junction and crease included.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from vesselbot_ros.physics import meshed_wall3d as mw
from vesselbot_ros.physics import wall_field3d as wf

R = 1.5e-3
H = 0.2e-3
Array = npt.NDArray[np.float64]


def _angle(a: Array, b: Array) -> Array:
    return np.degrees(np.arccos(np.clip((a * b).sum(axis=1), -1.0, 1.0)))


def _near_wall(field: wf.WallField3D, n: int, seed: int) -> Array:
    rng = np.random.default_rng(seed)
    o = field.head[:3]
    top = o + field.head[3] * (np.array(field.shape) - 1)
    q = rng.uniform(o, top, size=(n, 3))
    return np.ascontiguousarray(q[np.abs(field.wall.query(q)["sdist"]) <= 1e-3])


def _build(v: Array, t: npt.NDArray[np.int64], caps: list[mw.Cap], refine: int = 1) -> wf.WallField3D:
    return wf.build_wall_field3d(mw.Wall3D(v, t, caps, margin_m=1.05e-3 + 3 * H), h_m=H, refine=refine)


@pytest.fixture(scope="module")
def cylinder() -> wf.WallField3D:
    v, t, caps, _n = mw.cylinder_wall(length_m=5e-3)
    return _build(v, t, caps)


@pytest.fixture(scope="module")
def torus() -> wf.WallField3D:
    v, t, caps, _n = mw.bent_tube_wall(angle_rad=math.radians(60))
    return _build(v, t, caps)


@pytest.fixture(scope="module")
def y() -> wf.WallField3D:
    v, t, caps, _n = mw.y_wall()
    return _build(v, t, caps, refine=2)


def test_cylinder_meets_the_standard_against_the_analytic_wall(cylinder: wf.WallField3D) -> None:
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


def test_bent_tube_meets_the_standard_against_the_analytic_wall(torus: wf.WallField3D) -> None:
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


def test_y_meets_the_standard_against_the_exact_query_junction_included(y: wf.WallField3D) -> None:
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


def test_y_sign_is_the_analytic_unions(y: wf.WallField3D) -> None:
    rng = np.random.default_rng(4)
    q = rng.uniform([-5.8e-3, -4.5e-3, -2.0e-3], [4.5e-3, 4.5e-3, 2.0e-3], size=(20000, 3))
    inside, near, beyond = mw.y_solids(q)
    ok = (near > 5e-6) & ~beyond
    s = y.query(q)["sdist"]
    np.testing.assert_array_equal(s[ok] > 0, inside[ok])


def test_flagged_cells_and_points_off_the_grid_answer_exactly(y: wf.WallField3D) -> None:
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


def test_the_pruned_exact_query_answers_as_the_whole_tree_wherever_the_lookup_asks_it(y: wf.WallField3D) -> None:
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
    np.testing.assert_array_equal(wf.field_points3d(q, *y.args), wf.field_points3d(q, *full))
    g = y.wall.tree.grid  # off the grid, in the tree's box (beyond it the lists do not hold)
    off = np.ascontiguousarray(rng.uniform(g[0:3], g[0:3] + g[3] * g[4:7], size=(40000, 3)))
    off = off[((off < o) | (off >= top)).any(axis=1)]
    a, b = wf.field_points3d(off, *y.args), wf.field_points3d(off, *full)
    same = (a == b).all(axis=1)
    assert same.any() and (b[~same, 0] < 0).all()  # sealed leaves: wholly outside the lumen
    assert (a[~same, 0] <= b[~same, 0] + 1e-12).all()


def test_grid_nodes_lie_on_multiples_of_the_spacing_and_must_stay_in_the_candidate_tree() -> None:
    origin, n = wf.grid_box([0.05e-3, -1.0e-3, 0.0], [1.0e-3, 1.0e-3, 0.3e-3], 0.1e-3, 0.2e-3)
    np.testing.assert_allclose(origin / 0.1e-3, np.round(origin / 0.1e-3), atol=1e-9)
    top = origin + 0.1e-3 * (np.array(n) - 1)
    assert (origin <= [-0.15e-3, -1.2e-3, -0.2e-3]).all() and (top >= [1.2e-3, 1.2e-3, 0.5e-3]).all()
    v, t, caps, _n = mw.cylinder_wall(length_m=2e-3, h_m=0.3e-3)
    wall = mw.Wall3D(v, t, caps, margin_m=0.3e-3, root_m=0.4e-3)
    with pytest.raises(ValueError, match="candidate tree"):
        wf.build_wall_field3d(wall, h_m=0.2e-3, margin_m=1.0e-3)


def test_tube_cells_answer_a_narrow_vessel_s_axis() -> None:
    """A vessel narrower than the band (R = 0.6 mm): near its axis interpolation of the cone s = R - rho fails
    (the cells went to the exact query); with ``tube`` the straight round tube fitted to each such cell answers
    them, within the standard of the exact query (the normal but within 50 um of the axis, where it is undefined)
    and of the analytic tube."""
    r0, h = 0.6e-3, 0.1e-3
    v, t, caps, _n = mw.cylinder_wall(r0, 3e-3, 0.04e-3)
    wall = mw.Wall3D(v, t, caps, margin_m=1.05e-3 + 3 * h)
    plain, tubes = (wf.build_wall_field3d(wall, h_m=h, refine=2, out_band_m=0.1e-3, tube=tb) for tb in (False, True))
    rng = np.random.default_rng(9)
    n = 20000
    x = rng.uniform(0.8e-3, 2.2e-3, n)
    th = rng.uniform(0, 2 * np.pi, n)
    rho = np.sqrt(rng.uniform(0, 1, n)) * r0
    q = np.column_stack([x, rho * np.cos(th), rho * np.sin(th)])
    assert plain.exact_mask(q).mean() > 0.02 and tubes.exact_mask(q).mean() < 0.002
    assert tubes.stats["tube_cells"] > 0
    r, e = tubes.query(q), wall.query(q)
    assert np.abs(r["sdist"] - e["sdist"]).max() < 5e-6 and np.abs(r["sdist"] - (r0 - rho)).max() < 5e-6
    off_axis = rho > 50e-6
    assert _angle(r["normal"], e["normal"])[off_axis].max() < 2.0
    radial = -np.column_stack([0 * x, np.cos(th), np.sin(th)])
    assert _angle(r["normal"], radial)[off_axis].max() < 2.0


def test_a_model_cell_answers_the_least_of_its_models_with_the_normal_of_the_one_that_attains_it() -> None:
    """Two straight round tubes (sigma -1: a lumen's wall seen from within) crossing, and a ridge (sigma +1):
    the answer is the least of their s, the normal the attaining model's; an unused slot ends the list."""
    rec = np.zeros(wf.MODEL_REC + 4)
    o = 4
    rec[o:o + 8] = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0e-3, -1.0]  # tube along x, R = 1 mm
    rec[o + 8:o + 16] = [0.0, 0.5e-3, 0.0, 0.0, 0.0, 1.0, 0.8e-3, -1.0]  # tube along z through y = 0.5 mm
    rec[o + 16:o + 24] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, wf._NO_MODEL]
    for q in ([0.2e-3, 0.1e-3, 0.3e-3], [0.0, 0.9e-3, 0.0], [0.1e-3, -0.6e-3, 0.2e-3]):
        s1 = 1.0e-3 - math.hypot(q[1], q[2])
        s2 = 0.8e-3 - math.hypot(q[0], q[1] - 0.5e-3)
        s, nx, ny, nz, _rho = wf._models(q[0], q[1], q[2], rec, o)
        assert s == pytest.approx(min(s1, s2), abs=1e-15)
        n_true = (np.array([0.0, -q[1], -q[2]]) / math.hypot(q[1], q[2]) if s1 <= s2
                  else np.array([-q[0], 0.5e-3 - q[1], 0.0]) / math.hypot(q[0], q[1] - 0.5e-3))
        np.testing.assert_allclose([nx, ny, nz], n_true, atol=1e-12)
    rec[o + 16:o + 24] = [0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0]  # a crease line along z seen from outside (R = 0)
    s, nx, ny, nz, rho = wf._models(0.3e-4, 0.4e-4, 0.0, rec, o)
    assert s == pytest.approx(0.5e-4, abs=1e-15) and rho == pytest.approx(0.5e-4)
    np.testing.assert_allclose([nx, ny, nz], [0.6, 0.8, 0.0], atol=1e-12)


@pytest.fixture(scope="module")
def y_fast() -> tuple[wf.WallField3D, wf.WallField3D]:
    """The Y refined, without and with model cells and list cells (their lattice coarser than the plant's, for
    speed)."""
    v, t, caps, _n = mw.y_wall()
    wall = mw.Wall3D(v, t, caps, margin_m=1.05e-3 + 3 * H)
    return (wf.build_wall_field3d(wall, h_m=H, refine=2),
            wf.build_wall_field3d(wall, h_m=H, refine=2, tube=True, list_max=64, list_lattice=9, list_sub=2))


def test_model_cells_answer_the_y_s_medial_cells_within_the_standard(y_fast: tuple[wf.WallField3D, wf.WallField3D]) -> None:
    """The Y built with model cells: flagged cells wholly in the lumen answered by the least of a few fitted
    tubes, ridges or planes (some by more than one), fewer left to the exact query; at random points in the
    model cells the lookup is within 5 um of the exact query and within 2 deg of its normal wherever that is
    defined (it does not turn by more than 2 deg within 5 um: off a medial surface)."""
    plain, mod = y_fast
    wall = mod.wall
    assert mod.stats["tube_cells"] > 0 and mod.stats["exact_cells"] < plain.stats["exact_cells"]
    assert mod.stats["model_cells_2"] + mod.stats["model_cells_3"] > 0  # some answered by two or three models
    flags = mod.flags()
    kk, jj, ii = np.nonzero(flags <= -2.0)
    rng = np.random.default_rng(11)
    pick = rng.integers(0, len(kk), 30000)
    q = np.ascontiguousarray(mod.head[:3] + H * (np.column_stack([ii[pick], jj[pick], kk[pick]]) + rng.uniform(0, 1, (len(pick), 3))))
    assert not mod.exact_mask(q).any()
    r, e = mod.query(q), wall.query(q)
    band = e["sdist"] <= 1e-3
    assert band.sum() > 1000
    assert np.abs(r["sdist"] - e["sdist"])[band].max() < 5e-6
    ang = _angle(r["normal"], e["normal"])
    turn = np.zeros(len(q))
    for _ in range(6):
        step = rng.normal(size=q.shape)
        step *= 5e-6 / np.linalg.norm(step, axis=1)[:, None]
        turn = np.maximum(turn, _angle(wall.query(q + step)["normal"], e["normal"]))
    assert ang[band & (turn <= 2.0)].max() < 2.0


def _well_conditioned(wall: mw.Wall3D, q: Array, n: Array, rng: np.random.Generator) -> npt.NDArray[np.bool_]:
    turn = np.zeros(len(q))
    for _ in range(6):
        step = rng.normal(size=q.shape)
        step *= 5e-6 / np.linalg.norm(step, axis=1)[:, None]
        turn = np.maximum(turn, _angle(wall.query(q + step)["normal"], n))
    return turn <= 2.0


def test_the_list_scan_is_the_exact_query_over_the_whole_list() -> None:
    """The list cells' scan over every triangle of the wall (nearest the point first, or not) answers as the
    exact query, bit for bit: the same bounds, closest points and tie rule."""
    v, t, caps, _n = mw.y_wall(h_m=0.3e-3)
    wall = mw.Wall3D(v, t, caps, margin_m=1.0e-3)
    d = wall._args[0]
    n = d.size // mw.STRIDE
    rng = np.random.default_rng(12)
    q = rng.uniform([-4e-3, -2e-3, -1.5e-3], [3e-3, 2e-3, 1.5e-3], size=(300, 3))
    e = mw.query_points3d(np.ascontiguousarray(q), *wall._args, True)
    for order in (np.arange(n), rng.permutation(n)):
        lst = order.astype(np.float32)
        for k in range(len(q)):
            assert wf._scan_list(q[k, 0], q[k, 1], q[k, 2], d, lst, 0, n) == tuple(e[k])


def test_list_cells_answer_as_the_exact_query(y_fast: tuple[wf.WallField3D, wf.WallField3D]) -> None:
    """Exact cells wholly in the lumen whose nearest triangles are few: the lookup scans the cell's list (checked
    at build against the exact query at 1000 points per cell), not the candidate tree; at random points of those
    cells it answers as the exact query bit for bit almost everywhere, and within the standard everywhere."""
    _plain, y = y_fast
    assert y.stats["list_cells"] > y.stats["list_cells_fine"] > 0 and 0 < y.stats["list_mean_len"] <= 64
    nx, ny, nz = y.shape
    rec = y.field.reshape(nz, ny, nx, wf.NODE_STRIDE)[:-1, :-1, :-1]
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


def test_a_list_cells_directory_decodes_beyond_float32s_exact_integers() -> None:
    """A list cell's directory gives its lists' start as hi * 2^20 + lo, each exact in float32, so a start beyond
    2^24 (the synthetic tree's lists reach 2.2 x 10^7) is read exactly; the point's sub-cube picks its list."""
    base = 37 * wf._LIST_BASE + 12345
    assert int(np.float32(base)) != base  # not exact as one float32
    starts = [0, 3, 3, 7, 8, 8, 8, 9, 12]
    o, sub = 10, 2
    fine = np.zeros(30, dtype=np.float32)
    fine[o], fine[o + 1] = divmod(base, wf._LIST_BASE)
    fine[o + 2:o + 2 + len(starts)] = starts
    for c in range(sub ** 3):
        t = [((c >> a) & 1) * 0.5 + 0.25 for a in range(3)]
        assert wf._sub_list(t[0], t[1], t[2], fine, o, sub) == (base + starts[c], starts[c + 1] - starts[c])
    assert wf._sub_list(1.0, 1.0, 1.0, fine, o, sub) == (base + 9, 3)  # the far faces belong to the last sub-cube
    assert wf._sub_list(0.75, 0.0, 0.0, fine, o, sub) == (base + 3, 0)  # an empty list: the exact query answers
