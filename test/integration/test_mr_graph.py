"""`vesselbot run` with the MR imager and the tracker node: the pure runner's numbers bit for bit, the frames in the bag.

The clinical 3 T plan (multiplexed: one MS-SET acquisition per tracking window) flown on MR frames
(``imager.kind mr_images``) over 0.3 s, lockstep, seed 0: once with one process per node (the default),
with the live view on and Foxglove's own client (``tools/js/ws_live.mjs``: @foxglove/ws-protocol and its ROS 2
deserializer) connected, once composed in one process, and once with a user's tracker kind
(``examples/plugin_tracker.py``, by ``module:Class``) in the tracker node.  Each run's metrics equal the ROS-free loop's bit for
bit; the bag holds one ``imager/frame`` per tick (empty between frames) and one ``imager/image`` per frame; every
frame decoded from the bag and tracked again gives the measurement the bag holds for its tick; the magnitude image
is the frame's magnitude; and the client decoded the same images over the Foxglove protocol.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("rclpy")

from _runs import free_port, last_json, node_client
from vesselbot_ros.bag.reader import iter_messages, open_bag
from vesselbot_ros.graph_spec import topic
from vesselbot_ros.imaging.frames import frame_of
from vesselbot_ros.sim.closed_loop import build_stage, run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario

REPO = Path(__file__).resolve().parents[2]
CONFIG = "config/plans/clinical_3t.yaml"
SETS = ("imager.kind=mr_images", "imager.fov_centre_m=[4.0e-3, 0.0, 0.0]")
DURATION_S = 0.3


#: A user's tracker kind (examples/plugin_tracker.py), reaching the tracker node's process through PYTHONPATH.
USER_TRACKER = "tracker.kind=plugin_tracker:CentroidTracker"
EXAMPLES = REPO / "examples"


@pytest.fixture(scope="module")
def pure_runs():  # type: ignore[no-untyped-def]
    sys.path.insert(0, str(EXAMPLES))
    out = {}
    for sets in (SETS, (*SETS, USER_TRACKER)):
        scenario = load_scenario(REPO / CONFIG, duration=DURATION_S, sets=list(sets))
        out[sets[-1]] = scenario, run_closed_loop(scenario, 0)
    return out


@pytest.fixture(scope="module", params=["processes", "single_process", "user_tracker"])
def run(request, tmp_path_factory, pure_runs):  # type: ignore[no-untyped-def]
    tmp = tmp_path_factory.mktemp(f"mr_run_{request.param}")
    bag, metrics = tmp / "bag", tmp / "metrics.json"
    sets = (*SETS, USER_TRACKER) if request.param == "user_tracker" else SETS
    cmd = [sys.executable, "-m", "vesselbot_ros.cli", "run", "--config", CONFIG, "--seed", "0", "--quiet",
           "--duration", str(DURATION_S), "--record-dir", str(bag), "--metrics-json", str(metrics),
           "--wait-timeout", "120", "--run-timeout", "240", *[a for kv in sets for a in ("--set", kv)]]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(EXAMPLES), os.environ.get("PYTHONPATH")])))
    client = None
    if request.param == "single_process":
        cmd += ["--single-process"]
    else:
        port = free_port()
        client = node_client("ws_live.mjs", str(port), "120", "60")
        cmd += ["--live-port", str(port), "--live-rate", "0"]
    try:
        proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=420, env=env)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        got = last_json(client, timeout=120) if client is not None else None
    finally:
        if client is not None and client.poll() is None:
            client.kill()
    return bag, json.loads(metrics.read_text())["metrics"], got, pure_runs[sets[-1]]


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _recorded(bag: Path) -> dict[str, list[Any]]:
    names = {topic(k).name: k for k in ("mr_frame", "mr_image", "measurement")}
    out: dict[str, list[Any]] = {k: [] for k in names.values()}
    for m in iter_messages(open_bag(bag), topics=list(names)):
        out[names[m.topic]].append(m.decode())
    return out


def test_lockstep_metrics_equal_the_pure_runner_bit_for_bit(run) -> None:  # type: ignore[no-untyped-def]
    _bag, m, _got, (_scenario, res) = run
    assert res.metrics["imager_frames"] >= 4
    for k, v in res.metrics.items():
        assert m[k] == v, k  # every metric of the pure runner, the frame counts included: bit for bit


def test_the_bag_holds_every_frame_and_its_measurement(run) -> None:  # type: ignore[no-untyped-def]
    bag, _m, _got, (scenario, res) = run
    rec = _recorded(bag)
    n = scenario.sim.n_ticks
    assert len(rec["mr_frame"]) == n and len(rec["measurement"]) == n  # one per tick, lockstep
    full = [k for k, f in enumerate(rec["mr_frame"]) if f.height > 0]
    assert len(full) == len(rec["mr_image"]) == res.metrics["imager_frames"]
    fresh = np.flatnonzero(np.isfinite(res.timeseries["meas_p"][:, 0]))
    assert list(fresh) == full  # the frames arrive at the ticks the pure runner delivers them
    tracker = build_stage(scenario, "tracker")  # the run's tracker, fresh: it tracks the bag's frames again
    for i, k in enumerate(full):
        f, img = rec["mr_frame"][k], rec["mr_image"][i]
        assert (f.encoding, f.step, img.encoding) == ("64FC2", 16 * f.width, "32FC1")
        samples = np.frombuffer(bytes(f.data), dtype="<c16").reshape(f.height, f.width)
        assert (f.height, f.width) == (3, scenario.imager.imaging.matrix)  # MS-SET: x, y, z projections
        mag = np.frombuffer(bytes(img.data), dtype="<f4").reshape(img.height, img.width)
        assert np.array_equal(mag, np.abs(samples).astype(np.float32)) and _stamp(img) == _stamp(f)
        meas = tracker.track(k * scenario.sim.dt_control_s, frame_of(scenario.imager, samples, _stamp(f) * 1e-9, i))
        point = rec["measurement"][k].point
        assert meas is not None and [point.x, point.z] == list(meas.p) == list(res.timeseries["meas_p"][k])
        assert _stamp(rec["measurement"][k]) == _stamp(f)
    empty = [f for f in rec["mr_frame"] if f.height == 0]
    assert all(_stamp(f) == round(k * scenario.sim.dt_control_s * 1e9)
               for k, f in enumerate(rec["mr_frame"]) if f.height == 0) and len(empty) == n - len(full)


@pytest.mark.parametrize("run", ["processes"], indirect=True)  # the run with the live view
def test_foxglove_decodes_the_images_the_bag_holds(run) -> None:  # type: ignore[no-untyped-def]
    bag, _m, got, _pure = run
    assert got["decode_errors"] == {}, got["decode_errors"]
    name = topic("mr_image").name
    assert {"topic": name, "encoding": "cdr", "schemaName": "sensor_msgs/msg/Image",
            "schemaEncoding": "ros2msg"} in got["advertised"]
    seen = got["images"][name]
    rec = _recorded(bag)["mr_image"]
    assert len(seen) == len(rec) >= 4
    for s, img in zip(seen, rec, strict=True):
        mag = np.frombuffer(bytes(img.data), dtype="<f4").astype(np.float64)
        assert (s["height"], s["width"], s["encoding"], s["n_bytes"]) == (img.height, img.width, "32FC1", len(img.data))
        assert int(s["stamp"]) == _stamp(img)
        assert s["max"] == pytest.approx(float(mag.max()), rel=1e-12)
        assert s["sum"] == pytest.approx(float(mag.sum()), rel=1e-9)
    frames = got["images"][topic("mr_frame").name]  # the complex frames decode too (their magnitudes)
    assert len(frames) == len(rec)


@pytest.mark.parametrize("run", ["single_process"], indirect=True)
def test_the_report_draws_the_last_frame_and_has_the_runs_metrics(run, tmp_path) -> None:  # type: ignore[no-untyped-def]
    from vesselbot_ros.bag.report import MR_FRAME_FIGURE, write_report

    bag, m, _got, _pure = run
    got = write_report(bag, tmp_path / "report")
    assert (tmp_path / "report" / MR_FRAME_FIGURE).stat().st_size > 10_000
    for key in ("tracking_error_max_m", "estimation_error_max_m", "imager_frames", "imager_frames_rejected"):
        assert got[key] == m[key], key  # the bag alone gives the run's metrics and frame counts


@pytest.mark.timeout(400)
def test_a_users_own_tracker_node_in_the_slot_gives_the_pure_runners_numbers(tmp_path, pure_runs) -> None:
    """examples/my_tracker_node.py in the tracker's slot (``--without tracker``), running the default tracker kind."""
    import signal

    from _runs import hostile_env, run_cmd
    from vesselbot_ros.ros_env import allocate_domain_for_peers

    lease = allocate_domain_for_peers()  # held until the run ended: no other test's run can take the id meanwhile
    dom = lease.domain_id
    env = hostile_env(dom, tmp_path / "ros_log")
    params = ["-p", f"config:={CONFIG}", "-p", "set:=[" + ", ".join(f"'{kv}'" for kv in SETS) + "]"]
    user = subprocess.Popen([sys.executable, str(EXAMPLES / "my_tracker_node.py"), "--ros-args", *params], cwd=REPO,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    metrics = tmp_path / "metrics.json"
    try:
        p = subprocess.run(run_cmd("--config", CONFIG, "--seed", "0", "--duration", str(DURATION_S), "--quiet",
                                   "--without", "tracker", "--domain-id", str(dom), "--no-record",
                                   "--metrics-json", str(metrics), "--wait-timeout", "120",
                                   *[a for kv in SETS for a in ("--set", kv)]),
                           cwd=REPO, capture_output=True, text=True, timeout=300)
    finally:
        user.send_signal(signal.SIGINT)
        try:
            user.wait(timeout=20)
        except subprocess.TimeoutExpired:
            user.kill()
        lease.release()
    assert p.returncode == 0, p.stdout + p.stderr
    assert "slot 'tracker' is yours" in p.stdout + p.stderr  # the contract, printed
    m = json.loads(metrics.read_text())["metrics"]
    _scenario, res = pure_runs[SETS[-1]]
    for key in ("tracking_error_max_m", "tracking_error_rms_m", "estimation_error_max_m", "estimation_error_rms_m"):
        assert m[key] == res.metrics[key], key  # the default tracker in the user's node: the same bits
