"""The task tiers, registered with Gymnasium under the ``vesselbot/`` namespace.

==========================  ===============================  ======================================================
id                          default scenario                 task
==========================  ===============================  ======================================================
``vesselbot/Straight-v0``   ``sound_small_artery``           Section III-C: track the reference in the straight
                                                             pulsing vessel (2 s, 2 axes)
``vesselbot/Network-v0``    ``paper_iiic_network_lower``     follow the planned route through the planar III-C
                                                             network to its lower daughter (2 axes)
``vesselbot/Tree-v0``       ``carotid_bifurcation_3d_eca``   the route through a 3-D carotid bifurcation to the
                                                             external carotid (3 axes)
``vesselbot/MriSequence-v0``  ``clinical_3t_small_artery``   the straight vessel under a multiplexed MRI sequence
                                                             (tracking and propulsion windows, latency, dB/dt);
                                                             the observation carries the scanner's phase
``vesselbot/MriImages-v0``  ``config/plans/clinical_3t``     the clinical 3 T plan with the estimate made from MR
                            with ``imager.kind: mr_images``  images of the bead (MS-SET projections, fitted by the
                                                             tracker stage): per tick in Python
                                                             (:class:`~vesselbot_ros.envs.stage_env.StageEnv`)
==========================  ===============================  ======================================================

Each takes ``scenario=`` (a shipped name, a file or a :class:`~vesselbot_ros.sim.scenario.Scenario`) to run the
task on another vessel, and the options of :class:`~vesselbot_ros.envs.env.VesselbotEnv`.  Each compiled id's vector
form (``gymnasium.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")``) is
:class:`~vesselbot_ros.envs.vector.VesselbotVectorEnv`; the image-based tier's is Gymnasium's own (``sync`` or
``async``: one Python loop per copy).
"""

from __future__ import annotations

from typing import Any

import gymnasium

from vesselbot_ros.sim.scenario import MR_IMAGES_PLAN

__all__ = ["TIERS", "STAGE_TIERS", "NAMESPACE", "register_envs"]

NAMESPACE = "vesselbot"
#: Tier name -> its default scenario (the table above).
TIERS: dict[str, str] = {
    "Straight": "sound_small_artery",
    "Network": "paper_iiic_network_lower",
    "Tree": "carotid_bifurcation_3d_eca",
    "MriSequence": "clinical_3t_small_artery",
}


#: Tier name -> (its default scenario, the overrides it runs it with): the tiers over the per-tick loop (the table).
STAGE_TIERS: dict[str, tuple[str, dict[str, Any]]] = {
    "MriImages": (str(MR_IMAGES_PLAN[0]), MR_IMAGES_PLAN[1]),
}


def register_envs() -> None:
    """Register every tier (``vesselbot/<Tier>-v0``); a second call does nothing."""
    for tier, scenario in TIERS.items():
        env_id = f"{NAMESPACE}/{tier}-v0"
        if env_id in gymnasium.registry:
            continue
        gymnasium.register(id=env_id, entry_point="vesselbot_ros.envs.env:VesselbotEnv",
                           vector_entry_point="vesselbot_ros.envs.vector:VesselbotVectorEnv",
                           kwargs={"scenario": scenario})
    for tier, (scenario, changes) in STAGE_TIERS.items():
        env_id = f"{NAMESPACE}/{tier}-v0"
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point="vesselbot_ros.envs.stage_env:StageEnv",
                               kwargs={"scenario": scenario, "changes": changes})
