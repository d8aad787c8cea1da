"""The environments' benchmark: its rows are the runner's runs, summarised as the module says."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from vesselbot_ros.analysis.benchmark import (
    BenchmarkRow,
    benchmark,
    format_table,
    markdown_table,
    parse_seeds,
    run_summary,
    tier_scenario,
)
from vesselbot_ros.envs.copies import route_end
from vesselbot_ros.errors import ConfigError
from vesselbot_ros.sim.closed_loop import SimResult, run_closed_loop

SHORT = ["sim.duration_s=0.1"]

POLICY = '''
def act(obs):
    d = (len(obs) - 1) // 6
    return 40.0 * (obs[2 * d + 1:3 * d + 1] - obs[0:d]) + 2.0 * (obs[3 * d + 1:4 * d + 1] - obs[d:2 * d])
'''


@pytest.fixture
def policy_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    (tmp_path / "vb_bench_policy.py").write_text(POLICY)
    monkeypatch.syspath_prepend(str(tmp_path))
    sys.modules.pop("vb_bench_policy", None)
    return "vb_bench_policy:act"


def test_seeds_are_ranges_and_lists() -> None:
    assert parse_seeds("0-4") == [0, 1, 2, 3, 4]
    assert parse_seeds("3") == [3]
    assert parse_seeds("0-2, 9") == [0, 1, 2, 9]
    for bad in ("", "x", "-1", "1-", "4-2", "1,1", "0.5", "0-99999"):
        with pytest.raises(ConfigError, match="--seeds"):
            parse_seeds(bad)


def test_each_controller_is_its_tiers_loop(policy_module: str) -> None:
    assert tier_scenario("Straight", "law24").controller.kind == "backstepping"
    assert tier_scenario("Straight", "ekf").name == "sound_small_artery_ekf"
    assert tier_scenario("Tree", "predictive").controller.kind == "predictive"
    assert tier_scenario("MriSequence", "ekf") is None  # no clinical_3t_small_artery_ekf is shipped
    sc = tier_scenario("Network", "policy", policy_module)
    assert sc.controller.kind == "policy" and sc.controller.policy == policy_module
    with pytest.raises(ConfigError, match="unknown tier 'Nope'; the tiers are Straight, Network, Tree, MriSequence"):
        tier_scenario("Nope", "law24")
    with pytest.raises(ConfigError, match="unknown controller 'pid'"):
        tier_scenario("Straight", "pid")
    with pytest.raises(ConfigError, match="controller.policy: module 'vb_no_such_module' does not import"):
        tier_scenario("Straight", "policy", "vb_no_such_module:act")


def _fake(scenario, p_true, p_ref, delta_m, g, status="ok"):  # type: ignore[no-untyped-def]
    n = len(p_true)
    ts = {"t_s": np.arange(n) * scenario.sim.dt_control_s, "p_true": np.array(p_true, dtype=float),
          "p_ref": np.array(p_ref, dtype=float), "delta_m": np.array(delta_m, dtype=float),
          "g_applied": np.array(g, dtype=float)}
    e = np.linalg.norm(ts["p_true"] - ts["p_ref"], axis=1)
    return SimResult(ts, {"after_s": 0.0, "tracking_error_max_m": float(e.max()), "status": status})


def test_a_runs_summary_follows_the_definitions() -> None:
    sc = tier_scenario("Straight", "law24", sets=SHORT)
    r = sc.physics.robot.radius_m
    dt = sc.sim.dt_control_s
    ref = [[0.0, 0.0]] * 4
    run = _fake(sc, [[0.0, 0.0], [1e-4, 0.0], [0.0, 2e-4], [0.0, 0.0]], ref, [0.0, 2 * r, 0.5 * r, 0.0],
                [[0.1, 0.0], [0.0, 0.2], [0.0, 0.0], [0.1, 0.1]])
    s = run_summary(sc, run)
    assert s["outside_lumen_s"] == dt  # one tick beyond the robot's radius
    assert s["energy_T2s_per_m2"] == pytest.approx((0.01 + 0.04 + 0.02) * dt, rel=1e-12)
    assert s["tracking_mean_m"] == pytest.approx(0.75e-4) and s["tracking_max_m"] == 2e-4
    assert not s["success"]  # it left the lumen
    inside = _fake(sc, [[0.0, 0.0]] * 4, ref, [0.0] * 4, [[0.0, 0.0]] * 4)
    assert run_summary(sc, inside)["success"]
    assert not run_summary(sc, _fake(sc, [[0.0, 0.0]] * 4, ref, [0.0] * 4, [[0.0, 0.0]] * 4, "diverged"))["success"]
    far = _fake(sc, [[0.0, 0.0]] * 3 + [[1e-3, 0.0]], ref, [0.0] * 4, [[0.0, 0.0]] * 4)
    assert not run_summary(sc, far)["success"]  # ends farther than goal_radius_m from the path's end


def test_on_a_route_success_is_the_outlet_reached_before_leaving_the_lumen() -> None:
    sc = tier_scenario("Network", "law24", sets=SHORT)
    end = route_end(sc)
    r = sc.physics.robot.radius_m
    z = [0.0, 0.0]
    reached_then_out = _fake(sc, [z, list(end), list(end)], [z] * 3, [0.0, 0.0, 2 * r], [z] * 3)
    assert run_summary(sc, reached_then_out)["success"]
    out_then_reached = _fake(sc, [z, z, list(end)], [z] * 3, [0.0, 2 * r, 0.0], [z] * 3)
    assert not run_summary(sc, out_then_reached)["success"]


def test_the_rows_are_the_runners_runs(policy_module: str) -> None:
    rows, notes = benchmark(["Straight", "MriSequence"], ["law24", "ekf", "policy"], [0, 2], policy=policy_module,
                            sets=SHORT, workers=1)
    assert [(r.tier, r.controller) for r in rows] == [
        ("Straight", "law24"), ("Straight", "ekf"), ("Straight", f"policy {policy_module}"),
        ("MriSequence", "law24"), ("MriSequence", f"policy {policy_module}")]
    assert notes == ["MriSequence: no ekf loop (no shipped clinical_3t_small_artery_ekf scenario)"]
    for row in rows:
        ctrl = "policy" if row.controller.startswith("policy") else row.controller
        sc = tier_scenario(row.tier, ctrl, policy_module, SHORT)
        runs = [run_closed_loop(sc, s) for s in (0, 2)]
        sums = [run_summary(sc, x) for x in runs]
        assert row.seeds == 2 and row.scenario == sc.name
        assert row.tracking_worst_m == max(x.metrics["tracking_error_max_m"] for x in runs)
        assert row.tracking_mean_m == np.mean([s["tracking_mean_m"] for s in sums])
        assert row.energy_T2s_per_m2 == np.mean([s["energy_T2s_per_m2"] for s in sums])
        assert row.success == sum(s["success"] for s in sums) / 2
    assert rows[2].scenario == "sound_small_artery"
    text = format_table(rows)
    assert text.splitlines()[0].split()[:2] == ["tier", "controller"] and len(text.splitlines()) == 6
    assert markdown_table(rows).count("\n") == 7


def test_no_seeds_is_refused() -> None:
    with pytest.raises(ConfigError, match="no seed"):
        benchmark(["Straight"], ["law24"], [])


def test_a_row_is_a_plain_record() -> None:
    row = BenchmarkRow("Straight", "law24", "sound_small_artery", 5, 0.4, 1e-5, 2e-5, 0.0, 1e-3, 0)
    assert "40 %" in format_table([row]) and "| 10.0 | 20.0 |" in markdown_table([row])
