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
   drifts by tens of % within a minute, so both graphs stay up for the whole
   comparison and take turns: ``--segments`` pairs (default 16) of
   ``--segment-ticks`` ticks (default 250) each, the bare chain stepped by its
   plant process, ours by ``StepSimulation`` (``vesselbot run --start-paused``),
   ours first in every other pair.  Each pair gives one ratio; the median over
   the pairs is the figure (quartiles and range printed with it).  The graph
   that waits is idle (its timers only).  With them, the CPU time of each graph's processes over its
   own segments, per tick and by process (from /proc): on two cores, a graph whose processes need
   more than one core between them also waits for the CPU;
6. real-time mode: imager -> coil-driver latency (median, p99), measured by a
   probe node that timestamps, on one clock, the arrival of each fresh
   measurement and of the first ``coil/applied`` that answers it.

Usage: .venv/bin/python bench/bench_graph.py [--config F] [--duration S] [--segments N] [--segment-ticks N]
       [--skip-realtime]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config" / "sound_small_artery.yaml"  # what `make run` runs; --config to change


def pure_wall(duration: float | None) -> tuple[float, float]:
    from vesselbot_ros.sim.closed_loop import run_closed_loop
    from vesselbot_ros.sim.scenario import load_scenario

    s = load_scenario(CONFIG, duration=duration)
    short = load_scenario(CONFIG, duration=0.01)
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
    """The plant of a bare chain: tick k+1 on the answer to tick k.

    ``node.segment(n)`` runs the next ``n`` of its ``n_ticks`` ticks; ``done`` gets their wall time (s),
    from the first emit to the last answer.
    """
    state = {"t0": 0.0, "next": 0, "end": n_ticks}

    def on_answer(msg):
        k = msg.header.stamp.nanosec + 1
        state["next"] = k
        if k < state["end"]:
            emit(k)
        else:
            done(time.perf_counter() - state["t0"])

    def segment(n: int) -> None:
        state["end"] = state["next"] + n
        state["t0"] = time.perf_counter()
        emit(state["next"])

    node.create_subscription(msg_cls, name, on_answer, qos)
    node.segment = segment


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


