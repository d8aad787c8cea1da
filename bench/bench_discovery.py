"""Benchmark of DDS discovery: how late a new process's publisher is matched, with our participant defaults and without
(prints figures, asserts nothing).

A run's node process makes its publishers and subscriptions in its first second (imports, the scenario, the compiled
stage), while its participant is still being discovered by the run's other processes.  Each trial, measured side by
side and alternating the two settings:

1. a peer process (the run's launcher or recorder, already up) subscribes to a topic and stays up;
2. a new process makes its participant, waits ``--delay`` s (default 0.25: a node's construction), makes a publisher
   on that topic, and times until the publisher has matched the peer's subscription.

The settings: the peer (and the new process) with ``vesselbot_ros/fastdds_profile.xml``, whose participants
re-announce every 250 ms (what ``vesselbot run`` gives every process of a run, :mod:`vesselbot_ros.ros_env`), and
with Fast DDS's defaults (every 3 s).  Printed: each setting's median, worst and the share of trials matched later
than 0.5 s.

Usage: .venv/bin/python bench/bench_discovery.py [--trials N] [--delay S]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

from vesselbot_ros.ros_env import FASTDDS_PROFILE, FASTDDS_PROFILE_KEY, allocate_domain, ros_environment

PEER = """
import sys, time, rclpy
from std_msgs.msg import String
rclpy.init(); n = rclpy.create_node("peer")
n.create_subscription(String, "/bench_discovery", lambda m: None, 10)
print("up", flush=True)
t0 = time.monotonic()
while time.monotonic() - t0 < float(sys.argv[1]):
    rclpy.spin_once(n, timeout_sec=0.05)
"""
NEW = """
import sys, time, rclpy
from std_msgs.msg import String
rclpy.init(); n = rclpy.create_node("new")
time.sleep(float(sys.argv[1]))
t0 = time.monotonic(); pub = n.create_publisher(String, "/bench_discovery", 10)
while pub.get_subscription_count() == 0 and time.monotonic() - t0 < 10.0:
    rclpy.spin_once(n, timeout_sec=0.002)
print(time.monotonic() - t0, flush=True)
"""


def trial(env: dict[str, str], delay: float) -> float:
    """Seconds from the new process's publisher to its first match with the peer's subscription."""
    peer = subprocess.Popen([sys.executable, "-c", PEER, "30"], env=env, stdout=subprocess.PIPE, text=True)
    try:
        line = peer.stdout.readline() if peer.stdout is not None else ""
        assert line.strip() == "up", line
        time.sleep(1.0)  # the peer settled, as a run's launcher and recorder are when its nodes start
        out = subprocess.run([sys.executable, "-c", NEW, str(delay)], env=env, capture_output=True, text=True,
                             timeout=60, check=True)
        return float(out.stdout.strip().splitlines()[-1])
    finally:
        peer.kill()
        peer.wait()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=10, help="trials per setting (default 10)")
    ap.add_argument("--delay", type=float, default=0.25, help="s from the new participant to its publisher")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        # Fast DDS's own default (a profiles file must hold a profile: ours with the period set back to 3 s)
        defaults = Path(tmp) / "defaults.xml"
        tree = ET.parse(FASTDDS_PROFILE)
        ns = {"d": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
        lease = tree.getroot().find("d:profiles/d:participant/d:rtps/d:builtin/d:discovery_config/d:leaseAnnouncement", ns)
        assert lease is not None, f"{FASTDDS_PROFILE} sets no leaseAnnouncement"
        for tag, value in (("sec", "3"), ("nanosec", "0")):
            field = lease.find(f"d:{tag}", ns)
            assert field is not None, f"{FASTDDS_PROFILE}: leaseAnnouncement has no {tag}"
            field.text = value
        ET.register_namespace("", ns["d"])
        tree.write(defaults, xml_declaration=True, encoding="UTF-8")
        lease = allocate_domain()
        try:
            base = {k: v for k, v in os.environ.items() if k != FASTDDS_PROFILE_KEY}
            ours = ros_environment(lease.domain_id, Path(tmp) / "logs", base=base)
            settings = {"ours (250 ms announcements)": ours,
                        "Fast DDS defaults (3 s)": {**ours, FASTDDS_PROFILE_KEY: str(defaults)}}
            assert ours[FASTDDS_PROFILE_KEY] == str(FASTDDS_PROFILE)
            got: dict[str, list[float]] = {k: [] for k in settings}
            for i in range(args.trials):
                order = list(settings) if i % 2 == 0 else list(settings)[::-1]
                for name in order:
                    got[name].append(trial(settings[name], args.delay))
        finally:
            lease.release()
    print(f"publisher made {args.delay:.2f} s after its participant; {args.trials} trials per setting, alternating")
    for name, v in got.items():
        late = sum(x > 0.5 for x in v)
        print(f"  {name:30s} median {statistics.median(v) * 1e3:7.1f} ms  worst {max(v) * 1e3:7.1f} ms  "
              f"matched later than 0.5 s: {late} of {len(v)}")
    a, b = (statistics.mean(v) for v in got.values())
    print(f"  mean ratio, Fast DDS defaults over ours: {b / a:.1f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
