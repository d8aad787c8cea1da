"""Gymnasium environments over the compiled closed loop: an agent commands the gradient coil.

Importing this package registers the task tiers under the ``vesselbot/`` namespace
(:mod:`vesselbot_ros.envs.registration`)::

    import gymnasium
    import vesselbot_ros.envs  # noqa: F401  (registers vesselbot/...)

    env = gymnasium.make("vesselbot/Tree-v0", scenario="carotid_bifurcation_3d_eca")
    envs = gymnasium.make_vec("vesselbot/Straight-v0", num_envs=256, vectorization_mode="vector_entry_point")

* :mod:`~vesselbot_ros.envs.copies`: N copies of a scenario's loop stepped in one compiled call; the observation,
  the reward and the end of an episode;
* :mod:`~vesselbot_ros.envs.env`: :class:`~vesselbot_ros.envs.env.VesselbotEnv`, one loop;
* :mod:`~vesselbot_ros.envs.vector`: :class:`~vesselbot_ros.envs.vector.VesselbotVectorEnv`, N loops in one call;
* :mod:`~vesselbot_ros.envs.stage_env`: :class:`~vesselbot_ros.envs.stage_env.StageEnv`, one loop of stages the
  compiled loop cannot run (MR images of the bead and their tracker, a user's Python stage), per tick;
* :mod:`~vesselbot_ros.envs.replay`: an episode's actions through ``run_closed_loop`` (the same bits);
* :mod:`~vesselbot_ros.envs.registration`: the tiers.

The package sits above :mod:`vesselbot_ros.sim` and never imports ROS.
"""

from __future__ import annotations

from vesselbot_ros.envs.registration import STAGE_TIERS, TIERS, register_envs

__all__ = ["TIERS", "STAGE_TIERS", "register_envs"]

register_envs()
