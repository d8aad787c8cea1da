"""`vesselbot run` with a plug-in controller that returns NaN from t = 0.5 s: the coil ramps to zero, and it is said.

The controller (``test/plugins/vesselbot_graph_fault_plugin.py``) steers until 0.5 s, then returns NaN
gradients.  On the recorded bag: every command from 0.5 s on is rejected by the coil driver, the coil state ramps
to zero at the slew limit within |G| / slew (+/- 2 ticks) of 0.5 s and stays at zero, the slew and saturation
limits hold throughout; the controller node counts them (``status:nonfinite``, not ``ok``); the metrics
(summary and ``--metrics-json``) count the rejected commands and name the first; one warning line, exit 1; the
numbers are the ROS-free runner's.  A plug-in whose constructor raises is one line and exit 2, before any node
starts and before any run directory exists.  (It used to hold 36 mT/m for the remaining 1.5 s, exit 0, and
report ``ok``.)
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")

from _runs import REPO, assert_coil_invariants, diagnostics, run_cmd, write_config

PLUGINS = REPO / "test" / "plugins"
KIND = "vesselbot_graph_fault_plugin:FaultAfter"
DT_S = 1e-3
U_SAT = 0.08
SLEW = 2.0  # T/m/s: custom slow slew, so the ramp spans many ticks
T_BAD_S = 0.5
DURATION_S = 1.0
N = int(round(DURATION_S / DT_S))
K_BAD = int(round(T_BAD_S / DT_S))


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(PLUGINS), str(REPO), env.get("PYTHONPATH")]))
    return env


@pytest.fixture(scope="module")
def nan_run(tmp_path_factory):
    from vesselbot_ros.bag.reader import open_bag, read_timeseries

    tmp = tmp_path_factory.mktemp("nan_controller")
    cfg = write_config(tmp, controller={"kind": KIND, "after_s": T_BAD_S, "mode": "nan_gradient"},
                       coil__slew_rate="custom", coil__custom_slew_rate_T_per_m_per_s=SLEW,
                       sim__duration_s=DURATION_S, sim__metrics_after_s=0.1)
    bag = tmp / "bag"
    out = tmp / "metrics.json"
    t0 = time.monotonic()
    p = subprocess.run(run_cmd("--config", str(cfg), "--record-dir", str(bag), "--metrics-json", str(out), "--quiet"),
                       cwd=tmp, capture_output=True, text=True, timeout=300, env=_env())
    assert out.exists(), p.stdout + p.stderr
    info = open_bag(bag)
    assert info.consistent, info.problems
    return {"p": p, "bag": bag, "ts": read_timeseries(info), "json": json.loads(out.read_text()), "cfg": cfg,
            "wall_s": time.monotonic() - t0}


def test_nan_commands_ramp_the_coil_to_zero_at_the_slew_limit_and_it_stays_there(nan_run):
    ts = nan_run["ts"]
    assert_coil_invariants(ts, U_SAT, SLEW, DT_S)  # every tick, finite, |G| <= U_sat, the slew limit through the ramp
    t, g = ts["coil.t_s"], ts["coil.applied"][:, [0, 2]]
    assert len(t) == N
    rejected = ts["coil.rejected"]
    np.testing.assert_array_equal(rejected, t >= T_BAD_S - 1e-9)  # every NaN command, and only those
    g0 = float(np.abs(g[K_BAD - 1]).max())
    assert g0 > 0.005, f"the coil was nearly idle at {T_BAD_S} s ({g0} T/m): the ramp would not be measured"
    zero = np.flatnonzero(np.all(g == 0.0, axis=1) & (t >= T_BAD_S - 1e-9))
    assert zero.size, "the coil never reached zero: it held a stale gradient"
    t_zero = t[zero[0]] - t[K_BAD - 1]
    assert abs(t_zero - g0 / SLEW) <= 2 * DT_S + 1e-9, (t_zero, g0 / SLEW)  # a ramp at the slew limit, not a jump
    np.testing.assert_array_equal(g[zero[0]:], 0.0)  # and it stays at zero
    # within the ramp each tick moves the largest axis by the full slew step towards zero
    ramp = np.abs(g[K_BAD - 1:zero[0] + 1]).max(axis=1)
    np.testing.assert_allclose(np.diff(ramp)[:-1], -SLEW * DT_S, rtol=1e-9, atol=1e-12)
    assert np.all(ts["coil.commanded"][rejected] == 0.0)  # nothing non-finite in the coil's messages


def test_every_nan_command_is_in_the_bag_and_counted_by_both_nodes(nan_run):
    bag, ts = nan_run["bag"], nan_run["ts"]
    cmd = ts["command.u_cmd"]
    t_cmd = ts["command.t_s"]
    assert len(t_cmd) == N  # published, not dropped: the bag holds every command the loop ran on
    np.testing.assert_array_equal(~np.all(np.isfinite(cmd), axis=1), t_cmd >= T_BAD_S - 1e-9)
    ctl = diagnostics(bag, "vesselbot_controller")
    last = ctl[-1][1]
    assert last["status:nonfinite"] == str(N - K_BAD) and last["status:ok"] == str(K_BAD)  # used to say ok N times
    assert last["rejected_commands"] == str(N - K_BAD) and last["first_rejected_command_tick"] == str(K_BAD)
    assert any(level == 1 for _t, _d, level in ctl)  # WARN diagnostics
    drv = diagnostics(bag, "vesselbot_coil_driver")[-1][1]
    assert drv["rejected_commands"] == str(N - K_BAD)


def test_the_run_reports_the_rejections_warns_in_one_line_and_exits_1(nan_run):
    p, m = nan_run["p"], nan_run["json"]["metrics"]
    assert p.returncode == 1, p.stdout + p.stderr
    assert m["rejected_commands"] == N - K_BAD and m["first_rejected_command_s"] == pytest.approx(T_BAD_S, abs=1e-12)
    assert m["status"] == "rejected_commands"
    warnings = [line for line in p.stderr.splitlines() if "warning" in line]
    assert warnings == [f"vesselbot: warning: {N - K_BAD} of {N} controller commands rejected (non-finite) from "
                        f"t = {T_BAD_S:.3f} s; the coil ramped to zero"], p.stderr
    assert f"; rejected commands {N - K_BAD}" in p.stdout, p.stdout  # the one-line result too
    assert "Traceback" not in p.stderr


def test_the_graph_gives_the_runners_numbers(nan_run):
    """Lockstep over ROS is the ROS-free runner bit for bit: the node rejects through the core's coil stage."""
    sys.path.insert(0, str(PLUGINS))
    try:
        from vesselbot_ros.sim.closed_loop import run_closed_loop
        from vesselbot_ros.sim.scenario import load_scenario

        pure = run_closed_loop(load_scenario(str(nan_run["cfg"])))
    finally:
        sys.path.remove(str(PLUGINS))
    ros = nan_run["json"]
    assert pure.metrics["rejected_commands"] == ros["metrics"]["rejected_commands"] == N - K_BAD
    for k, v in pure.metrics.items():
        if isinstance(v, float) and math.isnan(v):
            assert math.isnan(ros["metrics"][k]), k
        else:
            assert ros["metrics"][k] == v, (k, ros["metrics"][k], v)
    for key in ("p_true", "x_hat", "g_applied"):
        assert ros["final"][key] == [float(x) for x in pure.timeseries[key][-1]], key
    np.testing.assert_array_equal(nan_run["ts"]["coil.applied"][:, [0, 2]], pure.timeseries["g_applied"])


