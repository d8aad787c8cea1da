"""Node loss: `vesselbot run` with a node SIGKILLed mid-run (controller, imager, plant), at the same time.

Test config: the sound scenario with ``coil.command_timeout_s`` = 20 ms and a slow custom slew rate
(2 T/m/s, so a ramp from up to U_sat = 80 mT/m to zero takes up to 40 ticks and is measured over many
ticks), ``--stall-timeout 0.5`` s.

* controller or imager killed: the coil driver's lockstep watchdog answers the missing ticks, holds
  the output for ``command_timeout_s`` of sim time and ramps it to zero within the slew limit; the
  run then exits 1 naming the node, and the finalised bag shows the ramp (measured there in sim time).
* plant killed: the plant is the clock; no tick follows, so the driver has nothing to answer and
  simply keeps its last output (it publishes nothing more); the run exits 1 at once naming the plant
  and the bag up to the plant's last tick is intact.
"""

from __future__ import annotations

import os
import re
import signal
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")

from _runs import assert_coil_invariants, node_pid, popen_run, write_config

DT_S = 1e-3
U_SAT = 0.08
SLEW = 2.0  # T/m/s, custom slow slew of the test config
CMD_TIMEOUT_S = 0.02
VICTIMS = ("controller", "imager", "plant")


@pytest.fixture(scope="module")
def killed_runs(tmp_path_factory):
    """Start one run per victim, kill the victim once the run is under way, collect exit code, output, bag."""
    from vesselbot_ros.bag.reader import open_bag, read_timeseries

    tmp = tmp_path_factory.mktemp("node_loss")
    cfg = write_config(tmp, coil__command_timeout_s=CMD_TIMEOUT_S, coil__slew_rate="custom",
                       coil__custom_slew_rate_T_per_m_per_s=SLEW)
    runs = {v: popen_run("--config", str(cfg), "--duration", "5.0", "--stall-timeout", "0.5",
                         "--record-dir", str(tmp / v), cwd=tmp) for v in VICTIMS}
    results = {}
    try:
        for v, p in runs.items():
            deadline = time.monotonic() + 120
            line, t_sim = "", 0.0
            # a progress line past 0.1 s of sim time: every node has answered ticks (a loaded machine may
            # print the first progress line before the controller's first command)
            while time.monotonic() < deadline and t_sim < 0.1:
                line = p.stdout.readline()
                assert line or p.poll() is None, p.stderr.read()
                m = re.search(r"sim\s+([0-9.]+) /", line)
                t_sim = float(m.group(1)) if m else t_sim
            assert t_sim >= 0.1, (v, line)
        for v, p in runs.items():
            os.kill(node_pid(p.pid, v), signal.SIGKILL)
        for v, p in runs.items():
            t0 = time.monotonic()
            _out, err = p.communicate(timeout=120)
            results[v] = {"code": p.returncode, "err": err, "wall_s": time.monotonic() - t0}
    finally:
        for p in runs.values():
            if p.poll() is None:
                p.kill()
    for v in VICTIMS:
        info = open_bag(tmp / v)
        results[v]["info"] = info
        results[v]["ts"] = read_timeseries(info) if info.consistent else None
    return results


