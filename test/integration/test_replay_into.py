"""`vesselbot replay DIR --into observer|controller`: a fresh node fed from a real run's bag reproduces it.

One short lockstep run (0.3 s, seed 5) of the paper scenario with a 250 Hz
imager, 2 ms latency and an outlier burst at 0.1 s (so the bag holds
"no frame yet" placeholders, zero-order-held frames and outliers) is recorded
once and shared by the tests.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("rclpy")

from vesselbot_ros.bag.reader import iter_messages, open_bag

REPO = Path(__file__).resolve().parents[2]
N_TICKS = 300


@pytest.fixture(scope="module")
def bag(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("replay_into")
    # the paper scenario extended by a file (`base:`), which is deleted once recorded: the bag alone holds the
    # merged scenario, which the re-run nodes get
    cfg = {"base": "paper_small_artery", "name": "paper_small_artery",
           "imager": {"frame_rate_Hz": 250.0, "latency_s": 0.002,
                      "outliers": [{"start_s": 0.1, "duration_s": 0.02, "magnitude_m": 1.0e-3}]}}
    (tmp / "zoh.yaml").write_text(yaml.safe_dump(cfg))
    out = tmp / "bag"
    cmd = [sys.executable, "-m", "vesselbot_ros.cli", "run", "--config", str(tmp / "zoh.yaml"), "--duration", "0.3",
           "--seed", "5", "--quiet", "--record-dir", str(out)]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    (tmp / "zoh.yaml").unlink()
    return out


def test_the_bag_holds_the_merged_scenario_of_a_file_with_base(bag):
    from vesselbot_ros.sim.scenario import load_scenario, scenario_from_mapping

    config = open_bag(bag).run_metadata["config"]
    assert "base" not in config
    got = scenario_from_mapping(config)
    paper = load_scenario("paper_small_artery", duration=0.3, seed=5)
    assert (got.imager.frame_rate_Hz, got.imager.latency_s, len(got.imager.outliers)) == (250.0, 0.002, 1)
    assert (got.physics, got.controller, got.reference, got.coil) == (paper.physics, paper.controller,
                                                                      paper.reference, paper.coil)


def _replay(*args: str, timeout: float = 180) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "vesselbot_ros.cli", "replay", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=timeout)


def _by_tick(path: Path, topic: str) -> dict[int, object]:
    out = {}
    for m in iter_messages(path, topics=[topic]):
        msg = m.decode()
        ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        out.setdefault(round(ns / 1_000_000), msg)  # 1 kHz ticks
    return out


def test_the_bag_exercises_placeholders_held_frames_and_outliers(bag):
    meas = [m.decode() for m in iter_messages(bag, topics=["/vesselbot/measurement"])]
    assert len(meas) == N_TICKS
    assert [m.header.frame_id for m in meas[:2]] == ["", ""]  # 2 ms latency: no frame yet on ticks 0 and 1
    stamps = [m.header.stamp.nanosec for m in meas[2:]]
    assert len(set(stamps)) == (N_TICKS - 2 + 3) // 4  # 250 Hz frames, each held for 4 ticks
    assert max(abs(m.point.x) for m in meas) > 5e-4  # the outlier burst is in the bag


def test_into_observer_reproduces_the_recorded_estimates_bit_for_bit(bag, tmp_path):
    out = tmp_path / "obs"
    proc = _replay(str(bag), "--into", "observer", "--out", str(out), "--tolerance", "0")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert f"fed {N_TICKS}/{N_TICKS} ticks, answered {N_TICKS}" in proc.stdout
    assert f"{N_TICKS} bit-identical" in proc.stdout
    info = open_bag(out)
    assert info.consistent, info.problems
    counts = {t.name: t.count for t in info.topics}
    assert counts["/vesselbot/measurement"] == N_TICKS and counts["/vesselbot/coil/applied"] == N_TICKS - 1
    assert counts["/vesselbot/estimate"] == counts["/vesselbot/replay/estimate"] == N_TICKS
    assert info.run_metadata["reestimate"]["into"] == "observer" and info.run_metadata["seed"] == 5
    old, new = _by_tick(out, "/vesselbot/estimate"), _by_tick(out, "/vesselbot/replay/estimate")
    assert sorted(new) == list(range(N_TICKS))
    for k in range(N_TICKS):  # every field of every estimate, no tolerance
        a, b = old[k], new[k]
        assert (a.header.stamp.sec, a.header.stamp.nanosec, a.header.frame_id) == \
               (b.header.stamp.sec, b.header.stamp.nanosec, b.header.frame_id), k
        pa, pb = a.pose.pose.position, b.pose.pose.position
        va, vb = a.twist.twist.linear, b.twist.twist.linear
        assert (pa.x, pa.y, pa.z, va.x, va.y, va.z) == (pb.x, pb.y, pb.z, vb.x, vb.y, vb.z), k
        assert np.array_equal(a.pose.covariance, b.pose.covariance), k
    # the recorded estimates in the result bag are the original bag's
    orig = _by_tick(bag, "/vesselbot/estimate")
    assert all(orig[k].pose.pose.position.x == old[k].pose.pose.position.x for k in range(N_TICKS))
    summary = json.loads((out / "comparison.json").read_text())
    assert summary["identical"] == N_TICKS and set(summary["max_abs_difference"].values()) == {0.0}


def test_into_controller_reproduces_the_recorded_commands_bit_for_bit(bag, tmp_path):
    before = sorted(p.name for p in bag.iterdir())
    proc = _replay(str(bag), "--into", "controller", "--tolerance", "0")  # the default result: beside the bag
    assert proc.returncode == 0, proc.stdout + proc.stderr
    out = bag.with_name(f"{bag.name}.reestimate_controller")
    assert f"bag: {out} " in proc.stdout
    assert sorted(p.name for p in bag.iterdir()) == before  # nothing written into the recorded bag
    old, new = _by_tick(out, "/vesselbot/gradient_command"), _by_tick(out, "/vesselbot/replay/gradient_command")
    assert sorted(new) == sorted(old) == list(range(N_TICKS))
    for k in range(N_TICKS):
        assert (old[k].vector.x, old[k].vector.y, old[k].vector.z) == (new[k].vector.x, new[k].vector.y,
                                                                       new[k].vector.z), k
    assert any(abs(new[k].vector.x) > 0 for k in range(N_TICKS))  # not a trivially zero command
    counts = {t.name: t.count for t in open_bag(out).topics}
    assert counts["/vesselbot/reference"] == counts["/vesselbot/estimate"] == N_TICKS


USER_OBSERVER = '''
import sys
import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from geometry_msgs.msg import PointStamped
from nav_msgs.msg import Odometry


class CopyObserver(Node):
    """A naive user observer: the estimate is the latest measurement, zero velocity."""

    def __init__(self):
        super().__init__("my_observer")
        rate = self.declare_parameter("sim.control_rate_Hz", 1.0).value
        self.dt, self.n = 1.0 / rate, 0
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.create_publisher(Odometry, "/vesselbot/estimate", qos)
        self.create_subscription(PointStamped, "/vesselbot/measurement", self.on_measurement, qos)

    def on_measurement(self, m):
        est = Odometry()
        est.header.frame_id = "vessel"
        est.header.stamp.sec, est.header.stamp.nanosec = divmod(round(self.n * self.dt * 1e9), 10**9)
        est.pose.pose.position = m.point
        self.n += 1
        self.pub.publish(est)


rclpy.init(args=sys.argv)
node = CopyObserver()
try:
    rclpy.spin(node)
except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
    pass
'''


def test_node_cmd_runs_a_users_observer_and_reports_its_differences(bag, tmp_path):
    script = tmp_path / "my_observer.py"
    script.write_text(USER_OBSERVER)
    out = tmp_path / "user"
    proc = _replay(str(bag), "--into", "observer", "--node-cmd", f"python {script}", "--out", str(out),
                   "--tolerance", "0")
    # every tick answered, but the naive estimate differs from ours: --tolerance 0 fails the run
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert f"answered {N_TICKS}" in proc.stdout and "exceeds --tolerance 0" in proc.stderr
    assert "does not subscribe to /vesselbot/coil/applied; feeding anyway" in proc.stderr
    meas = [m.decode() for m in iter_messages(out, topics=["/vesselbot/measurement"])]
    new = _by_tick(out, "/vesselbot/replay/estimate")
    old = _by_tick(out, "/vesselbot/estimate")
    assert [new[k].pose.pose.position.x for k in range(N_TICKS)] == [m.point.x for m in meas]
    want = max(abs(meas[k].point.x - old[k].pose.pose.position.x) for k in range(N_TICKS))
    summary = json.loads((out / "comparison.json").read_text())
    assert summary["max_abs_difference"]["x_hat_x_m"] == want > 1e-4  # the outlier burst, copied through
    assert summary["ticks_answered"] == N_TICKS and summary["identical"] < N_TICKS


def test_a_node_cmd_that_exits_is_named_with_its_exit_code(bag, tmp_path):
    proc = _replay(str(bag), "--into", "controller", "--node-cmd", "python -c 'import sys; sys.exit(3)'",
                   "--out", str(tmp_path / "dead"), "--wait-timeout", "30", timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "the controller node exited with code 3" in proc.stderr


def test_into_refuses_an_existing_result_and_options_without_into(bag, tmp_path):
    proc = _replay(str(bag), "--into", "observer", "--out", str(bag))
    assert proc.returncode == 2 and "already holds a bag (metadata.yaml" in proc.stderr, proc.stderr
    proc = _replay(str(bag), "--node-cmd", "x")
    assert proc.returncode == 2 and "need --into observer|controller" in proc.stderr, proc.stderr


def test_into_on_a_disk_that_fills_after_the_feed_leaves_no_partial_result_bag(bag, tmp_path):
    """The disk fills once the node's answers are in, before the result bag is written: one error line naming the
    result bag, no partial bag (no MCAP, no metadata.yaml, no work folder), exit 2."""
    from vesselbot_ros.testing import cli_on_a_full_disk

    out = tmp_path / "into"
    child = cli_on_a_full_disk(["replay", str(bag), "--into", "observer", "--out", str(out)],
                               fill_after="vesselbot_ros.launch.reestimate:compare_outputs", cwd=REPO, timeout=300)
    errors = [ln for ln in child.stderr.splitlines() if "error" in ln]
    assert child.returncode == 2, child.stderr
    assert len(errors) == 1 and errors[0].startswith(f"vesselbot replay: error: cannot write the result bag {out} ("), \
        child.stderr
    assert "File too large: the disk is full" in errors[0] and errors[0].endswith(
        f"no partial bag was left (the node's log is in {out / 'logs'})")
    assert "Traceback" not in child.stderr
    left = sorted(p.name for p in out.iterdir())
    assert "logs" in left and not [n for n in left if n.endswith(".mcap") or n.startswith(".") or n == "metadata.yaml"]
