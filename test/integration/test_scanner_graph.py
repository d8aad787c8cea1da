"""The scanner in the graph (issue 12): a recorded clinical 3 T run, checked on its bag alone.

One lockstep run of ``config/clinical_3t_small_artery.yaml`` (2 s, seed 0, one process per node) is
recorded.  From the MCAP bag alone (rosbags, :func:`vesselbot_ros.bag.reader.read_timeseries`):

* the sequence-phase topic tiles the run with windows, and no propulsion gradient is applied (the
  coil's output and the plant's input are exactly zero) at any tick outside a propulsion window;
* every fresh measurement is stamped inside a tracking window, at its middle, and delivered at the
  first tick at or after the window's end + the recorded latency; every tracking window whose
  delivery falls inside the run gave exactly one frame;
* at every tick the applied gradient is within the recorded amplitude, slew and dB/dt limits, and
  the recorded dB/dt limit is the IEC normal-mode value of the recorded slew;

and the run equals the ROS-free runner bit for bit.  A user's controller that reads the phase
(``examples/my_scanner_controller.py``) runs in the controller's slot through ``--without``.
"""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("rclpy")

import itertools

from _runs import REPO, assert_coil_invariants, hostile_env, run_cmd
from vesselbot_ros.scanner.sequence import PHASE_CODES

CONFIG = "config/clinical_3t_small_artery.yaml"
DT = 1e-3
N_TICKS = 2000
TRACKING, PROPULSION = PHASE_CODES["tracking"], PHASE_CODES["propulsion"]


@pytest.fixture(scope="module")
def clinical_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("scanner")
    bag, metrics = tmp / "bag", tmp / "metrics.json"
    p = subprocess.run(run_cmd("--config", CONFIG, "--seed", "0", "--record-dir", str(bag), "--metrics-json",
                               str(metrics), "--quiet"), cwd=REPO, capture_output=True, text=True, timeout=400)
    assert p.returncode == 0, p.stdout + p.stderr
    from vesselbot_ros.bag.reader import open_bag, read_timeseries

    info = open_bag(bag)
    assert info.consistent, info.problems
    return info, read_timeseries(info), json.loads(metrics.read_text())


def _windows(ts):
    """(phase, start, end) of every recorded window, in order."""
    return list(zip(ts["phase.phase"].astype(int), ts["phase.window_start_s"], ts["phase.window_end_s"], strict=True))


def _phase_per_tick(ts, t):
    """The recorded phase of each tick time in ``t`` (every tick must lie in exactly one recorded window)."""
    out = np.full(t.size, -1)
    for ph, a, b in _windows(ts):
        sel = (t >= a - 1e-9) & (t < b - 1e-9)
        assert np.all(out[sel] == -1), "recorded windows overlap"
        out[sel] = ph
    assert np.all(out >= 0), f"ticks outside every recorded window: {t[out < 0][:5]}"
    return out


@pytest.mark.timeout(420)
def test_phase_windows_tile_the_run_and_no_gradient_outside_propulsion(clinical_run):
    _info, ts, _ = clinical_run
    w = _windows(ts)
    assert len(w) > 4 * 30  # 2 s of a 54 ms period: 37 periods of 4 windows
    for (_, _, end), (_, start, _) in itertools.pairwise(w):
        assert start == pytest.approx(end, abs=1e-12)  # contiguous
    # each message is stamped at the first tick of its window
    assert np.all(ts["phase.t_s"] >= ts["phase.window_start_s"] - 1e-9)
    assert np.all(ts["phase.t_s"] - ts["phase.window_start_s"] < DT + 1e-9)
    assert set(ts["phase.phase"].astype(int)) == {TRACKING, PHASE_CODES["dead"], PROPULSION}
    t = ts["coil.t_s"]
    assert t.size == N_TICKS
    phase = _phase_per_tick(ts, t)
    off = phase != PROPULSION
    assert np.count_nonzero(phase == TRACKING) > 700
    g = ts["coil.applied"]
    assert np.all(g[off] == 0.0), f"gradient applied outside a propulsion window at t = {t[off & np.any(g != 0, 1)][:5]}"
    # the plant's input, as it recorded it: the gradient over [t_k, t_k+1] is in truth k+1
    g_plant = ts["truth.applied_gradient"][1:]
    assert np.all(g_plant[off[:-1]] == 0.0)
    # the controller did ask for a gradient there: the gate, not the law, made it zero
    assert np.count_nonzero(np.any(ts["command.u_cmd"][off] != 0.0, axis=1)) > 0.5 * np.count_nonzero(off)
    assert np.count_nonzero(np.any(g[~off] != 0.0, axis=1)) > 0.5 * np.count_nonzero(~off)


