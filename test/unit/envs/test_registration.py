"""The tiers under the vesselbot/ namespace."""

from __future__ import annotations

import gymnasium

from vesselbot_ros.envs.registration import NAMESPACE, STAGE_TIERS, TIERS, register_envs
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


def test_the_image_based_tier_is_registered_on_the_clinical_plan_with_mr_images() -> None:
    register_envs()
    assert set(STAGE_TIERS) == {"MriImages"}
    spec = gymnasium.spec(f"{NAMESPACE}/MriImages-v0")
    assert spec.entry_point == "vesselbot_ros.envs.stage_env:StageEnv"
    assert spec.kwargs["changes"]["imager.kind"] == "mr_images" and spec.kwargs["scenario"].endswith("clinical_3t.yaml")
