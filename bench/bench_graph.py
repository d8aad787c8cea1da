"""Benchmark of the ROS 2 node graph against the pure runner (prints figures, asserts nothing).

For the paper's 2 s scenario at 1 kHz control (default config/sound_small_artery.yaml,
the one `make run` runs; `--config config/paper_small_artery.yaml` for the printed one):

1. pure runner wall time (same process, after a warm-up for numba);
2. lockstep over ROS, one process per node (6 nodes + the launcher = 7 processes);
3. lockstep over ROS, ``--single-process``;
4. real-time mode: imager -> coil-driver latency (median, p99), measured by a
   probe node that timestamps, on one clock, the arrival of each fresh
   measurement and of the first ``coil/applied`` that answers it.

Usage: .venv/bin/python bench/bench_graph.py [--config F] [--duration S] [--skip-realtime]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config" / "sound_small_artery.yaml"  # what `make run` runs; --config to change


def pure_wall(duration: float | None) -> tuple[float, float]:
    from vesselbot_ros.config import load_yaml
    from vesselbot_ros.launch.run_cli import apply_overrides
    from vesselbot_ros.sim.closed_loop import run_closed_loop
    from vesselbot_ros.sim.scenario import scenario_from_mapping

    s = scenario_from_mapping(apply_overrides(load_yaml(CONFIG), duration, None))
    short = scenario_from_mapping(apply_overrides(load_yaml(CONFIG), 0.01, None))
    run_closed_loop(short)  # numba warm-up
    t = time.perf_counter()
    run_closed_loop(s)
    wall = time.perf_counter() - t
    return wall, s.sim.n_ticks * s.sim.dt_control_s


def ros_run(extra: list[str], duration: float | None) -> dict:
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "m.json"
        cmd = [sys.executable, "-m", "vesselbot_ros.cli", "run", "--config", str(CONFIG), "--no-record", "--quiet",
               "--metrics-json", str(out), *extra]
        if duration is not None:
            cmd += ["--duration", str(duration)]
        p = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=1800)
        if p.returncode != 0:
            raise SystemExit(f"vesselbot run failed:\n{p.stdout}\n{p.stderr}")
        return json.loads(out.read_text())


def realtime_latency(duration: float, rtf: float) -> np.ndarray:
    """Imager -> driver latency samples (s) in real-time mode."""
    import rclpy
    from geometry_msgs.msg import PointStamped, Vector3Stamped

    from vesselbot_ros.nodes.conversions import ns_of_stamp
    from vesselbot_ros.ros_env import allocate_domain, ros_environment
    from vesselbot_ros.graph_spec import qos_profile, topic

    lease = allocate_domain()
    dom = lease.domain_id
    lease.release()  # the launcher leases it again for the run; our probe joins it
    import os

    with tempfile.TemporaryDirectory() as d:
        env = ros_environment(dom, Path(d) / "log")
        os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOG_DIR")})
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=dom)
        node = rclpy.create_node("latency_probe", context=ctx)
        meas: list[tuple[float, int]] = []
        applied: list[tuple[float, int]] = []
        node.create_subscription(PointStamped, topic("measurement").name,
                                 lambda m: meas.append((time.perf_counter(), ns_of_stamp(m.header.stamp))),
                                 qos_profile(topic("measurement")))
        node.create_subscription(Vector3Stamped, topic("coil_applied").name,
                                 lambda m: applied.append((time.perf_counter(), ns_of_stamp(m.header.stamp))),
                                 qos_profile(topic("coil_applied")))
        from rclpy.experimental import EventsExecutor

        ex = EventsExecutor(context=ctx)
        ex.add_node(node)
        cmd = [sys.executable, "-m", "vesselbot_ros.cli", "run", "--config", str(CONFIG), "--no-record", "--quiet",
               "--mode", "realtime", "--real-time-factor", str(rtf), "--duration", str(duration),
               "--domain-id", str(dom)]
        run = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        while run.poll() is None:
            ex.spin_once(timeout_sec=0.01)
        if run.returncode != 0:
            raise SystemExit(f"real-time run failed:\n{run.stdout.read()}")
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    lat = []
    j = 0
    for w_m, s_m in meas:
        while j < len(applied) and (applied[j][0] < w_m or applied[j][1] < s_m):
            j += 1
        if j < len(applied):
            lat.append(applied[j][0] - w_m)
    return np.asarray(lat)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=None, help="sim duration (s), default: the scenario's 2 s")
    ap.add_argument("--config", type=Path, default=None,
                    help="scenario (default: config/sound_small_artery.yaml, the one `make run` runs)")
    ap.add_argument("--skip-realtime", action="store_true")
    ap.add_argument("--rt-duration", type=float, default=0.5)
    ap.add_argument("--rt-factor", type=float, default=0.1, help="real-time factor of the latency run")
    a = ap.parse_args()
    if a.config is not None:
        global CONFIG
        CONFIG = a.config.resolve()
    print(f"scenario: {CONFIG.relative_to(REPO) if CONFIG.is_relative_to(REPO) else CONFIG}")
    pure, sim = pure_wall(a.duration)
    print(f"{sim:.3f} s sim at 1 kHz = {int(round(sim * 1000))} ticks")
    print(f"pure runner:                 wall {pure:7.2f} s   RTF {sim / pure:6.3f}")
    rows = []
    for label, extra in (("lockstep, 7 processes", []), ("lockstep, --single-process", ["--single-process"])):
        r = ros_run(extra, a.duration)
        rows.append((label, r))
        over_us = (r["wall_s"] - pure) / (sim * 1000) * 1e6
        print(f"{label:28s} wall {r['wall_s']:7.2f} s   RTF {r['real_time_factor']:6.3f}   "
              f"ROS/pure wall ratio {r['wall_s'] / pure:5.2f}   graph overhead {over_us:7.0f} us/tick")
    if not a.skip_realtime:
        lat = realtime_latency(a.rt_duration, a.rt_factor)
        if lat.size:
            print(f"real-time (RTF {a.rt_factor}): imager->driver latency over {lat.size} frames: "
                  f"median {np.median(lat) * 1e6:.0f} us, p99 {np.percentile(lat, 99) * 1e6:.0f} us")
        else:
            print("real-time: no latency samples")
    return 0


if __name__ == "__main__":
    sys.exit(main())
