"""The per-tick environment (vesselbot_ros.envs.stage_env): the image-based tier, the compiled tiers' task to the bit."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import vesselbot_ros.envs  # noqa: F401  (registers vesselbot/...)
from vesselbot_ros.envs.env import InvalidActionError, VesselbotEnv
from vesselbot_ros.envs.registration import STAGE_TIERS
from vesselbot_ros.envs.replay import replay
from vesselbot_ros.envs.stage_env import StageEnv
from vesselbot_ros.sim.scenario import load_scenario, scenario_with

TIER_SCENARIO, TIER_CHANGES = STAGE_TIERS["MriImages"]


def _images(duration_s: float) -> StageEnv:
    return StageEnv(TIER_SCENARIO, changes={**TIER_CHANGES, "sim.duration_s": duration_s}, privileged=True)


def test_the_image_based_tier_passes_gymnasiums_checker_and_sees_images_through_its_tracker() -> None:
    env = gymnasium.make("vesselbot/MriImages-v0")
    assert isinstance(env.unwrapped, StageEnv)
    assert env.unwrapped.scenario.imager.kind == "mr_images"
    check_env(env.unwrapped, skip_render_check=True)
    short = _images(0.12)
    obs, info = short.reset(seed=2)
    f = dict(short.fields)
    ages = [obs[f["measurement_age_s"]][0]]
    done = False
    while not done:
        obs, _r, term, trunc, info = short.step(np.zeros(short.dims))
        ages.append(obs[f["measurement_age_s"]][0])
        done = term or trunc
    assert trunc and info["tick"] == short.n_steps
    # the estimate is corrected by tracked frames: its measurement's age falls back at each delivered frame
    assert min(ages[1:]) < 0.05 and np.count_nonzero(np.diff(ages) < 0) >= 2


def test_an_image_based_episode_replayed_through_the_simulator_gives_its_bits() -> None:
    env = _images(0.1)
    f = dict(env.fields)
    obs = [env.reset(seed=5)[0]]
    actions = np.random.default_rng(3).uniform(-0.02, 0.02, (env.n_steps, env.dims))
    actions[11] = [np.inf, 0.0, 0.0][: env.dims]  # a rejected command: the coil ramps to zero, counted
    for a in actions:
        o, _r, _term, _trunc, info = env.step(a)
        obs.append(o)
    assert info["rejected_commands"] == 1
    o = np.array(obs[:-1])
    run = replay(env.scenario, 5, actions, path="per_tick")
    ts = run.timeseries
    for field, col in (("x_hat_m", "x_hat"), ("z_hat_m_per_s", "z_hat"), ("p_true_m", "p_true"),
                       ("v_true_m_per_s", "v_true"), ("p_ref_m", "p_ref")):
        np.testing.assert_array_equal(o[:, f[field]], ts[col], err_msg=field)
    np.testing.assert_array_equal(np.array(obs[1:])[:, f["g_applied_T_per_m"]], ts["g_applied"])
    assert np.isfinite(o).all() and list(np.flatnonzero(ts["cmd_rejected"])) == [11]
    assert run.metrics["imager_frames"] >= 2


@pytest.mark.parametrize("name", ["sound_small_artery", "clinical_3t_small_artery"])
def test_on_a_compiled_scenario_it_is_the_compiled_environment_to_the_bit(name: str) -> None:
    """The same task (observation, reward, ends) over the per-tick loop as over the compiled one."""
    sc = scenario_with(load_scenario(name), {"sim.duration_s": 0.05})
    a, b = StageEnv(sc, privileged=True), VesselbotEnv(sc, privileged=True)
    assert a.fields == b.fields and a.action_space == b.action_space
    oa, ob = a.reset(seed=4)[0], b.reset(seed=4)[0]
    np.testing.assert_array_equal(oa, ob)
    rng = np.random.default_rng(0)
    for _ in range(sc.sim.n_ticks):
        act = rng.uniform(-0.1, 0.1, sc.dims)
        ra, rb = a.step(act), b.step(act)
        np.testing.assert_array_equal(ra[0], rb[0])
        assert ra[1:4] == rb[1:4] and ra[4]["rejected_commands"] == rb[4]["rejected_commands"]
    assert ra[3]


def test_bad_actions_and_steps_after_the_end() -> None:
    env = StageEnv("sound_small_artery", changes={"sim.duration_s": 0.003})
    env.reset(seed=0)
    with pytest.raises(InvalidActionError, match="shape"):
        env.step(np.zeros(3))
    obs, *_ = env.step([np.nan, 0.0])
    assert np.isfinite(obs).all()
    for _ in range(2):
        *_, trunc, info = env.step([0.0, 0.0])
    assert trunc and info["rejected_commands"] == 1
    with pytest.raises(gymnasium.error.ResetNeeded):
        env.step([0.0, 0.0])
    _obs, info = env.reset()  # no seed: one drawn from np_random, said
    assert isinstance(info["episode_seed"], int)
