"""The Gymnasium environment of a loop the compiled loop cannot run: MR images of the bead and their tracker.

:class:`StageEnv` is :class:`~vesselbot_ros.envs.env.VesselbotEnv`'s task (the same observation, action, reward,
termination and truncation: :mod:`vesselbot_ros.envs.copies`) over the per-tick loop of the stages' methods
(:func:`~vesselbot_ros.sim.closed_loop.per_tick_ticks`, the loop ``vesselbot simulate`` runs for such a scenario),
one tick per :meth:`~StageEnv.step`.  It takes any scenario, and is the image-based tier
(``vesselbot/MriImages-v0``): with ``imager.kind: mr_images`` the imager synthesises each MR acquisition of the bead
and the tracker stage fits it (docs/imaging.md), so the estimate the agent sees comes from images, with the
tracker's own errors and rejected frames.  A user's Python stage (``tracker.kind: my_module:MyTracker``) runs in it
the same way.

It is Python per tick (each frame synthesised and fitted): for training on positions, the compiled
:class:`~vesselbot_ros.envs.env.VesselbotEnv` is orders of magnitude faster.

Seeding: ``reset(seed=s)`` builds the episode's stages with seed ``s``, as ``vesselbot simulate --seed s`` does, so
the episode's actions replayed through the simulator (:func:`~vesselbot_ros.envs.replay.replay` with
``path="per_tick"``, or ``vesselbot simulate --set controller.kind=action_replay``) give the same bits.  A
``reset()`` without a seed draws the episode's seed from ``self.np_random``; ``info["episode_seed"]`` says which.
"""

from __future__ import annotations

import math
from collections.abc import Generator
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from vesselbot_ros.control.backstepping import ControlCommand
from vesselbot_ros.control.policy import AGE_CAP_S, observation_fields
from vesselbot_ros.scanner.actuator_limits import coil_params
from vesselbot_ros.scanner.hardware import effective_coil_limits
from vesselbot_ros.scanner.sequence import phase_codes, sequence_vector
from vesselbot_ros.sim import kinds
from vesselbot_ros.sim.closed_loop import Tick, build_stages, per_tick_ticks
from vesselbot_ros.sim.scenario import Scenario, scenario_with

from .copies import RewardParams, route_end
from .env import _action_of, scenario_of

__all__ = ["StageEnv"]


class _Command:
    """The agent's action as the controller's command (the per-tick loop checks it as it checks a controller's:
    :func:`~vesselbot_ros.sim.kinds.checked_command`)."""

    def __init__(self) -> None:
        self.action = np.zeros(0)

    def command(self, t_s: float, estimate: Any, ref: Any) -> ControlCommand:
        return ControlCommand(self.action.copy(), np.full(self.action.shape[0], np.nan), "ok")  # as action_replay's