@pytest.mark.timeout(420)
def test_every_frame_is_acquired_in_a_tracking_window_and_delivered_after_the_latency(clinical_run):
    _, ts, _ = clinical_run
    latency = float(ts["phase.latency_s"][0])
    assert np.all(ts["phase.latency_s"] == latency) and latency == 0.02
    tracking = [(a, b) for ph, a, b in _windows(ts) if ph == TRACKING]
    stamps, fresh = ts["measurement.t_s"], ts["measurement.fresh"]
    assert stamps.size == N_TICKS  # one message per tick (the n-th belongs to tick n)
    valid = stamps > 0.0  # stamp 0 with an empty frame_id: "no frame yet" (the first window's frame is stamped 10 ms)
    ticks = np.flatnonzero(fresh & valid)
    delivered = []
    for k in ticks:
        t_acq = stamps[k]
        hits = [(a, b) for a, b in tracking if a - 1e-9 <= t_acq < b - 1e-9]
        assert len(hits) == 1, f"frame stamped {t_acq} s lies in no tracking window"
        a, b = hits[0]
        assert t_acq == pytest.approx(0.5 * (a + b), abs=1e-12)  # the window's middle (motion-blurred frame)
        due = math.ceil((b + latency) / DT - 1e-9)  # first tick at or after end + latency
        assert k == due, f"frame of window [{a}, {b}) delivered at tick {k}, due at tick {due}"
        delivered.append((a, b))
        # until the next frame the imager repeats this one, unchanged
    expected = [(a, b) for a, b in tracking if math.ceil((b + latency) / DT - 1e-9) < N_TICKS]
    assert delivered == expected  # one frame per tracking window, none lost, none extra
    assert len(delivered) >= 36


@pytest.mark.timeout(420)
def test_amplitude_slew_and_dbdt_limits_hold_at_every_tick(clinical_run):
    from vesselbot_ros.scanner.hardware import DbdtLimit, dbdt_at

    _, ts, _ = clinical_run
    u_sat = float(ts["coil.max_gradient"][0])
    slew = float(ts["coil.slew_rate"][0])
    dbdt_limit, radius = float(ts["coil.dbdt_limit"][0]), float(ts["coil.dbdt_radius"][0])
    for key in ("coil.max_gradient", "coil.slew_rate", "coil.dbdt_limit", "coil.dbdt_radius"):
        assert np.all(ts[key] == ts[key][0]), key
    assert u_sat == 0.045 and radius == 0.2
    # the dB/dt limit binds below the hardware's 200 T/m/s, and the recorded values agree with each other
    assert slew < 200.0
    assert dbdt_limit == pytest.approx(dbdt_at(DbdtLimit("iec_normal_mode", radius), u_sat, slew), rel=1e-12)
    assert_coil_invariants(ts, u_sat, slew, DT)
    g = ts["coil.applied"][:, [0, 2]]
    steps = np.diff(np.vstack([np.zeros((1, 2)), g]), axis=0)
    dbdt = radius * np.hypot(steps[:, 0], steps[:, 1]) / DT  # T/s within radius of the isocentre
    worst = int(np.argmax(dbdt))
    assert dbdt[worst] <= dbdt_limit * (1 + 1e-9), f"dB/dt {dbdt[worst]} T/s > {dbdt_limit} at t = {ts['coil.t_s'][worst]}"
    # at 1 kHz the full 45 mT/m swing fits in one tick (45 T/m/s, below the 103 T/m/s dB/dt slew): the recorded
    # dB/dt reaches 9 T/s of the 29 T/s allowed; the insert's 400 mT/m is where the limit binds
    assert dbdt[worst] == pytest.approx(radius * u_sat / DT, rel=1e-6)


