"""The sampled 3-D wall's model cells (vesselbot_ros.geometry.field_models) against the exact query and analytic tubes."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from vesselbot_ros.geometry.field_build import WallField3D, build_wall_field3d
from vesselbot_ros.geometry.fixtures import cylinder_wall
from vesselbot_ros.geometry.surface_wall import Wall3D

H = 0.2e-3
Array = npt.NDArray[np.float64]


def _angle(a: Array, b: Array) -> Array:
    return np.degrees(np.arccos(np.clip((a * b).sum(axis=1), -1.0, 1.0)))


def test_tube_cells_answer_a_narrow_vessel_s_axis() -> None:
    """A vessel narrower than the band (R = 0.6 mm): near its axis interpolation of the cone s = R - rho fails
    (the cells went to the exact query); with ``tube`` the straight round tube fitted to each such cell answers
    them, within the standard of the exact query (the normal but within 50 um of the axis, where it is undefined)
    and of the analytic tube."""
    r0, h = 0.6e-3, 0.1e-3
    v, t, caps, _n = cylinder_wall(r0, 3e-3, 0.04e-3)
    wall = Wall3D(v, t, caps, margin_m=1.05e-3 + 3 * h)
    plain, tubes = (build_wall_field3d(wall, h_m=h, refine=2, out_band_m=0.1e-3, tube=tb) for tb in (False, True))
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


def test_model_cells_answer_the_y_s_medial_cells_within_the_standard(y_fast: tuple[WallField3D, WallField3D]) -> None:
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
