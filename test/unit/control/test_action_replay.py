"""The action_replay controller: row k at tick k, the same in its Python stage and its compiled step."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.action_replay import ActionReplayController, load_actions
from vesselbot_ros.sim import kinds
from vesselbot_ros.sim.closed_loop import build_stages, run_stages
from vesselbot_ros.sim.scenario import load_scenario


def test_row_k_at_tick_k_then_zero_as_a_bare_gradient() -> None:
    c = ActionReplayController([[0.01, -0.02], [0.03, 0.04]], 1e-3)
    for k, want in enumerate(([0.01, -0.02], [0.03, 0.04], [0.0, 0.0])):
        cmd = c.command(k * 1e-3, None, None)
        np.testing.assert_array_equal(cmd.gradient_T_per_m, want)
        assert np.isnan(cmd.u_m_per_s2).all() and cmd.status == "ok"
    assert kinds.kind_of("controller", c).name == "action_replay"


def test_its_compiled_step_commands_what_its_python_stage_does() -> None:
    sc = load_scenario("sound_small_artery_ekf", sets=["sim.duration_s=0.05"])
    actions = np.random.default_rng(0).uniform(-0.08, 0.08, (30, 2))  # 30 of 50 ticks: zero after
    runs = [run_stages(sc, build_stages(sc, 1)._replace(controller=ActionReplayController(actions, 1e-3)), 1, path=p)
            for p in ("compiled", "per_tick")]
    assert [r.path for r in runs] == ["compiled", "per_tick"]
    for k, v in runs[0].timeseries.items():
        np.testing.assert_array_equal(v, runs[1].timeseries[k], err_msg=k)
    g = runs[0].timeseries["g_cmd"]
    np.testing.assert_array_equal(g[:30], actions)
    assert not g[30:].any()


def test_a_bad_actions_file_is_refused_naming_the_key(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="controller.actions_file: the action_replay controller needs a .npy file"):
        load_actions("", 2)
    with pytest.raises(ConfigError, match="controller.actions_file: cannot read"):
        load_actions(tmp_path / "none.npy", 2)
    np.save(tmp_path / "a.npy", np.zeros((5, 3)))
    with pytest.raises(ConfigError, match=r"shape \(5, 3\), expected \(ticks, 2\)"):
        load_actions(tmp_path / "a.npy", 2)
