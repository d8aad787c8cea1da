"""The policy controller kind: a callable of the environments' observation, the same numbers in the env and the loop."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.policy import load_policy
from vesselbot_ros.envs.env import VesselbotEnv
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario

POLICY = '''
import numpy as np

def act(obs):
    """PD on the estimate's error, in the layout of vesselbot_ros.control.policy.observation_fields."""
    d = (len(obs) - 1) // 6
    x, z, p, v = obs[0:d], obs[d:2 * d], obs[2 * d + 1:3 * d + 1], obs[3 * d + 1:4 * d + 1]
    g_prev = obs[5 * d + 1:6 * d + 1]
    g = 40.0 * (p - x) + 2.0 * (v - z) + 0.1 * g_prev
    if len(obs) > 6 * d + 1 and obs[6 * d + 1] == 3.0:  # propulsion window: push harder
        g = 1.5 * g
    if obs[2 * d] > 0.5:  # a stale estimate: ask for nothing the coil can take
        g = g * np.nan
    return g
'''


@pytest.fixture
def policy_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    (tmp_path / "vb_test_policy.py").write_text(POLICY)
    monkeypatch.syspath_prepend(str(tmp_path))
    sys.modules.pop("vb_test_policy", None)
    return "vb_test_policy:act"


@pytest.mark.parametrize("name", ["sound_small_artery", "clinical_3t_small_artery", "paper_iiic_network_lower",
                                  "carotid_bifurcation_3d_eca"])
def test_a_policy_runs_as_a_controller_with_its_numbers_in_the_env(name: str, policy_module: str) -> None:
    sc = load_scenario(name, sets=["sim.duration_s=0.08"])
    act = load_policy(policy_module)
    env = VesselbotEnv(sc, privileged=True)
    n_plain = dict(env.fields)["p_true_m"].start  # the observation without the truth
    obs, _ = env.reset(seed=5)
    seen, truth, speed, commands = [], [], [], []
    for _k in range(sc.sim.n_ticks):
        plain = obs[:n_plain]
        seen.append(plain)
        truth.append(obs[dict(env.fields)["p_true_m"]])
        speed.append(obs[dict(env.fields)["v_true_m_per_s"]])
        commands.append(act(plain))
        obs, *_ = env.step(commands[-1])
    as_kind = load_scenario(name, sets=["sim.duration_s=0.08", "controller.kind=policy",
                                        f"controller.policy={policy_module}"])
    run = run_closed_loop(as_kind, 5)
    assert run.path == "per_tick"
    np.testing.assert_array_equal(run.timeseries["p_true"], np.array(truth))
    np.testing.assert_array_equal(run.timeseries["v_true"], np.array(speed))
    f = dict(env.fields)
    np.testing.assert_array_equal(run.timeseries["x_hat"], np.array(seen)[:, f["x_hat_m"]])
    np.testing.assert_array_equal(run.timeseries["z_hat"], np.array(seen)[:, f["z_hat_m_per_s"]])
    np.testing.assert_array_equal(run.timeseries["g_cmd"], np.array(commands))  # the commands, NaN where stale
    np.testing.assert_array_equal(run.timeseries["g_applied"][:-1], np.array(seen)[1:, f["g_applied_T_per_m"]])


def test_a_bad_policy_name_is_refused_naming_the_key() -> None:
    with pytest.raises(ConfigError, match="controller.policy must be 'module:callable', got 'nothing'"):
        load_policy("nothing")
    with pytest.raises(ConfigError, match="controller.policy: module 'no_such_module_43' does not import"):
        load_policy("no_such_module_43:act")
    with pytest.raises(ConfigError, match="controller.policy: module 'numpy' has no callable 'not_there'"):
        load_policy("numpy:not_there")