def bare_node_main(name: str, n_ticks: int, stepped: bool = False) -> int:
    """Bare-chain nodes as one process (``--bare-node NAME``); the process with the plant prints wall times.

    ``NAME``: one node of the bare chain, ``bare:a,b,...`` several, or ``topo:a,b,...`` roles of the bare
    topology.  ``--stepped``: the plant reads a tick count per line on stdin, runs that many ticks and
    prints their wall time, until stdin closes; otherwise it runs all ``n_ticks`` once.
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.experimental import EventsExecutor

    rclpy.init()
    result = {}
    kind, _, group = name.partition(":")
    names = group.split(",") if group else [name]
    made = (topo_nodes if kind == "topo" else bare_nodes)(None, n_ticks, names, lambda wall: result.setdefault("wall", wall))
    node = next((nd for nd in made if nd.get_name().endswith("plant")), None)
    ex = EventsExecutor()
    for nd in made:
        ex.add_node(nd)
    try:
        if node is None:  # relays: until SIGINT
            while rclpy.ok():
                ex.spin_once(timeout_sec=0.1)
            return 0
        while not node.ready():
            ex.spin_once(timeout_sec=0.05)
        time.sleep(1.0)  # every relay's matches settle too
        if stepped:
            print(json.dumps({"ready": True}), flush=True)
        for line in sys.stdin if stepped else [n_ticks]:
            result.clear()
            node.segment(int(line))
            while "wall" not in result:
                ex.spin_once(timeout_sec=0.1)
            print(json.dumps(result), flush=True)
        return 0
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:  # an executor left to the interpreter's exit can hang it
        ex.shutdown()
        for nd in made:
            nd.destroy_node()
        rclpy.try_shutdown()


def stop(procs: list[subprocess.Popen]) -> None:
    """SIGINT every relay process; one that has not exited within 20 s is killed."""
    for p in procs:
        p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def topo_chain(n_ticks: int, processes: bool) -> float:
    """Wall time (s) of ``n_ticks`` ticks of our topology with no project code."""
    from vesselbot_ros.graph_spec import loop_roles
    from vesselbot_ros.ros_env import allocate_domain, ros_environment

    roles = loop_roles(False)  # the benchmarked scenario's imager delivers positions: no tracker
    others = [r for r in roles if r != "plant"]
    groups = [[r] for r in others] + [["plant"]] if processes else [list(roles)]
    with allocate_domain() as lease, tempfile.TemporaryDirectory() as d:
        env = ros_environment(lease.domain_id, Path(d) / "log")

        return run_node_processes(env, n_ticks, ["topo:" + ",".join(g) for g in groups[:-1]],
                                  "topo:" + ",".join(groups[-1]))


def run_node_processes(env: dict, n_ticks: int, others: list[str], plant: str) -> float:
    """Start the ``--bare-node`` processes ``others``, run ``plant`` to the end, stop them; the plant's wall time."""
    def argv(name: str) -> list[str]:
        return [sys.executable, __file__, "--bare-node", name, "--bare-ticks", str(n_ticks)]

    procs = [subprocess.Popen(argv(o), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for o in others]
    try:
        out = subprocess.run(argv(plant), env=env, capture_output=True, text=True, timeout=600)
    finally:
        stop(procs)
    return float(json.loads(out.stdout.strip().splitlines()[-1])["wall"])


class SteppedBare:
    """The bare chain's processes, alive through the whole comparison; :meth:`run` times its next ``n`` ticks.

    Processes: one per node; ``processes=False``: all five in one process.
    """

    def __init__(self, processes: bool, n_ticks: int) -> None:
        from vesselbot_ros.ros_env import allocate_domain, ros_environment

        self._lease = allocate_domain()
        self._tmp = tempfile.TemporaryDirectory()
        env = ros_environment(self._lease.domain_id, Path(self._tmp.name) / "log")

        def argv(name: str, *more: str) -> list[str]:
            return [sys.executable, __file__, "--bare-node", name, "--bare-ticks", str(n_ticks), *more]

        relays = [r for r in BARE if r != "plant"]
        self._others = [subprocess.Popen(argv(r), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                        for r in (relays if processes else [])]
        self._plant = subprocess.Popen(argv("plant" if processes else "bare:" + ",".join(BARE), "--stepped"), env=env,
                                       stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                       text=True)
        self._read()  # wired and settled

    def _read(self) -> dict:
        line = self._plant.stdout.readline()  # type: ignore[union-attr]
        if not line:
            raise SystemExit("bench: the bare chain's plant process ended early")
        return json.loads(line)

    @property
    def pids(self) -> list[int]:
        """The chain's processes."""
        return [p.pid for p in self._others] + [self._plant.pid]

    def run(self, n: int) -> float:
        """Wall time (s) of the next ``n`` ticks."""
        self._plant.stdin.write(f"{n}\n")  # type: ignore[union-attr]
        self._plant.stdin.flush()  # type: ignore[union-attr]
        return float(self._read()["wall"])

    def close(self) -> None:
        self._plant.stdin.close()  # type: ignore[union-attr]
        try:  # the plant process ends at the end of its stdin
            self._plant.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self._plant.kill()
            self._plant.wait()
        stop(self._others)
        self._lease.release()
        self._tmp.cleanup()


class SteppedOurs:
    """``vesselbot run --start-paused`` (no recording), stepped by ``StepSimulation``; :meth:`run` times ``n`` ticks.

    The timed call includes the service's round trip, which counts against us.
    """

    def __init__(self, extra: list[str], n_ticks: int, dt: float) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from simulation_interfaces.msg import SimulationState

        from vesselbot_ros.graph_spec import import_type, resolve, service
        from vesselbot_ros.nodes.calls import prime
        from vesselbot_ros.ros_env import allocate_domain_for_peers, apply_to_process, ros_environment

        # held for our client until close(): the launcher joins it (--domain-id), no other run can take it meanwhile
        self._lease = allocate_domain_for_peers()
        dom = self._lease.domain_id
        self._tmp = tempfile.TemporaryDirectory()
        cmd = [sys.executable, "-m", "vesselbot_ros.cli", "run", "--config", str(CONFIG), "--no-record", "--quiet",
               "--start-paused", "--domain-id", str(dom), "--duration", repr(n_ticks * dt), *extra]
        self._proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self._saved = apply_to_process(ros_environment(dom, Path(self._tmp.name) / "log"))
        self._ctx = rclpy.Context()
        rclpy.init(context=self._ctx, domain_id=dom)
        self._node = rclpy.create_node("bench_stepper", context=self._ctx)
        self._ex = SingleThreadedExecutor(context=self._ctx)
        self._ex.add_node(self._node)

        def client(key: str):
            spec = service(key)
            return self._node.create_client(import_type(spec.srvtype), resolve(spec.rel))

        self._step = client("step_simulation")
        get_state = client("get_simulation_state")
        deadline = time.monotonic() + 180
        while True:
            if self._proc.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"bench: our graph did not come up paused:\n{self._proc.stdout.read()}")
            if get_state.service_is_ready():
                state = self._call(get_state, get_state.srv_type.Request(), 10.0)
                if state is not None and state.state.state == SimulationState.STATE_PAUSED:
                    break
            self._ex.spin_once(timeout_sec=0.1)
        # the step client's first call is a refused one (0 steps): a loaded machine can drop a fresh client's answer
        if prime(self._step, self._step.srv_type.Request(steps=0), 60.0,
                 spin=lambda dt: self._ex.spin_once(timeout_sec=dt)) is None:
            raise SystemExit("bench: StepSimulation never answered")

    def _call(self, cli, req, timeout: float):
        fut = cli.call_async(req)
        deadline = time.monotonic() + timeout
        while not fut.done() and time.monotonic() < deadline:
            self._ex.spin_once(timeout_sec=0.05)
        return fut.result() if fut.done() else None

    @property
    def pid(self) -> int:
        """The launcher's process (our nodes are its children)."""
        return self._proc.pid

    def run(self, n: int) -> float:
        """Wall time (s) of the next ``n`` ticks."""
        from simulation_interfaces.msg import Result

        req = self._step.srv_type.Request(steps=n)
        t0 = time.perf_counter()
        resp = self._call(self._step, req, 600.0)
        wall = time.perf_counter() - t0
        if resp is None or resp.result.result != Result.RESULT_OK:
            raise SystemExit(f"bench: StepSimulation({n}) failed: {resp}")
        return wall

    def close(self) -> None:
        """After the last tick the launcher ends the run by itself; an unfinished run is stopped."""
        import rclpy

        from vesselbot_ros.ros_env import restore_process_env

        self._node.destroy_node()
        rclpy.try_shutdown(context=self._ctx)
        restore_process_env(self._saved)
        try:
            self._proc.wait(timeout=120)
        except subprocess.TimeoutExpired:
            self._proc.send_signal(signal.SIGINT)
            self._proc.wait(timeout=60)
        self._lease.release()
        self._tmp.cleanup()


_CLK_TCK = os.sysconf("SC_CLK_TCK")


def _tree(pid: int) -> list[int]:
    """``pid`` and every process below it (Linux /proc)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as f:
                    todo += [int(c) for c in f.read().split()]
        except OSError:  # ended meanwhile
            pass
    return out


def _label(pid: int) -> str:
    """What a process of either graph is: a role of ours, a node of the bare chain, our launcher."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            argv = f.read().decode(errors="replace").split("\0")
    except OSError:
        return "?"
    for i, arg in enumerate(argv):
        if arg == "--bare-node" and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith("vesselbot_ros.nodes.") and arg.endswith("_node"):
            return arg[len("vesselbot_ros.nodes."):-len("_node")]
        if arg == "vesselbot_ros.launch.composed":
            return "composed nodes"
        if arg == "vesselbot_ros.cli":
            return "launcher"
    return "other"


def _cpu_s(pids: list[int]) -> dict[int, float]:
    """CPU time (user + system, s) of each process still alive."""
    out = {}
    for p in pids:
        try:
            with open(f"/proc/{p}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            out[p] = (int(fields[11]) + int(fields[12])) / _CLK_TCK
        except (OSError, IndexError, ValueError):
            pass
    return out


class CpuTally:
    """CPU time per process of one graph over the segments it ran, by label; :meth:`per_tick` in us."""

    def __init__(self, roots: list[int]) -> None:
        self.pids = [p for r in roots for p in _tree(r)]
        self.labels = {p: _label(p) for p in self.pids}
        self.cpu: dict[str, float] = {}
        self.ticks = 0

    def timed(self, run, n: int) -> float:
        before = _cpu_s(self.pids)
        wall = run(n)
        after = _cpu_s(self.pids)
        for p, t in after.items():
            if p in before:
                self.cpu[self.labels[p]] = self.cpu.get(self.labels[p], 0.0) + t - before[p]
        self.ticks += n
        return wall

    def per_tick(self) -> dict[str, float]:
        return {k: v / self.ticks * 1e6 for k, v in sorted(self.cpu.items(), key=lambda kv: -kv[1])}


def compare(processes: bool, segments: int, ticks: int, pure_tick_s: float,
            dt: float) -> tuple[list[tuple[float, float]], dict[str, float], dict[str, float]]:
    """``segments`` pairs of (bare chain, ours) wall per tick (s) over ``ticks`` ticks each, both graphs alive.

    Also returns the CPU time (us per tick) of each graph's processes, by process, over its own segments:
    on two cores a graph whose processes need more than one core between them waits for the CPU too.

    The two alternate every ``ticks`` ticks (ours first in every other pair), so a drift of the machine's
    speed, which on a shared host reaches tens of % within a minute, hits both sides of a pair alike.
    Ours is its graph overhead: wall minus the pure runner's time for the same ticks.
    """
    extra = [] if processes else ["--single-process"]
    ours = SteppedOurs(extra, segments * ticks, dt)
    bare = SteppedBare(processes, segments * ticks)
    cpu_ours, cpu_bare = CpuTally([ours.pid]), CpuTally(bare.pids)
    pairs = []
    try:
        for i in range(segments):
            if i % 2:
                o = cpu_ours.timed(ours.run, ticks)
                b = cpu_bare.timed(bare.run, ticks)
            else:
                b = cpu_bare.timed(bare.run, ticks)
                o = cpu_ours.timed(ours.run, ticks)
            pairs.append((b / ticks, o / ticks - pure_tick_s))
    finally:
        bare.close()
        ours.close()
    return pairs, cpu_bare.per_tick(), cpu_ours.per_tick()


def realtime_latency(duration: float, rtf: float) -> np.ndarray:
    """Imager -> driver latency samples (s) in real-time mode."""
    import os

    import rclpy
    from geometry_msgs.msg import PointStamped, Vector3Stamped

    from vesselbot_ros.graph_spec import qos_profile, topic
    from vesselbot_ros.nodes.conversions import ns_of_stamp
    from vesselbot_ros.ros_env import allocate_domain_for_peers, ros_environment

    # held for our probe until the run ended: the launcher joins it (--domain-id), no other run can take it meanwhile
    with allocate_domain_for_peers() as lease, tempfile.TemporaryDirectory() as d:
        dom = lease.domain_id
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
    ap.add_argument("--segments", type=int, default=16, help="pairs of bare chain / ours segments (median)")
    ap.add_argument("--segment-ticks", type=int, default=250, help="ticks per segment")
    ap.add_argument("--rt-duration", type=float, default=0.5)
    ap.add_argument("--rt-factor", type=float, default=0.1, help="real-time factor of the latency run")
    ap.add_argument("--bare-node", help=argparse.SUPPRESS)
    ap.add_argument("--bare-ticks", type=int, default=2000, help=argparse.SUPPRESS)
    ap.add_argument("--stepped", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.bare_node:
        return bare_node_main(a.bare_node, a.bare_ticks, a.stepped)
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
    pure_tick = pure / n
    dt = sim / n
    medians = {}
    for mode, label in (("processes", "6 node processes"), ("single", "--single-process")):
        got, cpu_bare, cpu_ours = compare(mode == "processes", a.segments, a.segment_ticks, pure_tick, dt)
        pairs = np.asarray(got)
        bare_us, ours_us = pairs[:, 0] * 1e6, pairs[:, 1] * 1e6
        ratio = ours_us / bare_us
        medians[mode] = float(np.median(ratio))
        q1, q3 = np.percentile(ratio, [25, 75])
        print(f"lockstep, {label:17s} {a.segments} x {a.segment_ticks} ticks alternating with the bare chain:")
        print(f"  bare rclpy chain, {mode + ':':11s}  median {np.median(bare_us):6.0f} us/tick "
              f"(range {bare_us.min():.0f}-{bare_us.max():.0f})")
        ours_tick = np.median(ours_us) * 1e-6 + pure_tick  # wall per tick
        print(f"  ours, graph overhead:          median {np.median(ours_us):6.0f} us/tick "
              f"(range {ours_us.min():.0f}-{ours_us.max():.0f})   RTF {dt / ours_tick:6.3f}   "
              f"ROS/pure {ours_tick / pure_tick:6.1f}   ours/bare topology {np.median(ours_us) / (topo[mode] / n * 1e6):5.2f}")
        print(f"  ours/bare chain per pair:      median {medians[mode]:5.2f}  quartiles {q1:.2f}-{q3:.2f}  "
              f"range {ratio.min():.2f}-{ratio.max():.2f}")
        total_b, total_o = sum(cpu_bare.values()), sum(cpu_ours.values())
        print(f"  CPU, every process of a graph: bare {total_b:6.0f} us/tick, ours {total_o:6.0f} us/tick "
              f"({total_o / total_b:.2f}x); one tick's wall: bare {np.median(bare_us):.0f}, ours {np.median(ours_us):.0f} us")
        for name, tally in (("bare", cpu_bare), ("ours", cpu_ours)):
            print(f"    {name} by process (us/tick): " + ", ".join(f"{k} {v:.0f}" for k, v in tally.items()))
    r = ros_run(["--single-process", "--no-intra-process"], a.duration)
    print(f"lockstep, --single-process --no-intra-process: wall {r['wall_s']:7.2f} s   RTF {r['real_time_factor']:6.3f}   "
          f"ROS/pure {r['wall_s'] / pure:6.1f}   "
          f"graph overhead {(r['wall_s'] - pure) / n * 1e6:6.0f} us/tick   ours/bare topology {r['wall_s'] / topo['single']:5.2f}")
    for mode, med in medians.items():
        print(f"ours/bare chain, {mode + ':':11s} median {med:5.2f} over {a.segments} pairs   target <= 1.2")
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
