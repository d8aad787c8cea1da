"""An episode's actions through the simulator: the same bits as the environment, on both paths and from a file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vesselbot_ros.envs.env import VesselbotEnv
from vesselbot_ros.envs.replay import replay
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario


@pytest.mark.parametrize("name", ["sound_small_artery", "clinical_3t_small_artery", "carotid_bifurcation_3d_eca"])
def test_an_episode_replayed_through_the_simulator_gives_its_bits(name: str, tmp_path: Path) -> None:
    sc = load_scenario(name, sets=["sim.duration_s=0.06"])
    env = VesselbotEnv(sc, privileged=True)
    f = dict(env.fields)
    obs = [env.reset(seed=9)[0]]
    actions = np.random.default_rng(1).uniform(-0.08, 0.08, (sc.sim.n_ticks, sc.dims))
    actions[7, 0] = np.nan  # a rejected command replays as one
    for a in actions:
        obs.append(env.step(a)[0])
    o = np.array(obs[:-1])  # the observation at ticks 0 .. n-1 (the last is the tick after the run)
    runs = [replay(sc, 9, actions, path="compiled"), replay(sc, 9, actions, path="per_tick")]
    np.save(tmp_path / "episode.npy", actions)
    from_file = load_scenario(name, sets=["sim.duration_s=0.06", "controller.kind=action_replay",
                                          f"controller.actions_file={tmp_path / 'episode.npy'}"])
    runs.append(run_closed_loop(from_file, 9))  # what `vesselbot simulate --set controller.kind=action_replay` runs
    assert [r.path for r in runs] == ["compiled", "per_tick", "compiled"]
    for r in runs:
        ts = r.timeseries
        for field, col in (("x_hat_m", "x_hat"), ("z_hat_m_per_s", "z_hat"), ("p_true_m", "p_true"),
                           ("v_true_m_per_s", "v_true"), ("p_ref_m", "p_ref")):
            np.testing.assert_array_equal(o[:, f[field]], ts[col], err_msg=field)
        np.testing.assert_array_equal(np.array(obs[1:])[:, f["g_applied_T_per_m"]], ts["g_applied"])
        assert list(np.flatnonzero(ts["cmd_rejected"])) == [7] and r.metrics["rejected_commands"] == 1
    for k in ("p_true", "x_hat", "g_cmd", "u_cmd", "flow_scale_hat", "cmd_status"):
        np.testing.assert_array_equal(runs[0].timeseries[k], runs[1].timeseries[k], err_msg=k)


def test_actions_of_the_wrong_shape_are_refused() -> None:
    sc = load_scenario("sound_small_artery", sets=["sim.duration_s=0.01"])
    with pytest.raises(ModelInputError, match=r"actions: shape \(10, 3\), expected \(ticks, 2\)"):
        replay(sc, 0, np.zeros((10, 3)))