class StageEnv(gymnasium.Env[npt.NDArray[np.float64], npt.NDArray[np.float64]]):
    """The task of :class:`~vesselbot_ros.envs.env.VesselbotEnv` over the per-tick loop (module docstring).

    Args:
        scenario: A shipped scenario's name, a scenario file or a :class:`Scenario`.
        changes: Dotted-key overrides of the scenario (``{"imager.kind": "mr_images"}``), as ``--set`` takes them.
        privileged: Add the true position and velocity to the observation.
        reward: The reward's parameters (:class:`~vesselbot_ros.envs.copies.RewardParams`), or a mapping of them.

    Raises:
        ConfigError: an unknown scenario, a bad override or reward, in one line naming it.
    """

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012 - Gymnasium's base class declares it so

    def __init__(self, scenario: str | Path | Scenario = "clinical_3t_small_artery", *,
                 changes: dict[str, Any] | None = None, privileged: bool = False,
                 reward: RewardParams | dict[str, Any] | None = None) -> None:
        if isinstance(reward, dict):
            reward = RewardParams(**reward)
        sc = scenario_of(scenario)
        self.scenario = scenario_with(sc, changes) if changes else sc
        sc = self.scenario
        self.dims = d = sc.dims
        self.privileged = bool(privileged)
        self.reward_params = reward if reward is not None else RewardParams()
        self._rw = self.reward_params.vector()
        self.n_steps = sc.sim.n_ticks
        self.sequenced = sc.sequence.mode != "continuous"
        self.fields = observation_fields(d, self.sequenced, self.privileged)
        self.obs_size = self.fields[-1][1].stop
        self.g_max_T_per_m = float(coil_params(effective_coil_limits(sc.coil, sc.dbdt, axes=d))[0])
        g = self.g_max_T_per_m
        self.action_space: spaces.Space[npt.NDArray[np.float64]] = spaces.Box(-g, g, (d,), dtype=np.float64)
        self.observation_space: spaces.Space[npt.NDArray[np.float64]] = spaces.Box(-np.inf, np.inf, (self.obs_size,),
                                                                                    dtype=np.float64)
        ts = np.arange(self.n_steps + 1) * sc.sim.dt_control_s
        self._phase = (phase_codes(sequence_vector(sc.sequence), ts).astype(np.float64) if self.sequenced
                       else np.zeros(0))
        self._goal = route_end(sc) if getattr(sc.reference, "route_outlet", "") else None
        self._radius = float(sc.physics.robot.radius_m)
        self._command = _Command()
        self._ticks: Generator[Tick, tuple[Any, int], Any] | None = None
        self._tick: Tick | None = None
        self._rejected = 0
        self._episode_seed = 0

    @property
    def tick(self) -> int:
        """The control tick the episode stands at (the observation's)."""
        return 0 if self._tick is None else self._tick.k

    def _observation(self, tick: Tick) -> npt.NDArray[np.float64]:
        est = tick.estimate
        parts = [np.asarray(est.x_hat, dtype=np.float64), np.asarray(est.z_hat, dtype=np.float64),
                 [min(float(est.time_since_measurement_s), AGE_CAP_S)], tick.p_ref, tick.v_ref, tick.a_ref,
                 tick.g_applied]
        if self.sequenced:
            parts.append([self._phase[tick.k]])
        if self.privileged:
            parts += [tick.truth.p, tick.truth.v]
        obs = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1) for p in parts])
        assert obs.shape == (self.obs_size,)
        return obs

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[npt.NDArray[np.float64], dict[str, Any]]:
        """A new episode at tick 0: its stages built with ``seed`` (else a seed drawn from ``np_random``)."""
        super().reset(seed=seed)
        self._episode_seed = int(seed) if seed is not None else int(self.np_random.integers(2**31 - 1))
        stages = build_stages(self.scenario, self._episode_seed)
        # the agent stands in the controller's place (one tick more than the run: the observation after the last step)
        self._ticks = per_tick_ticks(self.scenario, stages._replace(controller=self._command), self.n_steps + 1)
        self._tick = next(self._ticks)
        self._rejected = 0
        return self._observation(self._tick), {"tick": 0, "rejected_commands": 0, "episode_seed": self._episode_seed}

    def step(self, action: Any) -> tuple[npt.NDArray[np.float64], float, bool, bool, dict[str, Any]]:
        """One control tick under ``action`` (T/m, (d,)): coil, plant, imager (and tracker), observer."""
        if self._ticks is None or self._tick is None:
            raise gymnasium.error.ResetNeeded("step() after the episode ended: call reset() first")
        a = _action_of(action, self.dims)
        tick = self._tick
        est = tick.estimate
        self._command.action = a
        cmd, why, _detail = kinds.checked_command(self._command, tick.t_s, est.x_hat, est.z_hat,
                                                  est.time_since_measurement_s, getattr(est, "flow_scale", 1.0),
                                                  tick.p_ref, tick.v_ref, tick.a_ref, self.dims)
        if why:
            self._rejected += 1
        nxt = self._tick = self._ticks.send((cmd, why))
        rw, g_max = self._rw, self.g_max_T_per_m
        e2 = g2 = r2 = 0.0
        for c in range(self.dims):
            e = float(nxt.truth.p[c]) - float(nxt.p_ref[c])
            e2 += e * e
            g2 += float(nxt.g_applied[c]) * float(nxt.g_applied[c])
            if self._goal is not None:
                q = float(nxt.truth.p[c]) - float(self._goal[c])
                r2 += q * q
        delta = float(nxt.truth.delta_m)
        outside = delta > self._radius or (rw[5] > 0.5 and delta > 0.0)
        reached = self._goal is not None and math.sqrt(r2) <= rw[4]
        reward = -math.sqrt(e2) / rw[0] - rw[1] * g2 / (g_max * g_max)
        if outside:
            reward -= rw[2]
        elif reached:
            reward += rw[3]
        terminated = bool(outside or reached)
        truncated = nxt.k >= self.n_steps and not terminated
        obs = self._observation(nxt)
        if terminated or truncated:
            self._ticks.close()
            self._ticks = None
        return obs, float(reward), terminated, bool(truncated), {"tick": nxt.k, "rejected_commands": self._rejected}
