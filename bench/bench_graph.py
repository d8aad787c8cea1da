"""Benchmark of the ROS 2 node graph against a bare rclpy chain and the pure runner (prints figures, asserts nothing).

For the paper's 2 s scenario at 1 kHz control (default config/sound_small_artery.yaml,
the one `make run` runs; `--config config/paper_small_artery.yaml` for the printed one),
measured side by side in one run:

1. the bare chain: plain rclpy, no project code, the shape of our lockstep
   tick: a plant publishing a clock and a state, four relays, five sequential
   hops (plant -> r1 -> r2 -> r3 -> r4 -> plant), reliable keep-last 1000,
   EventsExecutor; one process per node and all in one process;
2. pure runner wall time (same process, after a warm-up for numba);
3. lockstep over ROS, one process per node (6 nodes; the launcher takes no per-tick topic);
4. lockstep over ROS, ``--single-process``;
5. the ratios: our graph overhead per tick (wall minus the pure runner's, per
   tick) over the bare chain's time per tick, in both modes (target <= 1.2), and
   our wall time over the pure runner's.  The machine is shared and its speed
   drifts within minutes, so the bare chain and ours run back to back in
   ``--rounds`` rounds (default 5); each round gives one ratio per mode, and the
   median over the rounds is the figure;
6. real-time mode: imager -> coil-driver latency (median, p99), measured by a
   probe node that timestamps, on one clock, the arrival of each fresh
   measurement and of the first ``coil/applied`` that answers it.

Usage: .venv/bin/python bench/bench_graph.py [--config F] [--duration S] [--rounds N] [--skip-realtime]
"""

from __future__ import annotations

import argparse
import json
import os
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


# ---------------------------------------------------------------- the bare chain
#: node -> (topic it waits for, topics it publishes); the plant starts each tick
BARE = {"plant": ("d", ("clock", "state")), "r1": ("state", ("a",)), "r2": ("a", ("b",)), "r3": ("b", ("c",)),
        "r4": ("c", ("d",))}


def plant_loop(node, emit, n_ticks: int, done, msg_cls, name: str, qos) -> None:
    """The plant of a bare chain: tick k+1 on the answer to tick k; ``node.start()`` emits tick 0."""
    state = {"t0": None}

    def on_answer(msg):
        k = msg.header.stamp.nanosec + 1
        if k < n_ticks:
            emit(k)
        else:
            done(time.perf_counter() - state["t0"])

    node.create_subscription(msg_cls, name, on_answer, qos)
    node.start = lambda: (state.__setitem__("t0", time.perf_counter()), emit(0))


def bare_nodes(context, n_ticks: int, names, done):
    """The bare chain's nodes ``names`` (plain rclpy; Vector3Stamped payloads stamped with the tick)."""
    import rclpy
    from geometry_msgs.msg import Vector3Stamped
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock

    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE)
    nodes = []
    for name in names:
        node = rclpy.create_node(f"bare_{name}", namespace="/bare", context=context)
        sub, pubs = BARE[name]
        out = {t: node.create_publisher(Clock if t == "clock" else Vector3Stamped, t, qos) for t in pubs}
        if name == "plant":
            def emit(k, out=out):
                c = Clock()
                c.clock.nanosec = k
                out["clock"].publish(c)
                m = Vector3Stamped()
                m.header.stamp.nanosec = k
                out["state"].publish(m)

            plant_loop(node, emit, n_ticks, done, Vector3Stamped, sub, qos)
            # the whole chain is wired: every hop has its publisher and its subscriber (graph-wide)
            node.ready = lambda node=node: all(node.count_publishers(f"/bare/{t}") > 0 and
                                               node.count_subscribers(f"/bare/{t}") > 0
                                               for t in ("state", "a", "b", "c", "d"))
        else:
            pub = out[pubs[0]]

            def relay(msg, pub=pub):
                m = Vector3Stamped()
                m.header.stamp = msg.header.stamp
                m.vector.x = msg.vector.x + 1.0
                pub.publish(m)

            node.create_subscription(Vector3Stamped, sub, relay, qos)
            if name == "r4":  # like the coil driver, the last relay also hears the clock
                node.create_subscription(Clock, "clock", lambda _m: None, qos)
            node.ready = lambda pub=pub: pub.get_subscription_count() > 0
        nodes.append(node)
    return nodes


# ------------------------------------------------------- the bare chain with our topology
#: role -> the input key whose arrival completes its tick (lockstep order); its other inputs are only heard
TRIGGER = {"reference": "clock", "imager": "truth", "observer": "measurement", "controller": "estimate",
           "coil_driver": "gradient_command", "plant": "coil_applied"}


