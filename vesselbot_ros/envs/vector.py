"""N copies of one closed loop as a Gymnasium vector environment, stepped in one compiled call.

:class:`VesselbotVectorEnv` steps its N copies with one call of
:func:`~vesselbot_ros.envs.copies.env_kernel` per :meth:`~VesselbotVectorEnv.step` (no Python per copy): the same
call, observation, reward and end of an episode as :class:`~vesselbot_ros.envs.env.VesselbotEnv`'s, so copy ``i``
reset with seed ``s + i`` gives, bit for bit, the scalar environment's episode of seed ``s + i`` under the same
actions.

Autoreset follows Gymnasium's default, ``AutoresetMode.NEXT_STEP``: the step after a copy's episode ended resets
that copy (its action is ignored; reward 0, neither terminated nor truncated) and returns its first observation; its
imager's stream goes on (as ``reset()`` without a seed).  ``reset(seed=s)`` seeds copy ``i`` with ``s + i`` (a list
gives each its own, as Gymnasium's vector environments do).  ``info["rejected_commands"]`` counts each copy's rejected
(NaN or infinite) commands in its episode.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import numpy.typing as npt
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from vesselbot_ros.errors import ConfigError
from vesselbot_ros.sim.scenario import Scenario

from .copies import OP_RESET, OP_STEP, LoopCopies, RewardParams
from .env import InvalidActionError, loop_spaces, scenario_of

__all__ = ["VesselbotVectorEnv"]


class VesselbotVectorEnv(VectorEnv[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[Any]]):
    """``num_envs`` copies of ``scenario``'s loop (module docstring); the options of
    :class:`~vesselbot_ros.envs.env.VesselbotEnv`, and ``threads``: threads that step disjoint ranges of the copies
    at once (the same bits on any number).

    Raises:
        ConfigError: ``num_envs`` < 1, or as :class:`~vesselbot_ros.envs.env.VesselbotEnv`.
    """

    metadata: dict[str, Any] = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}  # noqa: RUF012 - Gymnasium's base class declares it so

    def __init__(self, num_envs: int = 1, scenario: str | Path | Scenario = "sound_small_artery", *,
                 privileged: bool = False, reward: RewardParams | dict[str, Any] | None = None,
                 threads: int = 1) -> None:
        if not isinstance(num_envs, (int, np.integer)) or int(num_envs) < 1:
            raise ConfigError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        if isinstance(reward, dict):
            reward = RewardParams(**reward)
        self.scenario = scenario_of(scenario)
        self.num_envs = int(num_envs)
        self.loop = LoopCopies(self.scenario, self.num_envs, privileged=privileged, reward=reward, threads=threads)
        lp = self.loop
        self.dims = lp.dims
        self.fields = lp.fields
        self.single_action_space, self.single_observation_space = loop_spaces(lp)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        self._autoreset = np.zeros(self.num_envs, dtype=np.bool_)
        self._started = False

    def reset(self, *, seed: int | list[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[npt.NDArray[np.float64], dict[str, Any]]:
        """Every copy to tick 0 (``seed``: Gymnasium's vector rules; ``options`` is not used)."""
        n = self.num_envs
        if seed is None:
            seeds: list[int | None] = [None] * n
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = list(seed)
            if len(seeds) != n:
                raise ConfigError(f"reset: {len(seeds)} seeds for num_envs={n}")
        lp = self.loop
        for i, s in enumerate(seeds):
            if s is not None or self._rngs[i] is None:  # a new generator: its stream from the start
                rng, _ = seeding.np_random(s)
                self._rngs[i] = rng
                lp.seed(i, rng)
        lp.ops[:] = OP_RESET
        lp.run()
        self._autoreset[:] = False
        self._started = True
        return lp.obs.copy(), self._info()

    def step(self, actions: Any) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.bool_],
                                          npt.NDArray[np.bool_], dict[str, Any]]:
        """One control tick of every copy under ``actions`` (T/m, (num_envs, d)); copies whose episode ended on the
        last step are reset instead (NEXT_STEP autoreset)."""
        if not self._started:
            raise gymnasium.error.ResetNeeded("step() before reset(): call reset() first")
        lp = self.loop
        try:
            a = np.asarray(actions, dtype=np.float64)
        except (TypeError, ValueError):
            raise InvalidActionError(f"actions must be ({self.num_envs}, {self.dims}) numbers (T/m)") from None
        if a.shape != (self.num_envs, self.dims):
            raise InvalidActionError(f"actions must have shape ({self.num_envs}, {self.dims}) (T/m per copy and axis), "
                                     f"got shape {a.shape}")
        lp.actions[:] = a
        np.copyto(lp.ops, np.where(self._autoreset, OP_RESET, OP_STEP))
        lp.run()
        np.logical_or(lp.terminated, lp.truncated, out=self._autoreset)
        return lp.obs.copy(), lp.reward.copy(), lp.terminated.copy(), lp.truncated.copy(), self._info()

    def close_extras(self, **kwargs: Any) -> None:
        """Stop the stepping threads."""
        self.loop.close()

    def _info(self) -> dict[str, Any]:
        return {"rejected_commands": self.loop.rejected.copy(),
                "_rejected_commands": np.ones(self.num_envs, dtype=np.bool_)}
