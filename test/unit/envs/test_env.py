"""The scalar environment: Gymnasium's checker on every tier, the observation, bad actions, seeding, reward, ends."""

from __future__ import annotations

import functools
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from vesselbot_ros.envs import TIERS
from vesselbot_ros.envs.copies import RewardParams
from vesselbot_ros.envs.env import InvalidActionError, VesselbotEnv
from vesselbot_ros.errors import ConfigError, ModelInputError
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import Scenario, load_scenario


@functools.cache
def _short(name: str = "sound_small_artery", duration_s: float = 0.05) -> Scenario:
    return load_scenario(name, sets=[f"sim.duration_s={duration_s}"])


@pytest.mark.parametrize("tier", sorted(TIERS))
def test_check_env_passes_on_every_registered_tier(tier: str) -> None:
    env = gymnasium.make(f"vesselbot/{tier}-v0")
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*Box observation space (minimum|maximum) value is.*infinity")
        check_env(env.unwrapped)
    inner = env.unwrapped
    assert isinstance(inner, VesselbotEnv) and inner.scenario.name == TIERS[tier]
    assert inner.action_space.shape == (inner.scenario.dims,)
    assert ("sequence_phase" in dict(inner.fields)) == (inner.scenario.sequence.mode == "multiplexed")
    o, _info = env.reset(seed=1)
    assert np.isfinite(o).all()


def test_a_tier_takes_another_scenario_and_refuses_an_unknown_one() -> None:
    env = gymnasium.make("vesselbot/Straight-v0", scenario=_short("sound_small_artery_ekf"))
    assert env.unwrapped.scenario.name == "sound_small_artery_ekf"
    with pytest.raises(ConfigError, match="no_such_vessel"):
        VesselbotEnv("no_such_vessel")
    with pytest.raises(gymnasium.error.NameNotFound):
        gymnasium.make("vesselbot/Nope-v0")


def test_a_scenario_without_a_compiled_form_is_refused_in_one_line_naming_it() -> None:
    sc = load_scenario("config/plans/clinical_3t.yaml",
                       sets=["imager.kind=mr_images", "imager.fov_centre_m=[4.0e-3, 0.0, 0.0]", "sim.duration_s=0.1"])
    with pytest.raises(ConfigError) as err:
        VesselbotEnv(sc)
    msg = str(err.value)
    assert "\n" not in msg and "imager.kind 'mr_images'" in msg and sc.name in msg


def test_the_observation_is_what_a_controller_sees_and_the_truth_only_when_asked() -> None:
    plain, priv = VesselbotEnv(_short()), VesselbotEnv(_short(), privileged=True)
    names = [n for n, _s in plain.fields]
    assert names == ["x_hat_m", "z_hat_m_per_s", "measurement_age_s", "p_ref_m", "v_ref_m_per_s", "a_ref_m_per_s2",
                     "g_applied_T_per_m"]
    assert [n for n, _s in priv.fields] == [*names, "p_true_m", "v_true_m_per_s"]
    a, _ = plain.reset(seed=4)
    b, _ = priv.reset(seed=4)
    np.testing.assert_array_equal(a, b[:a.shape[0]])
    f = dict(priv.fields)
    run = run_closed_loop(_short(), 4)
    np.testing.assert_array_equal(b[f["p_true_m"]], run.timeseries["p_true"][0])
    np.testing.assert_array_equal(b[f["p_ref_m"]], run.timeseries["p_ref"][0])
    np.testing.assert_array_equal(b[f["x_hat_m"]], run.timeseries["x_hat"][0])


@pytest.mark.parametrize("bad", [np.zeros(3), np.zeros((1, 2)), 0.01, "up", [[0.0, 0.0]]])
def test_an_action_of_the_wrong_shape_raises_gymnasiums_invalid_action(bad: object) -> None:
    env = VesselbotEnv(_short())
    env.reset(seed=0)
    with pytest.raises(gymnasium.error.InvalidAction, match=r"shape \(2,\)|2 numbers"):
        env.step(bad)
    assert issubclass(InvalidActionError, ModelInputError)


def test_nan_and_inf_actions_are_rejected_by_the_coil_counted_and_never_make_a_nan_state() -> None:
    env = VesselbotEnv(_short(), privileged=True)
    env.reset(seed=0)
    g = dict(env.fields)["g_applied_T_per_m"]
    o, *_ = env.step(np.array([0.05, 0.05]))
    before = o[g].copy()
    for k, bad in enumerate(([np.nan, 0.0], [np.inf, -np.inf], [0.0, -np.inf])):
        o, r, term, trunc, info = env.step(np.array(bad))
        assert np.isfinite(o).all() and np.isfinite(r) and not (term or trunc)
        assert info["rejected_commands"] == k + 1
        assert np.linalg.norm(o[g]) < np.linalg.norm(before) or not o[g].any()  # to zero at the slew limit
        before = o[g].copy()
    assert not before.any()  # 100 T/m/s: zero within a tick


