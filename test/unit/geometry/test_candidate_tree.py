"""The candidate tree (vesselbot_ros.geometry.candidate_tree): its lists give brute force's answer, bit for bit.

The reference is independent of the module: every triangle (brute force) and the union's inside test of the
analytic Y.
"""

from __future__ import annotations

import numpy as np

from vesselbot_ros.geometry.fixtures import y_solids
from vesselbot_ros.geometry.surface_wall import Wall3D


def test_y_candidates_are_complete_and_the_sign_is_the_unions(y: Wall3D) -> None:
    """Everywhere in the Y's box, junction and crease included: the candidate lists give the answer of brute
    force over every triangle bit for bit, and the sign is the analytic union's (cylinders and the node's ball)
    wherever the point is more than 5 um from every solid's surface."""
    rng = np.random.default_rng(3)
    q = rng.uniform([-5.8e-3, -4.5e-3, -2.0e-3], [4.5e-3, 4.5e-3, 2.0e-3], size=(3000, 3))
    inside, near, beyond = y_solids(q)
    q = np.ascontiguousarray(q[~beyond])
    inside, near = inside[~beyond], near[~beyond]
    for smooth in (False, True):
        a, b = y.query(q, smooth=smooth), y.brute_force(q, smooth=smooth)
        np.testing.assert_array_equal(a["sdist"], b["sdist"])
        np.testing.assert_array_equal(a["normal"], b["normal"])
    s = y.query(q)["sdist"]
    far = near > 5e-6
    assert far.sum() > 2000
    np.testing.assert_array_equal(s[far] > 0, inside[far])


def test_the_lists_do_not_depend_on_the_chunks_they_are_filtered_in(y: Wall3D, monkeypatch) -> None:
    """The filter writes a chunk of cells at a time into bounded room, then compacts it: any chunking (down to
    one cell per chunk) gives the same tree to the bit."""
    from vesselbot_ros.geometry import candidate_tree as ct

    t = y.tree
    args = (y.surface, 1.2e-3, 0.8e-3, 8, 2)
    whole = ct.candidate_tree(*args)
    for room in (97, 5000):
        monkeypatch.setattr(ct, "_FILTER_BUFFER", room)
        small = ct.candidate_tree(*args)
        for name in ("grid", "nodes", "index", "depth"):
            assert np.array_equal(getattr(small, name), getattr(whole, name)), (room, name)
    assert np.array_equal(whole.index, t.index) and np.array_equal(whole.nodes, t.nodes)


def test_a_tree_over_a_box_answers_as_the_whole_tree_inside_it(y: Wall3D) -> None:
    """``box_m`` keeps the roots that meet the box, built from the whole grid's centres: inside the box every
    query gives the whole tree's answer to the bit."""
    from vesselbot_ros.geometry import candidate_tree as ct

    lo, hi = np.array([-2.0e-3, -1.0e-3, -1.0e-3]), np.array([1.0e-3, 2.0e-3, 1.0e-3])
    part = ct.candidate_tree(y.surface, 1.2e-3, 0.8e-3, 8, 2, box_m=(lo, hi))
    assert len(part.nodes) < len(y.tree.nodes)
    q = np.random.default_rng(5).uniform(lo, hi, size=(2000, 3))
    from vesselbot_ros.geometry.surface_query import query_points3d

    s = y.surface
    whole = query_points3d(q, s.data, s.patch_box, s.patch_start, y.tree.grid, y.tree.nodes, y.tree.index, True)
    boxed = query_points3d(q, s.data, s.patch_box, s.patch_start, part.grid, part.nodes, part.index, True)
    np.testing.assert_array_equal(boxed, whole)
