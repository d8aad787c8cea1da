"""The Gymnasium environment of one closed loop: an agent commands the gradient coil in the controller's place.

:class:`VesselbotEnv` is the loop of any scenario the compiled loop runs (shipped or a user's file,
:func:`~vesselbot_ros.sim.scenario.load_scenario`), stepped one control tick per :meth:`~VesselbotEnv.step` by
:class:`~vesselbot_ros.envs.copies.LoopCopies` with one copy.  The agent stands where the controller stands in
``vesselbot simulate``: after the observer's update at tick k it sees the observation (the estimate, the reference,
the coil, the scanner's phase: :mod:`vesselbot_ros.envs.copies`), and its action is the tick's gradient command,
which goes through the real coil (saturation, slew, the sequence's gate; a NaN or infinite command is rejected,
ramps the coil to zero and is counted in ``info["rejected_commands"]``); then the plant moves to tick k + 1.

* Action: ``Box(-g_max, g_max, (d,), float64)``, T/m, one per axis of the vessel (d = 2: x, z; d = 3 in a 3-D
  tree), ``g_max`` the coil's saturation.  A command outside it is saturated by the coil as any controller's
  command is (a command of the wrong shape raises :class:`InvalidActionError`).
* Observation: ``Box(-inf, inf, (m,), float64)``, the fields :attr:`VesselbotEnv.fields` names; the true state only
  with ``privileged=True``.
* Reward, termination, truncation: :mod:`vesselbot_ros.envs.copies` (:class:`~vesselbot_ros.envs.copies.RewardParams`).
* Seeding: ``reset(seed=s)`` seeds ``self.np_random`` as Gymnasium does, and the imager draws its noise from it as
  ``vesselbot simulate --seed s`` does (``run_closed_loop(scenario, s)``): an episode's actions replayed through
  the simulator give the same bits (:mod:`vesselbot_ros.envs.replay`).  ``reset()`` without a seed continues the
  stream (the next episode gets new noise).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from vesselbot_ros.errors import ConfigError, ModelInputError
from vesselbot_ros.sim.scenario import Scenario, load_scenario

from .copies import OP_RESET, OP_STEP, LoopCopies, RewardParams

__all__ = ["VesselbotEnv", "InvalidActionError", "scenario_of"]

_FLOAT64 = np.dtype(np.float64)



def loop_spaces(loop: LoopCopies) -> tuple[spaces.Space[npt.NDArray[np.float64]], spaces.Space[npt.NDArray[np.float64]]]:
    """One copy's action space (the gradient command, T/m, within the coil's saturation on each axis) and
    observation space (the layout of :attr:`LoopCopies.fields`), for the scalar and the vector environment."""
    g = loop.g_max_T_per_m
    action: spaces.Space[npt.NDArray[np.float64]] = spaces.Box(-g, g, (loop.dims,), dtype=np.float64)
    observation: spaces.Space[npt.NDArray[np.float64]] = spaces.Box(-np.inf, np.inf, (loop.obs_size,), dtype=np.float64)
    return action, observation

class InvalidActionError(ModelInputError, gymnasium.error.InvalidAction):
    """An action of the wrong shape or type (Gymnasium's ``InvalidAction``; a NaN or an infinity is not one: the coil
    rejects it)."""


def scenario_of(scenario: str | Path | Scenario) -> Scenario:
    """The scenario an environment is built from: a :class:`Scenario`, a shipped scenario's name or a file.

    Raises:
        ConfigError: an unknown name or a bad file, in one line naming it.
    """
    if isinstance(scenario, Scenario):
        return scenario
    if not isinstance(scenario, (str, Path)):
        raise ConfigError(f"scenario must be a shipped scenario's name, a file or a Scenario, got {scenario!r}")
    return load_scenario(scenario)


def _action_of(action: Any, dims: int) -> npt.NDArray[np.float64]:
    """The action as a (dims,) float64 array, or :class:`InvalidActionError`."""
    try:
        a = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidActionError(f"action must be {dims} numbers (T/m), got {action!r}") from None
    if a.shape != (dims,):
        raise InvalidActionError(f"action must have shape ({dims},) (T/m per axis), got shape {a.shape}")
    return a


class VesselbotEnv(gymnasium.Env[npt.NDArray[np.float64], npt.NDArray[np.float64]]):
    """One closed loop of ``scenario`` with the agent's gradient command in the controller's place (module docstring).

    Args:
        scenario: A shipped scenario's name (``vesselbot scenarios``), a scenario file or a :class:`Scenario`.
        privileged: Add the true position and velocity to the observation (a training aid; a real controller never
            sees them).
        reward: The reward's parameters (:class:`~vesselbot_ros.envs.copies.RewardParams`), or a mapping of them.

    Raises:
        ConfigError: an unknown scenario, or one the environment cannot step (a stage kind without a compiled form,
            e.g. ``imager.kind: mr_images``), in one line naming it.
    """

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012 - Gymnasium's base class declares it so

    def __init__(self, scenario: str | Path | Scenario = "sound_small_artery", *, privileged: bool = False,
                 reward: RewardParams | dict[str, Any] | None = None) -> None:
        if isinstance(reward, dict):
            reward = RewardParams(**reward)
        self.scenario = scenario_of(scenario)
        self.loop = LoopCopies(self.scenario, 1, privileged=privileged, reward=reward)
        lp = self.loop
        self.dims = lp.dims
        self.fields = lp.fields
        self.action_space, self.observation_space = loop_spaces(lp)
        self._rng_seen: np.random.Generator | None = None
        self._done = True
        # what step() returns, looked up once: copy 0's observation row (a view: the kernel writes it)
        self._obs_row = lp.obs[0]

    @property
    def tick(self) -> int:
        """The control tick the episode stands at (the observation's)."""
        return int(self.loop.ticks[0])

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[npt.NDArray[np.float64], dict[str, Any]]:
        """A new episode at tick 0 (Gymnasium's rules for ``seed``; ``options`` is not used)."""
        super().reset(seed=seed)
        lp = self.loop
        rng = self.np_random
        if rng is not self._rng_seen:  # a new generator (seeded): its stream from the start
            lp.seed(0, rng)
            self._rng_seen = rng
        lp.ops[0] = OP_RESET
        lp.run()
        lp.ops[0] = OP_STEP  # what every step() of the episode asks
        self._done = False
        return self._obs_row.copy(), {"tick": 0, "rejected_commands": 0}

    def step(self, action: Any) -> tuple[npt.NDArray[np.float64], float, bool, bool, dict[str, Any]]:
        """One control tick under ``action`` (T/m, (d,)): coil, plant, imager, observer."""
        if self._done:
            raise gymnasium.error.ResetNeeded("step() after the episode ended: call reset() first")
        lp = self.loop
        if not (type(action) is np.ndarray and action.dtype is _FLOAT64 and action.ndim == 1):
            # what the compiled entry takes (it checks no type; the length it checks)
            action = _action_of(action, self.dims)
        # ops[0] is OP_STEP (reset() set it): one compiled call copies the action in and steps
        failed, low, reward, terminated, truncated, tick, rejected = lp.step_one(lp.state_ref, action)
        if failed or low:
            if failed < 0:
                _action_of(action, self.dims)  # raises: the wrong length
            lp.settle(failed, low)
        self._done = terminated or truncated
        return self._obs_row.copy(), reward, terminated, truncated, {"tick": tick, "rejected_commands": rejected}