@pytest.mark.timeout(420)
def test_clinical_run_equals_the_pure_runner_bit_for_bit(clinical_run):
    from vesselbot_ros.sim.closed_loop import run_closed_loop
    from vesselbot_ros.sim.scenario import load_scenario

    _, ts, ros = clinical_run
    pure = run_closed_loop(load_scenario(REPO / CONFIG, seed=0))
    assert pure.path == "compiled"  # the scanner's stages run compiled (issue 18); same numbers as per tick
    for key, v in pure.metrics.items():
        w = ros["metrics"][key]
        assert (math.isnan(w) and math.isnan(v)) if isinstance(v, float) and math.isnan(v) else w == v, (key, w, v)
    for key in ("p_true", "x_hat", "g_applied"):
        assert ros["final"][key] == [float(x) for x in pure.timeseries[key][-1]], key
    # and tick by tick, from the bag: the applied gradient, the estimate and the fresh frames
    np.testing.assert_array_equal(ts["coil.applied"][:, [0, 2]], pure.timeseries["g_applied"])
    np.testing.assert_array_equal(ts["estimate.p_hat"][:, [0, 2]], pure.timeseries["x_hat"])
    got = ~np.isnan(pure.timeseries["meas_t_acq_s"])
    # stamps travel as integer ns: compare them as such (the reader's float can differ from t_k in the last bit)
    np.testing.assert_array_equal(np.round(ts["measurement.t_s"][got] * 1e9),
                                  np.round(pure.timeseries["meas_t_acq_s"][got] * 1e9))
    np.testing.assert_array_equal(ts["measurement.p_meas"][got][:, [0, 2]], pure.timeseries["meas_p"][got])
    # the recorded phase is the runner's sequence_phase column
    np.testing.assert_array_equal(_phase_per_tick(ts, ts["coil.t_s"]), pure.timeseries["sequence_phase"])


@pytest.mark.timeout(300)
def test_a_users_controller_reads_the_phase_through_without(tmp_path):
    """examples/my_scanner_controller.py in the controller's slot: it commands zero outside propulsion windows."""
    from vesselbot_ros.bag.reader import open_bag, read_timeseries
    from vesselbot_ros.ros_env import allocate_domain_for_peers

    lease = allocate_domain_for_peers()  # held until the run ended: no other test's run can take the id meanwhile
    dom = lease.domain_id
    env = hostile_env(dom, tmp_path / "ros_log")
    user = subprocess.Popen([sys.executable, str(REPO / "examples" / "my_scanner_controller.py"), "--ros-args", "-p",
                             "use_sim_time:=true"], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    bag = tmp_path / "bag"
    try:
        p = subprocess.run(run_cmd("--config", CONFIG, "--duration", "0.3", "--without", "controller", "--domain-id",
                                   str(dom), "--record-dir", str(bag), "--quiet"),
                           cwd=REPO, capture_output=True, text=True, timeout=240)
    finally:
        user.send_signal(signal.SIGINT)
        user.wait(timeout=20)
        lease.release()
    assert p.returncode == 0, p.stdout + p.stderr
    info = open_bag(bag)
    assert info.consistent, info.problems
    ts = read_timeseries(info)
    t = ts["command.t_s"]
    assert t.size == 300
    np.testing.assert_allclose(t, np.arange(300) * DT, atol=1e-9)
    phase = _phase_per_tick(ts, t)
    cmd = ts["command.u_cmd"]
    assert np.all(cmd[phase != PROPULSION] == 0.0)
    assert np.all(np.any(cmd[phase == PROPULSION] != 0.0, axis=1))
    assert np.count_nonzero(phase == PROPULSION) > 100