def topo_nodes(context, n_ticks: int, names, done):
    """Our graph's topics, types, QoS and fan-out (from the graph spec), no project code per message.

    Each role answers its trigger input with one default-constructed message per output (the tick in
    the stamp), hears its other inputs, and does nothing else.  The launcher takes no per-tick topic (it
    reads the run's series from the nodes afterwards), so it has no counterpart here.
    """
    import rclpy

    from vesselbot_ros.graph_spec import import_type, qos_profile, role, topic

    def stamp_of(msg):
        return msg.clock if hasattr(msg, "clock") else msg.header.stamp

    nodes = []
    for name in names:
        node = rclpy.create_node(f"topo_{name}", namespace="/topo", context=context)
        r = role(name)
        outs = [k for k in r.outputs if topic(k).per_tick]
        pubs = {k: node.create_publisher(import_type(topic(k).msgtype), topic(k).rel, qos_profile(topic(k)))
                for k in outs}
        types = {k: import_type(topic(k).msgtype) for k in outs}

        def emit(k, pubs=pubs, types=types):
            for key, pub in pubs.items():
                m = types[key]()
                stamp_of(m).nanosec = k
                pub.publish(m)

        if name == "plant":
            t = topic("coil_applied")
            plant_loop(node, emit, n_ticks, done, import_type(t.msgtype), t.rel, qos_profile(t))
            # the whole graph is wired: every per-tick topic has its publisher and its subscribers
            wired = [node.resolve_topic_name(topic(k).rel) for k in set(TRIGGER.values())]
            node.ready = lambda node=node, wired=wired: all(
                node.count_publishers(t) > 0 and node.count_subscribers(t) > 0 for t in wired)
        else:
            trig = TRIGGER[name]
            node.create_subscription(import_type(topic(trig).msgtype), topic(trig).rel,
                                     lambda msg, emit=emit: emit(stamp_of(msg).nanosec), qos_profile(topic(trig)))
            for key in r.inputs:
                if key != trig and topic(key).per_tick:
                    node.create_subscription(import_type(topic(key).msgtype), topic(key).rel, lambda _m: None,
                                             qos_profile(topic(key)))
            node.ready = lambda pubs=pubs: all(p.get_subscription_count() > 0 for p in pubs.values())
        nodes.append(node)
    return nodes


def bare_node_main(name: str, n_ticks: int) -> int:
    """One bare-chain node as a process (``--bare-node NAME``); the plant prints the wall time."""
    import rclpy
    from rclpy.experimental import EventsExecutor

    rclpy.init()
    result = {}
    topo = name.startswith("topo:")
    names = name[5:].split(",") if topo else [name]
    made = (topo_nodes if topo else bare_nodes)(None, n_ticks, names, lambda wall: result.setdefault("wall", wall))
    node = next((nd for nd in made if nd.get_name().endswith("plant")), made[0])
    name = "plant" if node.get_name().endswith("plant") else name
    ex = EventsExecutor()
    for nd in made:
        ex.add_node(nd)
    if name == "plant":
        while not node.ready():
            ex.spin_once(timeout_sec=0.05)
        time.sleep(1.0)  # every relay's matches settle too
        node.start()
        while "wall" not in result:
            ex.spin_once(timeout_sec=0.1)
        print(json.dumps(result), flush=True)
        return 0
    try:
        while rclpy.ok():
            ex.spin_once(timeout_sec=0.1)
    except KeyboardInterrupt:
        pass
    return 0


def topo_chain(n_ticks: int, processes: bool) -> float:
    """Wall time (s) of ``n_ticks`` ticks of our topology with no project code."""
    from vesselbot_ros.graph_spec import LOOP_ROLES
    from vesselbot_ros.ros_env import allocate_domain, ros_environment

    others = [r for r in LOOP_ROLES if r != "plant"]
    groups = [[r] for r in others] + [["plant"]] if processes else [list(LOOP_ROLES)]
    with allocate_domain() as lease, tempfile.TemporaryDirectory() as d:
        env = ros_environment(lease.domain_id, Path(d) / "log")

        return run_node_processes(env, n_ticks, ["topo:" + ",".join(g) for g in groups[:-1]],
                                  "topo:" + ",".join(groups[-1]))