def _assert_ramp_to_zero(r, victim):
    assert r["code"] == 1, r["err"]
    assert f"node {victim} died (exit code -9)" in r["err"]
    assert "coil output ramped to zero by the driver's watchdog" in r["err"]
    info = r["info"]
    assert info.consistent, info.problems
    ts = r["ts"]
    assert_coil_invariants(ts, U_SAT, SLEW, DT_S)  # also through the ramp: no tick lost, slew respected
    t, g, wd = ts["coil.t_s"], ts["coil.applied"][:, [0, 2]], ts["coil.watchdog"]
    # the last tick the driver answered with a real command, from its own record: its state's `commanded` is the
    # command it took, zero on a tick its watchdog answered (the controller was steering when it died: no real
    # command is zero there).  The command topic may end a few ticks earlier in the bag: the victim's last samples
    # reach the driver but not a recorder that lags behind under load (a SIGKILLed writer cannot resend them; up
    # to 253 ticks in a clean-clone CI run); the driver's state carries them
    cmd = ts["coil.commanded"]
    last_cmd = int(np.flatnonzero(np.any(cmd != 0.0, axis=1))[-1])
    t_cmd = ts["command.t_s"]
    answered = np.isin(np.round(t / DT_S), np.round(t_cmd / DT_S))
    # the recorded commands end at or before it, or one tick after: SIGKILL can land between the deliveries of
    # the victim's last message to its two subscribers (seen once in a clean-clone CI run: the recorder got
    # tick 669's command, the driver did not and its watchdog answered that tick)
    assert int(np.flatnonzero(answered)[-1]) <= last_cmd + 1
    g0 = np.abs(g[last_cmd]).max()
    assert g0 > 0.005, "the coil was nearly idle when the node died: the ramp would not be measured"
    after = np.arange(last_cmd + 1, len(t))
    # hold for command_timeout_s of sim time (watchdog not yet active), then ramp (watchdog_active)
    # (the tick exactly at command_timeout_s may fall on either side: t_k - t_j is a float difference)
    hold = after[t[after] - t[last_cmd] < CMD_TIMEOUT_S - 1e-9]
    np.testing.assert_array_equal(g[hold], np.repeat(g[last_cmd][None], len(hold), axis=0))
    assert not wd[hold].any()
    zero = after[np.all(g[after] == 0.0, axis=1)]
    assert zero.size, "the output never reached zero"
    t_zero = t[zero[0]] - t[last_cmd]
    bound = CMD_TIMEOUT_S + g0 / SLEW + 2 * DT_S
    assert t_zero <= bound, f"ramp to zero took {t_zero} s of sim time > {bound} s"
    assert t_zero >= CMD_TIMEOUT_S + g0 / SLEW - 2 * DT_S  # and it is a ramp, not a jump
    ramp = after[(t[after] - t[last_cmd] > CMD_TIMEOUT_S + 1e-9) & (t[after] <= t[zero[0]])]
    assert ramp.size >= 5 and wd[ramp].all()
    # no tick of the bag after the death is missing on the other per-tick topics either
    np.testing.assert_allclose(np.diff(ts["truth.t_s"]), DT_S, atol=1e-9)
    if victim == "controller":
        # the message names the sim time of the dead node's last output as its reader got it (the driver's last
        # command), not a progress sample of the plant (it used to name one, up to a second of wall time older)
        k_cmd = int(round(t[last_cmd] / DT_S))
        assert (f"its last message: /vesselbot/gradient_command of tick {k_cmd} (t = {t[last_cmd]:.3f} s), "
                "as vesselbot_coil_driver received it") in r["err"], r["err"]
    return t_zero, bound


@pytest.mark.timeout(300)
def test_controller_killed_driver_ramps_to_zero_within_timeout_and_slew(killed_runs):
    _assert_ramp_to_zero(killed_runs["controller"], "controller")


@pytest.mark.timeout(300)
def test_imager_killed_driver_ramps_to_zero_within_timeout_and_slew(killed_runs):
    _assert_ramp_to_zero(killed_runs["imager"], "imager")


@pytest.mark.timeout(300)
def test_plant_killed_run_exits_naming_the_plant_and_bag_is_intact(killed_runs):
    r = killed_runs["plant"]
    assert r["code"] == 1, r["err"]
    assert "node plant died (exit code -9)" in r["err"]
    info = r["info"]
    assert info.consistent, info.problems
    ts = r["ts"]
    t_truth = ts["truth.t_s"]
    assert len(t_truth) > 10
    np.testing.assert_allclose(np.diff(t_truth), DT_S, atol=1e-9)  # every tick up to the death is there
    # the driver answered ticks the plant announced, never one beyond: with the clock gone it publishes
    # nothing.  The plant's own last messages may be missing from the bag: DDS delivers to each reader
    # separately and a recorder that lags on a loaded machine cannot get them from a SIGKILLed writer (127
    # ticks of `truth` in a clean-clone CI run; docs/faults_and_safety.md).  The witness of what the plant
    # announced is the loop downstream, alive: a tick has an estimate only if the plant's truth reached the
    # imager, and the driver answers a tick only after the controller's command for it.
    assert ts["coil.t_s"][-1] <= ts["estimate.t_s"][-1] + 1e-12
    assert t_truth[-1] <= ts["coil.t_s"][-1] + DT_S + 1e-12  # the bag's truth never runs ahead of the answers
    assert_coil_invariants(ts, U_SAT, SLEW, DT_S)
    assert not ts["coil.watchdog"].any()
    if r["wall_s"] >= 60:  # it ended (within the launcher's own stop bounds); the 60 s is judged on a free machine
        from _machine import QUIET_CPU_SHARE, cpu_share

        share = cpu_share()
        if share < QUIET_CPU_SHARE:
            pytest.skip(f"the run ended {r['wall_s']:.0f} s after the plant died, beyond 60 s, on a loaded machine "
                        f"(a calibration spin got {share:.2f} of a core): cannot judge the 60 s")
        pytest.fail(f"the run ended {r['wall_s']:.0f} s after the plant died, on a free machine (spin {share:.2f})")