def test_an_action_is_taken_by_value_whatever_its_layout_or_type() -> None:
    """The step's compiled entry checks no type: a strided view, a list, a tuple and a read-only array give the bits
    of the plain float64 array (the view read with its strides, the others converted first); a float32 array is
    converted and flies."""
    env = VesselbotEnv(_short(), privileged=True)
    actions = np.random.default_rng(1).uniform(-0.08, 0.08, (10, 2))

    def episode(form) -> np.ndarray:  # type: ignore[no-untyped-def]
        env.reset(seed=3)
        return np.array([env.step(form(a))[0] for a in actions])

    plain = episode(lambda a: a.copy())
    wide = np.zeros((10, 4))
    wide[:, ::2] = actions

    def strided(a: np.ndarray) -> np.ndarray:
        i = int(np.flatnonzero((actions == a).all(axis=1))[0])
        return wide[i, ::2]  # a view two doubles apart

    def read_only(a: np.ndarray) -> np.ndarray:
        b = a.copy()
        b.flags.writeable = False
        return b

    for form in (strided, lambda a: list(a), lambda a: tuple(float(v) for v in a), read_only):
        np.testing.assert_array_equal(episode(form), plain)
    assert not np.array_equal(episode(lambda a: a.astype(np.float32)), np.zeros_like(plain))  # converted, flies


def test_the_same_seed_gives_the_same_bits_and_reset_without_a_seed_goes_on() -> None:
    env = VesselbotEnv(_short(), privileged=True)
    actions = np.random.default_rng(0).uniform(-0.08, 0.08, (20, 2))

    def episode(seed: int | None) -> np.ndarray:
        out = [env.reset(seed=seed)[0]]
        out += [env.step(a)[0] for a in actions]
        return np.array(out)

    first = episode(7)
    np.testing.assert_array_equal(episode(7), first)
    assert not np.array_equal(episode(8), first)
    episode(7)
    assert not np.array_equal(episode(None), first)  # the stream goes on: new noise


def test_the_reward_is_the_documented_sum_and_truncation_comes_at_the_duration() -> None:
    rw = RewardParams(error_scale_m=2e-3, energy_weight=0.5)
    env = VesselbotEnv(_short(duration_s=0.01), privileged=True, reward=rw)
    f = dict(env.fields)
    env.reset(seed=0)
    g_max = env.action_space.high[0]
    for k in range(10):
        o, r, term, trunc, info = env.step(np.array([0.03, -0.02]))
        e = np.linalg.norm(o[f["p_true_m"]] - o[f["p_ref_m"]])
        assert r == pytest.approx(-e / 2e-3 - 0.5 * np.sum(o[f["g_applied_T_per_m"]] ** 2) / g_max ** 2, rel=1e-12)
        assert not term and trunc == (k == 9) and info["tick"] == k + 1
    with pytest.raises(gymnasium.error.ResetNeeded):
        env.step(np.zeros(2))


def test_wall_contact_ends_the_episode_when_asked_with_the_lumen_penalty() -> None:
    env = VesselbotEnv(_short(duration_s=0.5), reward=RewardParams(contact_ends_episode=True, energy_weight=0.0))
    env.reset(seed=0)
    for _ in range(500):
        _o, r, term, trunc, _info = env.step(np.array([0.0, 0.08]))  # up, into the wall above
        if term or trunc:
            break
    assert term and not trunc and r < -100.0


def test_reaching_the_route_outlet_ends_the_episode_with_the_bonus() -> None:
    env = VesselbotEnv(_short("paper_iiic_network_lower", 0.05), reward=RewardParams(goal_radius_m=1.0))
    env.reset(seed=0)
    _o, r, term, trunc, _info = env.step(np.zeros(2))
    assert term and not trunc and r > 99.0
    straight = VesselbotEnv(_short(), reward=RewardParams(goal_radius_m=1.0))  # no route: no outlet
    straight.reset(seed=0)
    assert not straight.step(np.zeros(2))[2]


@pytest.mark.parametrize("bad", [{"error_scale_m": 0.0}, {"lumen_penalty": -1.0}, {"goal_radius_m": float("nan")},
                                 {"contact_ends_episode": 1}])
def test_bad_reward_parameters_are_refused_naming_the_key(bad: dict[str, float]) -> None:
    with pytest.raises(ConfigError, match=f"reward\\.{next(iter(bad))}"):
        RewardParams(**bad)
