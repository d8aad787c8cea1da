"""The tiers under the vesselbot/ namespace."""

from __future__ import annotations

import gymnasium

from vesselbot_ros.envs.registration import NAMESPACE, TIERS, register_envs
from vesselbot_ros.sim.scenario import shipped_scenarios


def test_every_tier_is_registered_once_on_a_shipped_scenario_with_its_vector_form() -> None:
    register_envs()
    register_envs()  # a second call does nothing
    assert set(TIERS) == {"Straight", "Network", "Tree", "MriSequence"}
    for tier, scenario in TIERS.items():
        spec = gymnasium.spec(f"{NAMESPACE}/{tier}-v0")
        assert spec.kwargs == {"scenario": scenario} and scenario in shipped_scenarios()
        assert spec.entry_point == "vesselbot_ros.envs.env:VesselbotEnv"
        assert spec.vector_entry_point == "vesselbot_ros.envs.vector:VesselbotVectorEnv"
