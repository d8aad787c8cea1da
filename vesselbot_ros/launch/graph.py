"""Start, watch and stop the node graph; collect its time series and metrics.

:func:`run_graph` is what ``vesselbot run`` does, as a function:

1. lease a ROS domain, write the scenario as a ``--params-file``;
2. start the recorder first (unless disabled) and wait until it subscribes to
   every topic of :data:`vesselbot_ros.topics.TOPICS`;
3. start the nodes (one process each, or one composed process), wait until
   every node reports ``wired: true`` in its diagnostics (all its DDS
   endpoints matched) and, for a role left to the user (``without``), until
   some node publishes that role's outputs;
4. call RunControl START on the plant, then watch: node processes (a death
   ends the run at once and names the node), progress, the plant's
   ``finished`` flag;
   a node that dies upstream of the coil driver (imager, observer,
   controller, reference; one process per node) does not stop the graph at
   once: the launcher first lets the coil driver's watchdog bring the applied
   gradient to zero (its ``coil/state`` shows ``applied = 0`` with
   ``watchdog_active``), bounded by ``wait_timeout_s``, so the bag ends with
   the coil safe; then it stops everything and raises :class:`NodeDied`
   naming the node.  A dead plant (the clock: in lockstep no sim time passes
   without it, so there is no time in which to ramp), coil driver or recorder
   ends the run at once;
5. after the run, wait (bounded) until the recorder's ``received:<topic>``
   counts equal the publishers' ``published:<topic>`` counts, then stop the
   nodes with SIGINT and the recorder last;
6. rebuild the pure runner's time series from the monitored topics and
   compute the same metrics (:func:`vesselbot_ros.sim.metrics.compute_metrics`).

The launcher's own node (``vesselbot_launcher``) subscribes to truth,
estimate, reference, coil state and ``/diagnostics``; it is not part of the
loop, so it cannot slow it down beyond the DDS fan-out.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vesselbot_ros.errors import VesselbotError
from vesselbot_ros.nodes.params import scenario_to_parameters, write_params_file
from vesselbot_ros.ros_env import allocate_domain, apply_to_process, restore_process_env, ros_environment
from vesselbot_ros.sim.metrics import compute_metrics
from vesselbot_ros.sim.scenario import Scenario
from vesselbot_ros.topics import NODE_NAMES, TOPICS, topic

__all__ = ["ROLES", "GraphOptions", "GraphResult", "NodeDied", "run_graph", "role_contract"]

#: Node roles of the loop, in start order (the plant last: it owns the clock).
ROLES = ("reference", "imager", "observer", "controller", "coil_driver", "plant")
_MODULES = {r: f"vesselbot_ros.nodes.{r}_node" for r in ROLES}


class NodeDied(VesselbotError):
    """A node process exited before the run finished."""


@dataclasses.dataclass(frozen=True)
class GraphOptions:
    """How to run the graph.

    Attributes:
        mode: ``lockstep`` or ``realtime``.
        real_time_factor: Real-time mode only.
        without: Roles not started (a user's node fills the slot).
        single_process: Compose all nodes in one process.
        record_dir: Bag directory (None: do not record).
        run_metadata: JSON-able run description for the recorder.
        log_dir: Folder for node logs (ROS logs and each process's output).
        domain_id: ROS domain (None: lease a free one).
        wait_timeout_s: Bound on start-up waits (recorder, wiring, user nodes).
        run_timeout_s: Bound on the run itself (wall s; None: from the duration).
        stall_timeout_s: Lockstep coil-driver watchdog (wall s).
        progress: Called with (sim_time_s, duration_s, wall_s) about once a second.
        on_contract: Called with the contract text of each role left to the user.
    """

    mode: str = "lockstep"
    real_time_factor: float = 1.0
    without: tuple[str, ...] = ()
    single_process: bool = False
    record_dir: Path | None = None
    run_metadata: dict[str, Any] | None = None
    log_dir: Path | None = None
    domain_id: int | None = None
    wait_timeout_s: float = 60.0
    run_timeout_s: float | None = None
    stall_timeout_s: float = 2.0
    progress: Callable[[float, float, float], None] | None = None
    on_contract: Callable[[str], None] | None = None


@dataclasses.dataclass
class GraphResult:
    """What a run produced.

    Attributes:
        metrics: Same keys as the pure runner's ``SimResult.metrics``.
        timeseries: The metric columns rebuilt from the topics (n ticks).
        wall_s: Wall time from START to the last tick (s).
        real_time_factor: ``duration_s / wall_s``.
        diagnostics: Last diagnostics key/values per node name.
    """

    metrics: dict[str, Any]
    timeseries: dict[str, np.ndarray]
    wall_s: float
    real_time_factor: float
    diagnostics: dict[str, dict[str, str]]


# node role -> (topic keys it subscribes to, topic keys it publishes): the contract of a slot
CONTRACT = {
    "plant": (("coil_applied",), ("clock", "truth", "vessel_markers")),
    "imager": (("truth",), ("measurement",)),
    "observer": (("measurement", "coil_applied"), ("estimate",)),
    "controller": (("estimate", "reference"), ("gradient_command",)),
    "coil_driver": (("gradient_command", "clock"), ("coil_applied", "coil_state")),
    "reference": (("clock",), ("reference", "reference_path")),
}


def role_contract(role: str) -> str:
    """Human-readable topic contract of a role (what a user's replacement must do)."""
    subs, pubs = CONTRACT[role]
    lines = [f"slot '{role}' is yours: your node must"]
    for k in subs:
        t = topic(k)
        lines.append(f"  subscribe {t.name} [{t.msgtype}] ({t.units}, frame {t.frame})")
    for k in pubs:
        t = topic(k)
        lines.append(f"  publish   {t.name} [{t.msgtype}] {t.rate} ({t.units}, frame {t.frame})")
    lines.append("  with use_sim_time=true; QoS: reliable, keep last 100 (see docs/graph.md).")
    if role != "plant":
        lines.append("  Lockstep: answer tick k with header.stamp = t_k of the input that triggered it.")
    return "\n".join(lines)


class _Proc:
    """One child process with its log file."""

    def __init__(self, label: str, argv: Sequence[str], env: dict[str, str], log_path: Path) -> None:
        self.label = label
        self.log_path = log_path
        log_path.parent.mkdir(parents=True, exist_ok=True)
        self._log = open(log_path, "wb")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen(list(argv), env=env, stdout=self._log, stderr=subprocess.STDOUT,
                                     start_new_session=True)

    def poll(self) -> int | None:
        return self.proc.poll()

    def tail(self, n: int = 15) -> str:
        with contextlib.suppress(OSError):
            self._log.flush()
            lines = self.log_path.read_text(errors="replace").splitlines()
            return "\n".join(lines[-n:])
        return ""

    def signal(self, sig: int) -> None:
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                self.proc.send_signal(sig)

    def wait(self, timeout: float) -> int:
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGKILL)
            return self.proc.wait(timeout=10)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._log.close()


class _Monitor:
    """The launcher's own node: collects the time series and the diagnostics."""

    def __init__(self, context: Any, n: int) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import Odometry

        from vesselbot_msgs.msg import CoilState, PlantState, ReferenceSample
        from vesselbot_msgs.srv import RunControl
        from vesselbot_ros.nodes.base import make_executor
        from vesselbot_ros.topics import qos_profile

        self.n = n
        self.node = rclpy.create_node("vesselbot_launcher", context=context)
        self.ex = make_executor(context)
        self.ex.add_node(self.node)
        self.p_true = np.full((n, 2), np.nan)
        self.v_true = np.full((n, 2), np.nan)
        self.contact = np.zeros(n, dtype=bool)
        self.x_hat = np.full((n, 2), np.nan)
        self.z_hat = np.full((n, 2), np.nan)
        self.p_ref = np.full((n, 2), np.nan)
        self.g_applied = np.full((n, 2), np.nan)
        self.saturated = np.zeros(n, dtype=bool)
        self.slew = np.zeros((n, 2), dtype=bool)
        self.got = {"truth": 0, "estimate": 0, "reference": 0, "coil_state": 0}
        self.max_tick = -1
        # latest coil/state: (tick, applied (2,), watchdog_active)
        self.last_coil: tuple[int, tuple[float, float], bool] | None = None
        self.diag: dict[str, dict[str, str]] = {}
        self.diag_level: dict[str, tuple[int, str]] = {}
        self.t_first_truth: float | None = None
        self.t_last_truth: float | None = None
        self.dt = 0.0
        sub = self.node.create_subscription
        sub(PlantState, topic("truth").name, self._on_truth, qos_profile(topic("truth")))
        sub(Odometry, topic("estimate").name, self._on_estimate, qos_profile(topic("estimate")))
        sub(ReferenceSample, topic("reference").name, self._on_reference, qos_profile(topic("reference")))
        sub(CoilState, topic("coil_state").name, self._on_coil, qos_profile(topic("coil_state")))
        sub(DiagnosticArray, "/diagnostics", self._on_diag, qos_profile(topic("diagnostics")))
        self.run_control = self.node.create_client(RunControl, "/vesselbot/run_control")

    def _tick(self, stamp: Any) -> int | None:
        from vesselbot_ros.nodes.conversions import ns_of_stamp, tick_of_ns

        k, ok = tick_of_ns(ns_of_stamp(stamp), self.dt)
        return k if ok and 0 <= k < self.n else None

    def _on_truth(self, m: Any) -> None:
        k = int(m.tick)
        if not 0 <= k < self.n:
            return
        now = time.monotonic()
        if self.t_first_truth is None:
            self.t_first_truth = now
        self.t_last_truth = now
        self.p_true[k] = (m.position.x, m.position.z)
        self.v_true[k] = (m.velocity.x, m.velocity.z)
        self.contact[k] = m.in_contact
        self.got["truth"] += 1
        self.max_tick = max(self.max_tick, k)

    def _on_estimate(self, m: Any) -> None:
        k = self._tick(m.header.stamp)
        if k is not None:
            self.x_hat[k] = (m.pose.pose.position.x, m.pose.pose.position.z)
            self.z_hat[k] = (m.twist.twist.linear.x, m.twist.twist.linear.z)
            self.got["estimate"] += 1

    def _on_reference(self, m: Any) -> None:
        k = int(m.tick)
        if 0 <= k < self.n:
            self.p_ref[k] = (m.position.x, m.position.z)
            self.got["reference"] += 1

    def _on_coil(self, m: Any) -> None:
        k = int(m.tick)
        if 0 <= k < self.n:
            self.g_applied[k] = (m.applied.x, m.applied.z)
            self.saturated[k] = m.saturated
            self.slew[k] = (m.slew_limited_x, m.slew_limited_z)
            self.got["coil_state"] += 1
            if self.last_coil is None or k >= self.last_coil[0]:
                self.last_coil = (k, (float(m.applied.x), float(m.applied.z)), bool(m.watchdog_active))

    def _on_diag(self, m: Any) -> None:
        for st in m.status:
            self.diag[st.name] = {kv.key: kv.value for kv in st.values}
            self.diag_level[st.name] = (int.from_bytes(st.level, "little") if isinstance(st.level, bytes) else int(st.level), st.message)

    def spin(self, dt: float = 0.05) -> None:
        self.ex.spin_once(timeout_sec=dt)

    def recorder_subscribed(self) -> bool:
        name = NODE_NAMES["recorder"]
        return all(
            any(i.node_name == name for i in self.node.get_subscriptions_info_by_topic(t.name)) for t in TOPICS
        )

    def publishes(self, key: str) -> bool:
        return self.node.count_publishers(topic(key).name) > 0

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.ex.remove_node(self.node)
            self.ex.shutdown()
            self.node.destroy_node()


def _counts(diag: dict[str, str], prefix: str) -> dict[str, int]:
    return {k[len(prefix):]: int(v) for k, v in diag.items() if k.startswith(prefix)}


def run_graph(scenario: Scenario, options: GraphOptions) -> GraphResult:
    """Run the node graph on ``scenario`` (see module docstring).

    Raises:
        NodeDied: a node process exited before the end (names it, with its
            last output lines).
        VesselbotError: a bounded wait expired (says what was awaited).
        KeyboardInterrupt: on Ctrl-C, after stopping everything cleanly.
    """
    import rclpy

    from vesselbot_ros.nodes.base import GraphParams

    roles = [r for r in ROLES if r not in options.without]
    graph = GraphParams(mode=options.mode, real_time_factor=options.real_time_factor,  # type: ignore[arg-type]
                        stall_timeout_s=options.stall_timeout_s)
    lease = allocate_domain(options.domain_id)
    log_dir = Path(options.log_dir) if options.log_dir else Path.cwd() / "runs" / "logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    env = ros_environment(lease.domain_id, log_dir)
    params = scenario_to_parameters(scenario)
    params.update({f"graph.{f.name}": getattr(graph, f.name) for f in dataclasses.fields(GraphParams)})
    params_file = write_params_file(log_dir / "params.yaml", params)
    saved_env = apply_to_process(env)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=lease.domain_id, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    n = scenario.sim.n_ticks
    mon = _Monitor(context, n)
    mon.dt = scenario.sim.dt_control_s
    recorder: _Proc | None = None
    procs: list[_Proc] = []
    proc_roles: dict[str, list[str]] = {}
    finished_ok = False
    try:
        if options.record_dir is not None:
            from vesselbot_ros.nodes.recorder_node import recorder_command

            recorder = _Proc("recorder", recorder_command(options.record_dir, options.run_metadata), env,
                             log_dir / "recorder.log")
            _wait(lambda: mon.recorder_subscribed(), options.wait_timeout_s, mon, [recorder],
                  "the recorder to subscribe to every topic")
        ros_args = ["--ros-args", "--params-file", str(params_file)]
        if options.single_process:
            p = _Proc("composed", [sys.executable, "-m", "vesselbot_ros.launch.composed", "--roles", ",".join(roles),
                                   *ros_args], env, log_dir / "composed.log")
            procs.append(p)
            proc_roles["composed"] = list(roles)
        else:
            for r in roles:
                procs.append(_Proc(r, [sys.executable, "-m", _MODULES[r], *ros_args], env, log_dir / f"{r}.log"))
                proc_roles[r] = [r]
        for r in options.without:
            if options.on_contract is not None:
                options.on_contract(role_contract(r))

        def wired() -> bool:
            for r in roles:
                d = mon.diag.get(NODE_NAMES[r])
                if d is None or d.get("wired") != "true":
                    return False
                # every publisher matched every subscription the graph knows of (the recorder's too), so
                # no reader joins late and misses tick 0
                for key, val in d.items():
                    if key.startswith("matched_subscribers:") and int(val) < mon.node.count_subscribers(
                            key.split(":", 1)[1]):
                        return False
            return all(mon.publishes(k) for r in options.without for k in CONTRACT[r][1] if k != "reference_path"
                       and k != "vessel_markers")

        _wait(wired, options.wait_timeout_s, mon, procs + ([recorder] if recorder else []),
              "every node to be wired (all publishers and subscriptions matched)" +
              (f" and a node to take the slot(s) {list(options.without)}" if options.without else ""))
        _wait(lambda: mon.publishes("truth") and mon.node.count_subscribers(topic("estimate").name) > 0
              and mon.run_control.service_is_ready(), options.wait_timeout_s, mon, procs, "the plant's RunControl service")
        from vesselbot_msgs.srv import RunControl

        fut = mon.run_control.call_async(RunControl.Request(command=RunControl.Request.START))
        _wait(fut.done, options.wait_timeout_s, mon, procs, "RunControl START")
        t_start = time.monotonic()
        duration = n * scenario.sim.dt_control_s
        timeout = options.run_timeout_s
        if timeout is None:
            timeout = 120.0 + (duration / options.real_time_factor if options.mode == "realtime" else 200.0 * duration)
        last_progress = t_start
        plant_name = NODE_NAMES["plant"]
        while True:
            mon.spin(0.05)
            try:
                _check_alive(procs + ([recorder] if recorder else []), proc_roles)
            except NodeDied as died:
                dead = next(p for p in procs + ([recorder] if recorder else []) if p.poll() is not None)
                if dead.label in SAFE_STOP_ROLES and "coil_driver" in roles and "plant" in roles:
                    _safe_stop(died, dead, mon, [p for p in procs if p is not dead] + ([recorder] if recorder else []),
                               proc_roles, options.wait_timeout_s, scenario.sim.dt_control_s)
                raise
            plant_done = mon.diag.get(plant_name, {}).get("finished") == "true" if "plant" in roles else False
            if plant_done or (mon.got["truth"] >= n and "plant" not in roles):
                break
            now = time.monotonic()
            if options.progress is not None and now - last_progress >= 1.0:
                last_progress = now
                options.progress((mon.max_tick + 1) * scenario.sim.dt_control_s, duration, now - t_start)
            if now - t_start > timeout:
                raise VesselbotError(f"the run did not finish within {timeout:.0f} s (wall); reached tick {mon.max_tick}")
        t_end = mon.t_last_truth or time.monotonic()
        wall = t_end - (mon.t_first_truth or t_start)
        # all per-tick messages at the monitor, and (if recording) at the recorder
        if options.mode == "lockstep":
            _wait(lambda: mon.got["coil_state"] >= n and mon.got["estimate"] >= n and mon.got["reference"] >= n
                  and mon.got["truth"] >= n, 30.0, mon, procs, "the last messages of the run at the launcher")
        else:  # real time: no per-tick guarantee, and only the plant marks itself finished.  With
            # /clock stopped nothing publishes any more; after one full diagnostics period (~1 Hz)
            # every node's published counts are final.
            grace = time.monotonic() + (1.5 if recorder is not None else 0.5)
            while time.monotonic() < grace:
                mon.spin(0.05)
        if recorder is not None:
            _wait(lambda: _recorder_caught_up(mon, roles, require_finished=options.mode == "lockstep"), 30.0,
                  mon, procs + [recorder], "the recorder's received counts to match the published counts")
        finished_ok = True
        diagnostics = dict(mon.diag)
    finally:
        interrupted = sys.exc_info()[0] is KeyboardInterrupt
        if recorder is not None and not finished_ok and not interrupted and recorder.poll() is None:
            # a node died (or a wait timed out): before stopping anything, let the recorder catch
            # up with every per-tick message the launcher itself received, so the bag holds the
            # run up to that moment (including the watchdog's ramp to zero)
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline and not _recorder_has_seen(mon):
                with contextlib.suppress(Exception):
                    mon.spin(0.05)
        for p in procs:
            p.signal(signal.SIGINT)
        for p in procs:
            p.wait(10.0)
            p.close()
        if recorder is not None:
            # let the recorder take the nodes' final diagnostics, then finalise the bag
            deadline = time.monotonic() + 0.5
            while time.monotonic() < deadline:
                with contextlib.suppress(Exception):
                    mon.spin(0.05)
            recorder.signal(signal.SIGINT)
            recorder.wait(30.0)
            recorder.close()
        mon.close()
        rclpy.try_shutdown(context=context)
        restore_process_env(saved_env)
        lease.release()
        if interrupted:
            print("vesselbot run: interrupted; nodes stopped" + (", bag finalised" if recorder else ""), file=sys.stderr)
    if not finished_ok:  # pragma: no cover - exceptions propagate above
        raise VesselbotError("run aborted")
    series = _series(mon, scenario)
    metrics: dict[str, Any] = dict(compute_metrics(series, scenario.sim.metrics_after_s))
    pd = diagnostics.get(plant_name, {})
    od = diagnostics.get(NODE_NAMES["observer"], {})
    idg = diagnostics.get(NODE_NAMES["imager"], {})
    metrics.update(scenario=scenario.name, seed=scenario.seed)
    from vesselbot_ros.nodes.plant_node import PLANT_STAT_NAMES

    for key, d in (*((name, pd) for name in PLANT_STAT_NAMES), ("observer_rhs_evals", od), ("measurements_used", od), ("measurements_rejected", od),
                   ("outlier_frames", idg)):
        if key in d:
            metrics[key] = int(d[key])
    return GraphResult(metrics, series, wall, duration / wall if wall > 0 else float("inf"), diagnostics)


def _series(mon: _Monitor, scenario: Scenario) -> dict[str, np.ndarray]:
    n = mon.n
    return {
        "t_s": np.arange(n) * scenario.sim.dt_control_s,
        "p_true": mon.p_true, "v_true": mon.v_true, "p_ref": mon.p_ref,
        "x_hat": mon.x_hat, "z_hat": mon.z_hat, "g_applied": mon.g_applied,
        "saturated": mon.saturated, "slew_limited": mon.slew, "in_contact": mon.contact,
    }


def _recorder_has_seen(mon: _Monitor) -> bool:
    """True once the recorder reports at least the per-tick messages the launcher's monitor got."""
    rec = mon.diag.get(NODE_NAMES["recorder"])
    if rec is None:
        return False
    received = _counts(rec, "received:")
    return all(received.get(topic(key).name, 0) >= n for key, n in mon.got.items())


def _recorder_caught_up(mon: _Monitor, roles: Sequence[str], require_finished: bool = True) -> bool:
    rec = mon.diag.get(NODE_NAMES["recorder"])
    if rec is None:
        return False
    received = _counts(rec, "received:")
    published: dict[str, int] = {}
    for r in roles:
        d = mon.diag.get(NODE_NAMES[r])
        if d is None or (require_finished and d.get("finished") != "true"):
            return False
        for t, c in _counts(d, "published:").items():
            published[t] = published.get(t, 0) + c
    return all(received.get(t, 0) >= c for t, c in published.items() if t != "/diagnostics")


#: Roles upstream of the coil driver: when one dies, the driver's watchdog ramps to zero before the stop.
SAFE_STOP_ROLES = ("imager", "observer", "controller", "reference")


def _safe_stop(died: NodeDied, dead: _Proc, mon: _Monitor, others: Sequence[_Proc], proc_roles: dict[str, list[str]],
               timeout: float, dt: float) -> None:
    """Keep the graph running until the coil driver's watchdog has brought the gradient to zero, then raise.

    Raises:
        NodeDied: always; the message names the dead node and says where the coil output ended.
    """
    k_death = mon.max_tick
    print(f"vesselbot run: node {dead.label} died (exit code {dead.poll()}) at tick {k_death} "
          f"(t = {k_death * dt:.3f} s); letting the coil driver's watchdog ramp the gradient to zero", file=sys.stderr,
          flush=True)
    deadline = time.monotonic() + timeout
    plant_name = NODE_NAMES["plant"]
    while time.monotonic() < deadline:
        mon.spin(0.05)
        _check_alive(others, proc_roles)
        lc = mon.last_coil
        if lc is not None and lc[0] > k_death and lc[2] and lc[1] == (0.0, 0.0):
            raise NodeDied(f"{died}\ncoil output ramped to zero by the driver's watchdog at tick {lc[0]} "
                           f"(t = {lc[0] * dt:.3f} s)") from None
        if mon.diag.get(plant_name, {}).get("finished") == "true":
            raise NodeDied(f"{died}\nthe run reached its end before the coil output was zero") from None
    raise NodeDied(f"{died}\nthe coil output did not reach zero within {timeout:.0f} s (wall)") from None


def _check_alive(procs: Sequence[_Proc], proc_roles: dict[str, list[str]]) -> None:
    for p in procs:
        code = p.poll()
        if code is not None:
            who = p.label if p.label not in proc_roles or proc_roles[p.label] == [p.label] else \
                f"{p.label} ({', '.join(proc_roles[p.label])})"
            raise NodeDied(f"node {who} died (exit code {code}) before the run finished; its last output:\n{p.tail()}")


def _wait(pred: Callable[[], bool], timeout: float, mon: _Monitor, procs: Sequence[_Proc], what: str) -> None:
    deadline = time.monotonic() + timeout
    labels = {p.label: [p.label] for p in procs}
    while not pred():
        _check_alive(procs, labels)
        if time.monotonic() > deadline:
            raise VesselbotError(f"timed out after {timeout:.0f} s waiting for {what}")
        mon.spin(0.05)
