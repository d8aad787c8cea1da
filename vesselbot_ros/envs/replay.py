"""An episode's actions driven through the simulator: ``run_closed_loop``'s loop with the actions as its commands.

The agent of :mod:`vesselbot_ros.envs` stands where the controller stands in the loop, so an episode is replayed by
a controller that commands the episode's actions (:class:`~vesselbot_ros.control.action_replay.ActionReplayController`,
the ``action_replay`` kind) in a run of the same scenario and seed.  :func:`replay` runs it on either path of
:func:`~vesselbot_ros.sim.closed_loop.run_stages` (compiled, or per tick through the stages' methods); the run's
rows at ticks ``0 .. len(actions) - 1`` equal the episode's, bit for bit (``test/unit/envs/test_replay.py``).  From
the command line, save the actions with ``numpy.save`` and run ``vesselbot simulate --seed S --set
controller.kind=action_replay --set controller.actions_file=FILE``.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.action_replay import ActionReplayController
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.sim.closed_loop import SimResult, build_stages, run_stages
from vesselbot_ros.sim.scenario import Scenario

__all__ = ["replay"]


def replay(scenario: Scenario, seed: int, actions: npt.ArrayLike,
           path: Literal["auto", "compiled", "per_tick"] = "auto") -> SimResult:
    """The run of ``scenario`` with seed ``seed`` whose controller commands ``actions`` (T/m, (m, d), row k at tick k;
    zero after the last row), on ``path``.

    Raises:
        ModelInputError: ``actions`` not of shape (m, d) on the scenario's d axes.
    """
    a = np.asarray(actions, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != scenario.dims:
        raise ModelInputError(f"actions: shape {a.shape}, expected (ticks, {scenario.dims}) gradients (T/m)")
    stages = build_stages(scenario, seed)
    controller = ActionReplayController(a, scenario.sim.dt_control_s)
    return run_stages(scenario, stages._replace(controller=controller), seed, path=path)