def test_a_plugin_whose_constructor_raises_stops_the_run_before_any_node_starts(tmp_path):
    cfg = write_config(tmp_path / "cfg", controller={"kind": "vesselbot_graph_fault_plugin:RaisingCtor"})
    bag = tmp_path / "bag"
    p = subprocess.run(run_cmd("--config", str(cfg), "--record-dir", str(bag), "--quiet"), cwd=tmp_path,
                       capture_output=True, text=True, timeout=120, env=_env())
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1, p.stdout + p.stderr
    assert "vesselbot_graph_fault_plugin:RaisingCtor" in lines[0] and "RuntimeError: no licence for this coil" in lines[0]
    assert not bag.exists() and not (tmp_path / "runs").exists()  # no run directory, no logs: nothing started
    assert "vesselbot run:" not in p.stdout  # the banner is printed when the graph starts


def test_a_controller_that_raises_in_its_step_is_contained_counted_and_named(tmp_path):
    """The plug-in raises from 0.1 s on: the node survives, every such tick is a rejected command (the coil ramps to
    zero), and the warning names the exception, with the runner's numbers (it used to kill the controller node)."""
    cfg = write_config(tmp_path / "cfg", controller={"kind": KIND, "after_s": 0.1, "mode": "raise"},
                       sim__duration_s=0.3, sim__metrics_after_s=0.05)
    out = tmp_path / "m.json"
    p = subprocess.run(run_cmd("--config", str(cfg), "--no-record", "--metrics-json", str(out), "--quiet"),
                       cwd=tmp_path, capture_output=True, text=True, timeout=300, env=_env())
    assert p.returncode == 1, p.stdout + p.stderr
    warnings = [line for line in p.stderr.splitlines() if "warning" in line]
    assert warnings == ["vesselbot: warning: 200 of 300 controller commands rejected (the controller raised; first: "
                        "ZeroDivisionError: the law divided by zero at t = 0.100 s) from t = 0.100 s; "
                        "the coil ramped to zero"], p.stderr
    m = json.loads(out.read_text())
    assert m["metrics"]["rejected_commands"] == 200 and m["final"]["g_applied"] == [0.0, 0.0]
    assert "died" not in p.stderr


