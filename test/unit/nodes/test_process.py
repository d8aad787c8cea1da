"""The process entry (run_node): a signal stops a node process with exit 0, no traceback, rcl's log file complete."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

REPO = Path(__file__).resolve().parents[3]

#: A reference node that logs one line once built, then publishes as fast as its executor lets it (a publication is
#: in flight whenever the signal comes), run through run_node as the console scripts run it (exit_process).
DRIVER = r"""
import sys
from std_msgs.msg import Header
from vesselbot_ros.nodes.process import run_node
from vesselbot_ros.nodes.reference_node import ReferenceNode

class Busy(ReferenceNode):
    def __init__(self, **kw):
        super().__init__(**kw)
        pub = self.create_publisher(Header, "busy", 10)
        self.create_timer(0.0, lambda: [pub.publish(Header()) for _ in range(200)])
        self.get_logger().info("test_process: node built")
        print("READY", flush=True)

sys.exit(run_node(Busy, sys.argv, exit_process=True))
"""


def _run(tmp_path: Path, sig: int | None, *args: str) -> tuple[int, str, str]:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_LOG_DIR=str(tmp_path))
    proc = subprocess.Popen([sys.executable, "-c", DRIVER, *args], env=env, cwd=REPO, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        if sig is not None:
            assert proc.stdout is not None and proc.stdout.readline().strip() == "READY"
            time.sleep(0.5)
            proc.send_signal(sig)
        _out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    logs = "".join(p.read_text() for p in tmp_path.glob("*.log"))
    return proc.returncode, err, logs


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_under_publications_stops_the_process_cleanly_and_rcl_logs_are_closed(tmp_path, sig) -> None:
    code, err, logs = _run(tmp_path, sig)
    assert code == 0, err
    assert "Traceback" not in err and "RCLError" not in err, err
    assert "test_process: node built" in logs  # the fast exit came after rcl logging was closed
    # the signal ended the spin, not a callback: no "Exception in 'timers' callback" FATAL in the node's log
    assert "FATAL" not in logs and "Traceback" not in logs, logs


def test_an_invalid_parameter_exits_2_with_one_line(tmp_path) -> None:
    code, err, _ = _run(tmp_path, None, "--ros-args", "-p", "no_such_parameter:=1")
    assert code == 2
    assert err.strip().splitlines() == [err.strip()] and "invalid parameter" in err and "no_such_parameter" in err
