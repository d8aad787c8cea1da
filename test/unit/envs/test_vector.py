"""The vector environment: N copies in one compiled call, bit for bit the scalar environment, NEXT_STEP autoreset."""

from __future__ import annotations

import functools

import gymnasium
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import vesselbot_ros.envs  # noqa: F401  (registers vesselbot/...)
from vesselbot_ros.envs.env import VesselbotEnv
from vesselbot_ros.envs.vector import VesselbotVectorEnv
from vesselbot_ros.errors import ConfigError
from vesselbot_ros.sim.scenario import Scenario, load_scenario


@functools.cache
def _short(name: str = "sound_small_artery", duration_s: float = 0.03) -> Scenario:
    return load_scenario(name, sets=[f"sim.duration_s={duration_s}"])


def _vector_run(env: VesselbotVectorEnv, seed: int, actions: np.ndarray) -> tuple[np.ndarray, ...]:
    obs = [env.reset(seed=seed)[0]]
    rew, term, trunc = [], [], []
    for a in actions:
        o, r, te, tr, _info = env.step(a)
        obs.append(o)
        rew.append(r)
        term.append(te)
        trunc.append(tr)
    return np.array(obs), np.array(rew), np.array(term), np.array(trunc)


@pytest.mark.parametrize("name,duration_s", [("sound_small_artery", 0.3), ("clinical_3t_small_artery", 0.12),
                                             ("paper_iiic_network_upper_3d", 0.03)])
def test_each_copy_is_the_scalar_env_of_its_seed_bit_for_bit_across_autoresets(name: str, duration_s: float) -> None:
    """Copy i reset with seed s gets seed s + i; its episodes (through NEXT_STEP autoresets, and across refills of its
    block of 256 acquisitions' draws in the 0.3 s run at 1 kHz) are the scalar environment's under the same actions."""
    sc = _short(name, duration_s)
    n, copies = sc.sim.n_ticks, 3
    vec = VesselbotVectorEnv(copies, sc, privileged=True)
    d = vec.dims
    steps = n + 1 + n // 2  # one whole episode, the autoreset step, half of the next
    actions = np.random.default_rng(5).uniform(-0.06, 0.06, (steps, copies, d))
    obs, rew, term, trunc = _vector_run(vec, 11, actions)
    one = VesselbotEnv(sc, privileged=True)
    for i in range(copies):
        got = [one.reset(seed=11 + i)[0]]
        rewards = []
        for j in range(n):
            o, r, te, tr, _info = one.step(actions[j, i])
            got.append(o)
            rewards.append(r)
            assert (te, tr) == (term[j, i], trunc[j, i])
        assert trunc[n - 1, i] and not term[:n, i].any()
        np.testing.assert_array_equal(np.array(got), obs[:n + 1, i])
        np.testing.assert_array_equal(np.array(rewards), rew[:n, i])
        # the next step resets the copy (its action ignored): reward 0, the next episode's first observation
        assert rew[n, i] == 0.0 and not term[n, i] and not trunc[n, i]
        got = [one.reset()[0]]  # no seed: the imager's stream goes on, as the copy's does
        got += [one.step(actions[j, i])[0] for j in range(n + 1, steps)]
        np.testing.assert_array_equal(np.array(got), obs[n + 1:, i])


def test_threads_give_the_same_bits() -> None:
    sc = _short()
    actions = np.random.default_rng(2).uniform(-0.08, 0.08, (40, 5, 2))
    one = _vector_run(VesselbotVectorEnv(5, sc), 3, actions)
    two_env = VesselbotVectorEnv(5, sc, threads=2)
    two = _vector_run(two_env, 3, actions)
    two_env.close()
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a, b)


def test_the_vector_api_spaces_autoreset_mode_and_make_vec() -> None:
    env = gymnasium.make_vec("vesselbot/Straight-v0", num_envs=4, vectorization_mode="vector_entry_point",
                             scenario=_short())
    assert isinstance(env, VesselbotVectorEnv)
    assert env.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert env.action_space.shape == (4, 2) and env.observation_space.shape == (4, env.single_observation_space.shape[0])
    obs, info = env.reset(seed=[1, 2, 3, 4])
    assert obs in env.observation_space and info["rejected_commands"].shape == (4,)
    a = env.action_space.sample()
    a[2, 0] = np.nan
    obs, rew, _term, _trunc, info = env.step(a)
    assert np.isfinite(obs).all() and np.isfinite(rew).all() and list(info["rejected_commands"]) == [0, 0, 1, 0]


def test_bad_input_is_refused() -> None:
    with pytest.raises(ConfigError, match="num_envs must be an integer >= 1, got 0"):
        VesselbotVectorEnv(0, _short())
    env = VesselbotVectorEnv(2, _short())
    with pytest.raises(gymnasium.error.ResetNeeded):
        env.step(np.zeros((2, 2)))
    env.reset(seed=0)
    with pytest.raises(gymnasium.error.InvalidAction, match=r"shape \(2, 2\)"):
        env.step(np.zeros(2))
    with pytest.raises(ConfigError, match="3 seeds for num_envs=2"):
        env.reset(seed=[1, 2, 3])
