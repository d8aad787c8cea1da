"""The numba warm-up (vesselbot_ros.sim.warm): what it compiles."""

from __future__ import annotations

import numba

from vesselbot_ros.geometry import candidate_tree, field_build, surface, surface_wall
from vesselbot_ros.sim.warm import SCOPES, warm_wall_build

#: Compiled functions of those modules that the wall's build never calls from Python: the lookup's queries and
#: brute force (the tests' reference), and the kernels' inner functions (compiled into their callers, so their
#: own dispatchers keep no signature); every other one is called from Python by the build or its candidate tree.
NOT_BUILD = {"query_points3d", "brute_force3d", "_patch_dist2", "_select", "_cube_centre", "_list_agrees",
             "_nearest_triangle", "_s_at", "_sub_lists", "_ball_diameters", "_ball_radius", "ball_diameters3d"}


def _dispatchers() -> dict[str, numba.core.registry.CPUDispatcher]:
    out = {}
    for mod in (candidate_tree, field_build, surface, surface_wall):
        for name, obj in vars(mod).items():
            if isinstance(obj, numba.core.registry.CPUDispatcher) and obj.__module__ == mod.__name__:
                out[f"{mod.__name__}.{name}"] = obj
    return out


def test_the_wall_builds_warm_up_compiles_every_kernel_the_build_calls() -> None:
    """The shipped trees' fields may already be cached, so the warm-up builds a block of the reference Y: after it,
    every kernel the build calls from Python has a compiled signature of the plant's types (float32 samples), so
    that no later build (a new tree, each subprocess of the cross-kernel build test) compiles it again."""
    warm_wall_build()
    disp = _dispatchers()
    assert len(disp) > 15
    missing = sorted(k for k, d in disp.items() if k.rsplit(".", 1)[1] not in NOT_BUILD and not d.signatures)
    assert not missing, f"not compiled by the warm-up: {missing}"
    types = {str(t) for sig in disp["vesselbot_ros.geometry.field_build._sample_nodes"].signatures for t in sig}
    assert "array(float32, 1d, C)" in types, types
    assert "trees" in SCOPES and "all" in SCOPES
