"""`vesselbot run` ends in bounded time when a node dies, and lets a user's node fill a slot."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

pytest.importorskip("rclpy")

from _runs import children, node_pid  # noqa: E402


def test_run_reports_which_node_died_and_exits_nonzero(repo, tmp_path):
    cmd = [sys.executable, "-m", "vesselbot_ros.cli", "run", "--no-record", "--duration", "30"]
    launcher = subprocess.Popen(cmd, cwd=repo, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # wait until the run is under way (a progress line), bounded
        deadline = time.monotonic() + 90
        line = ""
        while time.monotonic() < deadline and "sim " not in line:
            line = launcher.stdout.readline()
            assert line or launcher.poll() is None, launcher.stderr.read()
        assert "sim " in line
        victim = node_pid(launcher.pid, "observer")  # asserts there is exactly one
        t0 = time.monotonic()
        os.kill(victim, signal.SIGKILL)
        _, err = launcher.communicate(timeout=60)
        assert time.monotonic() - t0 < 30
    finally:
        if launcher.poll() is None:
            launcher.kill()
    assert launcher.returncode == 1
    assert "node observer died (exit code -9)" in err
    # the other nodes were stopped, not orphaned
    assert not children(launcher.pid)


def test_user_controller_takes_the_controller_slot(repo, tmp_path):
    # the user's node and the run must share a domain: pick a free one, then pass it with --domain-id
    from vesselbot_ros.ros_env import allocate_domain, ros_environment

    with allocate_domain() as lease:
        dom = lease.domain_id
    env = ros_environment(dom, tmp_path / "ros_log")
    user = subprocess.Popen([sys.executable, str(repo / "examples" / "my_controller.py"), "--ros-args", "-p",
                             "use_sim_time:=true"], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        p = subprocess.run([sys.executable, "-m", "vesselbot_ros.cli", "run", "--no-record", "--duration", "0.2",
                            "--without", "controller", "--domain-id", str(dom), "--wait-timeout", "60", "--quiet"],
                           cwd=repo, capture_output=True, text=True, timeout=180)
    finally:
        user.send_signal(signal.SIGINT)
        user.wait(timeout=20)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "slot 'controller' is yours" in p.stdout
    assert "subscribe /vesselbot/estimate [nav_msgs/msg/Odometry]" in p.stdout
    assert "run finished: 200 ticks" in p.stdout