def run_node_processes(env: dict, n_ticks: int, others: list[str], plant: str) -> float:
    """Start the ``--bare-node`` processes ``others``, run ``plant`` to the end, stop them; the plant's wall time."""
    import signal as sig

    def argv(name: str) -> list[str]:
        return [sys.executable, __file__, "--bare-node", name, "--bare-ticks", str(n_ticks)]

    procs = [subprocess.Popen(argv(o), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for o in others]
    try:
        out = subprocess.run(argv(plant), env=env, capture_output=True, text=True, timeout=600)
    finally:
        for p in procs:
            p.send_signal(sig.SIGINT)
        for p in procs:
            p.wait(timeout=20)
    return float(json.loads(out.stdout.strip().splitlines()[-1])["wall"])


def bare_chain(n_ticks: int, processes: bool) -> float:
    """Wall time (s) of ``n_ticks`` lockstep ticks of the bare chain."""
    import rclpy
    from rclpy.experimental import EventsExecutor

    from vesselbot_ros.ros_env import allocate_domain, apply_to_process, restore_process_env, ros_environment

    with allocate_domain() as lease, tempfile.TemporaryDirectory() as d:
        env = ros_environment(lease.domain_id, Path(d) / "log")
        if processes:
            return run_node_processes(env, n_ticks, ["r1", "r2", "r3", "r4"], "plant")
        saved = apply_to_process(env)
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=lease.domain_id)
        result = {}
        try:
            nodes = bare_nodes(ctx, n_ticks, list(BARE), lambda wall: result.setdefault("wall", wall))
            ex = EventsExecutor(context=ctx)
            for nd in nodes:
                ex.add_node(nd)
            deadline = time.monotonic() + 60
            while not all(nd.ready() for nd in nodes) and time.monotonic() < deadline:
                ex.spin_once(timeout_sec=0.05)
            nodes[0].start()
            while "wall" not in result:
                ex.spin_once(timeout_sec=0.1)
            for nd in nodes:
                ex.remove_node(nd)
                nd.destroy_node()
            ex.shutdown()
        finally:
            rclpy.try_shutdown(context=ctx)
            restore_process_env(saved)
        return float(result["wall"])


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
    ap.add_argument("--rounds", type=int, default=5, help="bare chain / ours side by side, this many times (median)")
    ap.add_argument("--rt-duration", type=float, default=0.5)
    ap.add_argument("--rt-factor", type=float, default=0.1, help="real-time factor of the latency run")
    ap.add_argument("--bare-node", help=argparse.SUPPRESS)
    ap.add_argument("--bare-ticks", type=int, default=2000, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.bare_node:
        return bare_node_main(a.bare_node, a.bare_ticks)
    if a.config is not None:
        global CONFIG
        CONFIG = a.config.resolve()
    print(f"scenario: {CONFIG.relative_to(REPO) if CONFIG.is_relative_to(REPO) else CONFIG}")
    pure, sim = pure_wall(a.duration)
    n = int(round(sim * 1000))
    print(f"{sim:.3f} s sim at 1 kHz = {n} ticks")
    load0 = os.getloadavg()[0]
    topo = {"processes": topo_chain(n, True), "single": topo_chain(n, False)}
    for mode, wall in topo.items():
        print(f"bare, our topology, {mode + ':':11s}     wall {wall:7.2f} s   {wall / n * 1e6:7.0f} us/tick   "
              f"(our 8 per-tick topics, types, QoS and fan-out; no code per message)")
    print(f"pure runner:                       wall {pure:7.2f} s   RTF {sim / pure:6.3f}")
    # the machine is shared: its speed drifts by tens of % within minutes, so the bare chain and ours run
    # back to back, round after round, and each round gives one ratio; the median over rounds is the result
    ratios: dict[str, list[float]] = {"processes": [], "single": []}
    runs = (("lockstep, 6 node processes", [], "processes"), ("lockstep, --single-process", ["--single-process"], "single"))
    for i in range(a.rounds):
        print(f"round {i + 1} of {a.rounds}")
        for label, extra, mode in runs:
            bare_us = bare_chain(n, mode == "processes") / n * 1e6
            print(f"  bare rclpy chain, {mode + ':':11s}     {bare_us:7.0f} us/tick")
            r = ros_run(extra, a.duration)
            over_us = (r["wall_s"] - pure) / n * 1e6
            ratios[mode].append(over_us / bare_us)
            print(f"  {label:32s} wall {r['wall_s']:7.2f} s   RTF {r['real_time_factor']:6.3f}   "
                  f"ROS/pure {r['wall_s'] / pure:6.1f}   graph overhead {over_us:6.0f} us/tick   "
                  f"ours/bare chain {over_us / bare_us:5.2f}   ours/bare topology {r['wall_s'] / topo[mode]:5.2f}")
    r = ros_run(["--single-process", "--no-intra-process"], a.duration)
    print(f"lockstep, --single-process --no-intra-process: wall {r['wall_s']:7.2f} s   RTF {r['real_time_factor']:6.3f}   "
          f"graph overhead {(r['wall_s'] - pure) / n * 1e6:6.0f} us/tick   ours/bare topology {r['wall_s'] / topo['single']:5.2f}")
    for mode, rs in ratios.items():
        print(f"ours/bare chain, {mode + ':':11s} median {float(np.median(rs)):5.2f} over {len(rs)} rounds "
              f"({', '.join(f'{x:.2f}' for x in rs)})   target <= 1.2")
    print(f"load average {load0:.1f} before, {os.getloadavg()[0]:.1f} after (2 cores; other jobs share them)")
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