SLOW_TICKS = 60


@pytest.fixture(scope="module")
def slow_run(tmp_path_factory):
    """A live controller that stalls once (1.3 s, 0.3 s past --stall-timeout), then answers each of 60 ticks in 40 ms:
    twice the 20 ms the plant grants a tick once commands count as lost."""
    from vesselbot_ros.bag.reader import open_bag, read_timeseries

    tmp = tmp_path_factory.mktemp("slow_controller")
    cfg = write_config(tmp, controller={"kind": KIND, "after_s": T_BAD_S, "mode": "slow", "pause_s": 1.3,
                                        "slow_tick_s": 0.04, "slow_ticks": SLOW_TICKS},
                       sim__duration_s=DURATION_S, sim__metrics_after_s=0.1)
    bag, out = tmp / "bag", tmp / "metrics.json"
    p = subprocess.run(run_cmd("--config", str(cfg), "--record-dir", str(bag), "--metrics-json", str(out), "--quiet",
                               "--stall-timeout", "1.0"),
                       cwd=tmp, capture_output=True, text=True, timeout=300, env=_env())
    assert out.exists(), p.stdout + p.stderr
    info = open_bag(bag)
    assert info.consistent, info.problems
    return {"p": p, "ts": read_timeseries(info), "json": json.loads(out.read_text())}


def test_a_live_but_slow_controller_is_not_locked_out_by_the_watchdog(slow_run):
    """Once the watchdog answered a tick the plant asks after 20 ms; the driver defers those requests while the
    controller still sends commands, so the watchdog answers only while the controller was silent and every tick
    after its slow stretch takes its command (it used to answer every tick of the slow stretch and more: a command
    40 ms late for each)."""
    ts, m, p = slow_run["ts"], slow_run["json"]["metrics"], slow_run["p"]
    assert_coil_invariants(ts, U_SAT, 100.0, DT_S)
    wd_ticks = np.flatnonzero(np.all(ts["coil.commanded"] == 0.0, axis=1) & (ts["coil.t_s"] >= T_BAD_S - 1e-9))
    assert m["watchdog_ticks"] == len(wd_ticks) >= 1  # the pause: the first request after the full stall timeout
    assert m["watchdog_ticks"] < SLOW_TICKS // 2, m
    assert m["deferred_stalls"] >= 1, m
    assert wd_ticks[-1] < K_BAD + SLOW_TICKS + 1  # from the end of the slow stretch on, every tick its command
    assert p.returncode == 1 and "ticks got no valid controller command in time" in p.stderr, p.stderr
