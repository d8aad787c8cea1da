"""`vesselbot run` ends in bounded time when a node dies, and lets a user's node fill a slot."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("rclpy")


def _children(pid: int) -> dict[int, str]:
    out = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            if ppid == pid:
                out[int(d.name)] = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, ValueError, IndexError):
            continue
    return out


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
        victims = [p for p, c in _children(launcher.pid).items() if "vesselbot_ros.nodes.observer_node" in c]
        assert len(victims) == 1
        t0 = time.monotonic()
        os.kill(victims[0], signal.SIGKILL)
        _, err = launcher.communicate(timeout=60)
        assert time.monotonic() - t0 < 30
    finally:
        if launcher.poll() is None:
            launcher.kill()
    assert launcher.returncode == 1
    assert "node observer died (exit code -9)" in err
    # the other nodes were stopped, not orphaned
    assert not _children(launcher.pid)


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
