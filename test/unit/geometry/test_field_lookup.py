"""The sampled 3-D wall's compiled lookup (vesselbot_ros.geometry.field_lookup): models, list scans, directories."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vesselbot_ros.geometry.field_lookup import _LIST_BASE, _NO_MODEL, MODEL_REC, _models, _scan_list, _sub_list
from vesselbot_ros.geometry.fixtures import y_wall
from vesselbot_ros.geometry.surface import STRIDE
from vesselbot_ros.geometry.surface_query import query_points3d
from vesselbot_ros.geometry.surface_wall import Wall3D


def test_a_model_cell_answers_the_least_of_its_models_with_the_normal_of_the_one_that_attains_it() -> None:
    """Two straight round tubes (sigma -1: a lumen's wall seen from within) crossing, and a ridge (sigma +1):
    the answer is the least of their s, the normal the attaining model's; an unused slot ends the list."""
    rec = np.zeros(MODEL_REC + 4)
    o = 4
    rec[o:o + 8] = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0e-3, -1.0]  # tube along x, R = 1 mm
    rec[o + 8:o + 16] = [0.0, 0.5e-3, 0.0, 0.0, 0.0, 1.0, 0.8e-3, -1.0]  # tube along z through y = 0.5 mm
    rec[o + 16:o + 24] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, _NO_MODEL]
    for q in ([0.2e-3, 0.1e-3, 0.3e-3], [0.0, 0.9e-3, 0.0], [0.1e-3, -0.6e-3, 0.2e-3]):
        s1 = 1.0e-3 - math.hypot(q[1], q[2])
        s2 = 0.8e-3 - math.hypot(q[0], q[1] - 0.5e-3)
        s, nx, ny, nz, _rho = _models(q[0], q[1], q[2], rec, o)
        assert s == pytest.approx(min(s1, s2), abs=1e-15)
        n_true = (np.array([0.0, -q[1], -q[2]]) / math.hypot(q[1], q[2]) if s1 <= s2
                  else np.array([-q[0], 0.5e-3 - q[1], 0.0]) / math.hypot(q[0], q[1] - 0.5e-3))
        np.testing.assert_allclose([nx, ny, nz], n_true, atol=1e-12)
    rec[o + 16:o + 24] = [0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0]  # a crease line along z seen from outside (R = 0)
    s, nx, ny, nz, rho = _models(0.3e-4, 0.4e-4, 0.0, rec, o)
    assert s == pytest.approx(0.5e-4, abs=1e-15) and rho == pytest.approx(0.5e-4)
    np.testing.assert_allclose([nx, ny, nz], [0.6, 0.8, 0.0], atol=1e-12)


def test_the_list_scan_is_the_exact_query_over_the_whole_list() -> None:
    """The list cells' scan over every triangle of the wall (nearest the point first, or not) answers as the
    exact query, bit for bit: the same bounds, closest points and tie rule."""
    v, t, caps, _n = y_wall(h_m=0.3e-3)
    wall = Wall3D(v, t, caps, margin_m=1.0e-3)
    d = wall._args[0]
    n = d.size // STRIDE
    rng = np.random.default_rng(12)
    q = rng.uniform([-4e-3, -2e-3, -1.5e-3], [3e-3, 2e-3, 1.5e-3], size=(300, 3))
    e = query_points3d(np.ascontiguousarray(q), *wall._args, True)
    for order in (np.arange(n), rng.permutation(n)):
        lst = order.astype(np.float32)
        for k in range(len(q)):
            assert _scan_list(q[k, 0], q[k, 1], q[k, 2], d, lst, 0, n) == tuple(e[k])


def test_a_list_cells_directory_decodes_beyond_float32s_exact_integers() -> None:
    """A list cell's directory gives its lists' start as hi * 2^20 + lo, each exact in float32, so a start beyond
    2^24 (the synthetic tree's lists reach 2.2 x 10^7) is read exactly; the point's sub-cube picks its list."""
    base = 37 * _LIST_BASE + 12345
    assert int(np.float32(base)) != base  # not exact as one float32
    starts = [0, 3, 3, 7, 8, 8, 8, 9, 12]
    o, sub = 10, 2
    fine = np.zeros(30, dtype=np.float32)
    fine[o], fine[o + 1] = divmod(base, _LIST_BASE)
    fine[o + 2:o + 2 + len(starts)] = starts
    for c in range(sub ** 3):
        t = [((c >> a) & 1) * 0.5 + 0.25 for a in range(3)]
        assert _sub_list(t[0], t[1], t[2], fine, o, sub) == (base + starts[c], starts[c + 1] - starts[c])
    assert _sub_list(1.0, 1.0, 1.0, fine, o, sub) == (base + 9, 3)  # the far faces belong to the last sub-cube
    assert _sub_list(0.75, 0.0, 0.0, fine, o, sub) == (base + 3, 0)  # an empty list: the exact query answers
