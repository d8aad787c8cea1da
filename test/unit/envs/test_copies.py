"""N copies of a loop in one call: the observation's layout, the route's goal, copies independent of each other."""

from __future__ import annotations

import numpy as np
import pytest

from vesselbot_ros.envs.copies import OP_RESET, OP_SKIP, OP_STEP, LoopCopies, observation_fields, route_end
from vesselbot_ros.errors import ConfigError
from vesselbot_ros.sim.scenario import load_scenario


def test_the_observation_fields_tile_the_vector_in_order() -> None:
    for d in (2, 3):
        for seq in (False, True):
            for priv in (False, True):
                fields = observation_fields(d, seq, priv)
                at = 0
                for _name, s in fields:
                    assert s.start == at
                    at = s.stop
                assert at == 6 * d + 1 + seq + 2 * d * priv


def test_a_route_ends_at_its_planned_last_anchor_on_its_axes() -> None:
    for name, d in (("paper_iiic_network_lower", 2), ("carotid_bifurcation_3d_eca", 3)):
        sc = load_scenario(name)
        end = route_end(sc)
        assert end.shape == (d,) and np.isfinite(end).all()
        assert np.linalg.norm(end - np.asarray(sc.initial.p0_m)) > 10e-3  # the far end, not the start


def test_a_copy_skipped_or_stepped_leaves_the_others_as_they_were() -> None:
    sc = load_scenario("sound_small_artery", sets=["sim.duration_s=0.02"])
    lp = LoopCopies(sc, 3)
    for i in range(3):
        lp.seed(i, np.random.default_rng(4))  # the same seed: the same bits in every copy
    lp.ops[:] = OP_RESET
    lp.run()
    np.testing.assert_array_equal(lp.obs[0], lp.obs[1])
    lp.actions[:] = [0.02, 0.01]
    lp.ops[:] = [OP_STEP, OP_SKIP, OP_STEP]
    lp.run()
    assert list(lp.ticks) == [1, 0, 1]
    np.testing.assert_array_equal(lp.obs[0], lp.obs[2])
    assert not np.array_equal(lp.obs[0], lp.obs[1])
    lp.ops[:] = [OP_SKIP, OP_STEP, OP_SKIP]
    lp.run()
    np.testing.assert_array_equal(lp.obs[0], lp.obs[1])  # copy 1 caught up: the same tick, the same numbers


def test_bad_counts_are_refused() -> None:
    sc = load_scenario("sound_small_artery", sets=["sim.duration_s=0.01"])
    with pytest.raises(ConfigError, match="copies must be >= 1, got 0"):
        LoopCopies(sc, 0)
    with pytest.raises(ConfigError, match="threads must be >= 1, got 0"):
        LoopCopies(sc, 2, threads=0)
