"""Run the node graph: ``vesselbot run`` as a function (:func:`run_graph`).

1. lease a ROS domain (held by every child until the last one exits), write
   the scenario as a ``--params-file``;
2. start the recorder first (unless disabled) and wait until it subscribes to
   every topic of the graph spec; with the live view on, also until it reports
   (``/diagnostics``, ``live_url``) the address its server accepts connections on,
   and hand that address to ``on_live``;
3. start the nodes (one process each, or one composed process), wait until
   every node reports ``wired: true`` (all its DDS endpoints matched) and, for
   a role left to the user (``without``), until some node publishes that
   role's outputs;
4. call RunControl START on the plant, then watch (:mod:`~vesselbot_ros.launch.supervision`):
   a node process that dies ends the run and is named; a node that dies
   upstream of the coil driver first lets the driver's watchdog bring the
   gradient to zero; progress lines show the real-time figures;
5. after the run, wait (bounded) until the recorder received what every
   publisher published, stop the nodes, then the recorder (it finalises the
   bag), and compare the bag's per-topic counts with the published counts
   (:func:`check_recorded_counts`): any difference fails the run;
6. take the run's time series from the nodes that published them
   (``<role>/series``; a user's node's messages from the monitor) and
   compute the same metrics as the pure runner (:func:`vesselbot_ros.sim.metrics.compute_metrics`);
   in real-time mode, the average real-time factor held, each loop node's
   missed periods, lateness and input age, and the verdict (:class:`RealtimeReport`).

Processes, supervision and monitoring live in :mod:`~vesselbot_ros.launch.processes`,
:mod:`~vesselbot_ros.launch.supervision` and :mod:`~vesselbot_ros.launch.monitor`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from vesselbot_ros.bag.reader import open_bag
from vesselbot_ros.control.route import navigation_metrics
from vesselbot_ros.errors import BagError, RunError, VesselbotError
from vesselbot_ros.graph_spec import (
    NODE_NAMES,
    REALTIME_FACTOR_LIMIT,
    REALTIME_MISSED_LIMIT,
    ROLES,
    SLOT_SETTLE_S,
    TOPICS,
    diagnostic_counters,
    loop_roles,
    remap_args,
    role,
    role_contract,
    topic,
)
from vesselbot_ros.launch.monitor import Monitor
from vesselbot_ros.launch.supervision import NodeDied, Supervisor, wait_for
from vesselbot_ros.nodes.calls import Resend
from vesselbot_ros.nodes.graph_params import GraphParams
from vesselbot_ros.nodes.params import scenario_to_parameters, write_params_file
from vesselbot_ros.nodes.recorder_node import recorder_command
from vesselbot_ros.ros_env import DomainLease, allocate_domain, apply_to_process, restore_process_env, ros_environment
from vesselbot_ros.sim.kinds import delivers_frames
from vesselbot_ros.sim.metrics import compute_metrics
from vesselbot_ros.sim.scenario import Scenario

__all__ = ["GraphOptions", "GraphResult", "NodeDied", "RecordingMismatch", "RealtimeStats", "run_graph",
           "role_contract", "check_recorded_counts", "realtime_report", "RealtimeReport", "INTERRUPTED_GRACE_S",
           "rejection_reasons"]

#: Seconds an interrupted run (Ctrl-C, SIGTERM, SIGHUP) gives its nodes to exit after SIGINT, in all, before SIGKILL
#: (a finished run gives them 10 s); the recorder then finalises the bag.
INTERRUPTED_GRACE_S = 3.0


class RecordingMismatch(RunError):
    """The bag does not hold exactly what the publishers published."""


@dataclasses.dataclass(frozen=True)
class GraphOptions:
    """How to run the graph.

    Attributes:
        mode: ``lockstep`` or ``realtime``.
        real_time_factor: Real-time mode only.
        without: Roles not started (a user's node fills the slot).
        single_process: Compose all nodes in one process.
        intra_process: Composed, lockstep: co-located nodes hand messages to each other without DDS
            (:class:`vesselbot_ros.nodes.intra_process.IntraProcess`); False: every message over DDS.
        record_dir: Bag directory (None: do not record).
        run_metadata: JSON-able run description for the recorder.
        log_dir: Folder for node logs (ROS logs and each process's output).
        domain_id: ROS domain (None: lease a free one).
        lease: An already held lease (the CLI leases before it creates anything); overrides ``domain_id``.
        namespace: The graph's namespace (None: ``/vesselbot``).
        wait_timeout_s: Bound on each wait for the graph: at start-up (recorder, wiring, user nodes) and
            after the run (final diagnostics, run series, the recorder catching up; a loaded machine is slow).
        run_timeout_s: Bound on the run itself (wall s; None: from the duration).
        stall_timeout_s: Lockstep coil-driver watchdog (wall s).
        progress: Called with (sim_time_s, duration_s, wall_s, status) about once a second;
            ``status`` is the real-time figures (empty in lockstep).
        on_contract: Called with the contract text of each role left to the user.
        compression: MCAP chunk compression of the bag (``none``, ``zstd_fast``, ``zstd_small``).
        start_paused: Start the run paused at t = 0 (simulation_interfaces SetSimulationState PAUSED) instead
            of playing; ``vesselbot run`` then waits (no run timeout unless ``run_timeout_s``) until a client
            plays or steps it to the end, or quits it.
        live_port: Serve every topic live over the Foxglove WebSocket protocol on this port
            (None: off).  The recorder serves it (with no bag when ``record_dir`` is None).
        live_rate_Hz: Messages per topic and wall second sent to the live view, at most (0: all; None: default).
        on_live: Called with the live view's address (``ws://127.0.0.1:PORT``, the bound port, also for
            ``live_port`` 0) once its server accepts connections, before the nodes start.
        on_paused: Called once the run is paused at t = 0 (``start_paused``), its services ready.
    """

    mode: str = "lockstep"
    real_time_factor: float = 1.0
    without: tuple[str, ...] = ()
    single_process: bool = False
    intra_process: bool = True
    record_dir: Path | None = None
    run_metadata: dict[str, Any] | None = None
    log_dir: Path | None = None
    domain_id: int | None = None
    lease: DomainLease | None = None
    namespace: str | None = None
    wait_timeout_s: float = 60.0
    run_timeout_s: float | None = None
    stall_timeout_s: float = 2.0
    progress: Callable[..., None] | None = None
    on_contract: Callable[[str], None] | None = None
    compression: str = "none"
    live_port: int | None = None
    live_rate_Hz: float | None = None
    start_paused: bool = False
    on_live: Callable[[str], None] | None = None
    on_paused: Callable[[], None] | None = None


@dataclasses.dataclass(frozen=True)
class RealtimeStats:
    """Real-time figures of one loop node (its deadlines).

    Attributes:
        role: The node's role.
        missed: Control periods it missed (late by more than one period, or skipped).
        periods: Control periods of the run (ticks).
        input_age_max_s: Largest age of an accepted input (sim s).
        input_age_mean_s: Mean age of its accepted inputs (sim s).
        lateness_mean_s: Mean wall time by which its periods ended after they were due (s).
        lateness_max_s: Largest wall time by which a period ended after it was due (s).
    """

    role: str
    missed: int
    periods: int
    input_age_max_s: float
    input_age_mean_s: float
    lateness_mean_s: float = 0.0
    lateness_max_s: float = 0.0

    @property
    def fraction(self) -> float:
        """Missed fraction of the periods."""
        return self.missed / self.periods if self.periods else 0.0

    @property
    def late(self) -> bool:
        """True if the node missed more than :data:`REALTIME_MISSED_LIMIT` of its periods (fails the run)."""
        return self.fraction > REALTIME_MISSED_LIMIT

    def as_dict(self) -> dict[str, Any]:
        """JSON-able figures (``--metrics-json``)."""
        return dataclasses.asdict(self) | {"fraction": self.fraction, "late": self.late}


@dataclasses.dataclass(frozen=True)
class RealtimeReport:
    """What a real-time run held, two things apart, and the verdict that follows from them.

    1. The *average real-time factor held*: sim time the plant advanced (first
       to last tick it published) over the wall time that took.  The plant never
       runs ahead of its wall schedule, so this is at most the asked factor; a
       machine too slow for the asked factor lowers it.
    2. The *deadlines*: per loop node, the control periods it missed (its work
       for a tick ended more than one period after the tick was due, or it
       skipped the tick), its mean and worst lateness and its inputs' age.  A
       plant that falls behind catches up (up to 50 ticks at once), so short
       stalls miss deadlines while the average factor holds.

    The rule (``vesselbot run``'s exit code): the run fails (exit 1) if any loop
    node missed more than :data:`REALTIME_MISSED_LIMIT` (1 %) of its periods, or
    if the average factor held is below the asked one by more than
    :data:`REALTIME_FACTOR_LIMIT` (1 %) of it; missed periods within the limit
    are a warning (exit 0).

    Attributes:
        asked: The real-time factor asked.
        sim_s: Sim time advanced from the first to the last tick published (s).
        wall_s: Wall time from the first to the last tick published (s).
        nodes: Per loop node, its deadlines.
        window_monotonic_s: The launcher's ``time.monotonic()`` before it asked the run to start and when it saw
            the run end (the machine's CLOCK_MONOTONIC, the same in every process), so the window holds every tick:
            where to look in other measurements of the machine (a load monitor, a trace) for what happened meanwhile.
    """

    asked: float
    sim_s: float
    wall_s: float
    nodes: tuple[RealtimeStats, ...]
    window_monotonic_s: tuple[float, float] = (0.0, 0.0)

    @property
    def factor_held(self) -> float:
        """The average real-time factor held: ``sim_s / wall_s`` (0 if no time passed)."""
        return self.sim_s / self.wall_s if self.wall_s > 0 else 0.0

    @property
    def factor_short(self) -> bool:
        """True if the average factor held is below the asked one by more than the limit (fails the run)."""
        return self.factor_held < self.asked * (1.0 - REALTIME_FACTOR_LIMIT)

    @property
    def late_nodes(self) -> list[RealtimeStats]:
        """The nodes that missed more than the limit of their periods (each fails the run)."""
        return [st for st in self.nodes if st.late]

    @property
    def worst(self) -> RealtimeStats | None:
        """The node that missed the largest fraction of its periods (the first of equals)."""
        return max(self.nodes, key=lambda st: st.fraction) if self.nodes else None

    @property
    def failed(self) -> bool:
        """True if real time was not held: deadlines missed beyond the limit, or the average factor short."""
        return self.factor_short or bool(self.late_nodes)

    @property
    def reasons(self) -> list[str]:
        """Why the run failed, in the rule's words (empty: it held)."""
        return (["deadlines missed"] if self.late_nodes else []) + (["average factor short"] if self.factor_short else [])

    @property
    def warnings(self) -> list[str]:
        """Missed periods within the limit: one line per node that missed some (the run still holds)."""
        return [f"node {st.role} missed {st.missed} of {st.periods} control periods ({100 * st.fraction:.2f} %, "
                f"within the {100 * REALTIME_MISSED_LIMIT:g} % allowed), worst {st.lateness_max_s * 1e3:.2f} ms late"
                for st in self.nodes if st.missed and not st.late]

    def factor_text(self) -> str:
        """The average factor held against the asked one, with the digits that make it true."""
        ratio = 100 * self.factor_held / self.asked
        return (f"average real-time factor held {self.factor_held:.4f} of {self.asked:g} asked ({ratio:.2f} %, "
                f"at least {100 * (1 - REALTIME_FACTOR_LIMIT):g} % needed: {self.sim_s:.3f} s sim in "
                f"{self.wall_s:.4f} s wall)")

    def deadlines_text(self) -> str:
        """The deadlines of the worst node: missed periods and worst lateness."""
        st = self.worst
        if st is None:
            return "no loop node of ours reported its periods"
        return (f"node {st.role} missed {st.missed} of {st.periods} control periods ({100 * st.fraction:.2f} %, "
                f"at most {100 * REALTIME_MISSED_LIMIT:g} % allowed), worst {st.lateness_max_s * 1e3:.2f} ms late")

    def verdict_line(self) -> str:
        """``real time held`` or ``real time not held (reasons)``, then the deadlines, then the average factor."""
        head = f"real time not held ({' and '.join(self.reasons)})" if self.failed else "real time held"
        return f"{head}: deadlines: {self.deadlines_text()}; {self.factor_text()}"

    def as_dict(self) -> dict[str, Any]:
        """JSON-able report (``--metrics-json``'s ``real_time``): the figures, the limits and the verdict."""
        return {"asked": self.asked, "factor_held": self.factor_held, "sim_s": self.sim_s, "wall_s": self.wall_s,
                "missed_limit": REALTIME_MISSED_LIMIT, "factor_limit": REALTIME_FACTOR_LIMIT,
                "factor_short": self.factor_short, "failed": self.failed, "reasons": self.reasons,
                "verdict": self.verdict_line(), "nodes": [st.as_dict() for st in self.nodes],
                "window_monotonic_s": list(self.window_monotonic_s)}


@dataclasses.dataclass
class GraphResult:
    """What a run produced.

    Attributes:
        metrics: Same keys as the pure runner's ``SimResult.metrics``.
        timeseries: The metric columns rebuilt from the topics (n ticks).
        wall_s: Wall time from START to the last tick (s).
        real_time_factor: Sim time advanced over ``wall_s`` (first to last tick published).
        diagnostics: Last diagnostics key/values per node name.
        realtime: Real-time mode: the average factor held and each loop node's deadlines (:class:`RealtimeReport`).
        recorded_counts: Recorded runs: messages per topic in the bag.
    """

    metrics: dict[str, Any]
    timeseries: dict[str, np.ndarray]
    wall_s: float
    real_time_factor: float
    diagnostics: dict[str, dict[str, str]]
    realtime: RealtimeReport | None = None
    recorded_counts: dict[str, int] = dataclasses.field(default_factory=dict)

    @property
    def realtime_failed(self) -> bool:
        """True if real time was not held (:attr:`RealtimeReport.failed`)."""
        return self.realtime is not None and self.realtime.failed


def realtime_report(diag: Mapping[str, Mapping[str, str]], roles: tuple[str, ...] | list[str],
                    n_ticks: int) -> list[RealtimeStats]:
    """Per loop node: missed periods (incl. the ticks after its last period), lateness and input age, from diagnostics."""
    out = []
    inf = float("inf")
    for r in roles:
        d = diag.get(NODE_NAMES[r])
        if d is None:
            out.append(RealtimeStats(r, n_ticks, n_ticks, inf, inf, inf, inf))
            continue
        missed = int(d.get("missed_periods", "0"))
        last = int(d.get("period_tick", "-1"))
        missed += max(0, n_ticks - 1 - last)  # periods it never reached
        out.append(RealtimeStats(r, min(missed, n_ticks), n_ticks, float(d.get("input_age_max_s", "0")),
                                 float(d.get("input_age_mean_s", "0")), float(d.get("lateness_mean_s", "0")),
                                 float(d.get("lateness_max_s", "0"))))
    return out


def realtime_status(diag: Mapping[str, Mapping[str, str]], roles: tuple[str, ...] | list[str], dt: float) -> str:
    """One-line real-time figures for the progress line: the worst node's missed periods and input age."""
    worst: tuple[int, str] | None = None
    age = 0.0
    for r in roles:
        d = diag.get(NODE_NAMES[r], {})
        m = int(d.get("missed_periods", "0"))
        age = max(age, float(d.get("input_age_max_s", "0")))
        if worst is None or m > worst[0]:
            worst = (m, r)
    if worst is None:
        return ""
    return f"missed {worst[0]} ({worst[1]})   input age max {age * 1e3:.1f} ms"


def check_recorded_counts(published: Mapping[str, int], recorded: Mapping[str, int]) -> list[str]:
    """Differences between what was published and what the bag holds, one line per topic (empty: equal)."""
    problems = []
    for name in sorted(set(published) | set(recorded)):
        p, r = published.get(name), recorded.get(name, 0)
        if p is None:
            continue  # a topic only the bag knows (e.g. an extra topic): nothing to compare against
        if p != r:
            problems.append(f"{name}: published {p}, recorded {r}")
    return problems


def run_graph(scenario: Scenario, options: GraphOptions) -> GraphResult:
    """Run the node graph on ``scenario`` (see module docstring).

    Raises:
        NodeDied: a node process exited before the end (names it, with its last output lines).
        RecordingMismatch: the bag does not hold what was published (names topic and counts).
        RunError: a bounded wait expired (says what was awaited).
        KeyboardInterrupt: on Ctrl-C / SIGTERM / SIGHUP, after stopping everything cleanly.
    """
    # deferred: rclpy and the message packages load only once a graph runs; the module is imported ROS-free
    # (its exceptions and options: the CLI's error handling, tests)
    import rclpy

    frames = delivers_frames(scenario)  # an imager of MR frames: the tracker joins the loop
    roles = [r for r in loop_roles(frames) if r not in options.without]
    graph = GraphParams(mode=options.mode, real_time_factor=options.real_time_factor,  # type: ignore[arg-type]  # mode: checked
                        stall_timeout_s=options.stall_timeout_s)
    lease = options.lease if options.lease is not None else allocate_domain(options.domain_id)
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
    dt = scenario.sim.dt_control_s
    mon = Monitor(context, n, dt, options.namespace, options.without, scenario.dims, frames)
    sup = Supervisor(env, log_dir, lease.fds)
    finished_ok = False
    recorded: dict[str, int] = {}
    published: dict[str, int] | None = None
    series: dict[str, np.ndarray] = {}
    try:
        if options.record_dir is not None or options.live_port is not None:
            sup.start_recorder(recorder_command(options.record_dir, options.run_metadata, namespace=options.namespace,
                                                compression=options.compression, live_port=options.live_port,
                                                live_rate_Hz=options.live_rate_Hz,
                                                # the free space was checked before the run, by the one rule
                                                # (vesselbot_ros.sim.scenario.check_resources)
                                                min_free_mb=0))
            wait_for(mon.recorder_subscribed, options.wait_timeout_s, mon, sup, "the recorder to subscribe to every topic")
            if options.live_port is not None:
                wait_for(lambda: mon.recorder_live_url() is not None, options.wait_timeout_s, mon, sup,
                         "the recorder's live view to accept connections")
                if options.on_live is not None:
                    options.on_live(str(mon.recorder_live_url()))
        sup.start_nodes(roles, ["--ros-args", *remap_args(options.namespace), "--params-file", str(params_file)],
                        options.single_process, options.intra_process)
        for r in options.without:
            if options.on_contract is not None:
                options.on_contract(role_contract(r, options.namespace, frames))
        wait_for(lambda: _wired(mon, roles, options.without, frames), options.wait_timeout_s, mon, sup,
                 "every node to be wired (all publishers and subscriptions matched)" +
                 (f" and a node to take the slot(s) {list(options.without)}" if options.without else ""))
        wait_for(lambda: mon.run_control.service_is_ready()
                 and all(c.service_is_ready() for c in mon.series_clients.values()),
                 options.wait_timeout_s, mon, sup,
                 "the plant's RunControl service and every node's series service")
        if sup.recorder is not None:
            wait_for(mon.recorder_matched, options.wait_timeout_s, mon, sup,
                     "the recorder to match every publisher (else it drops their first messages)")
        t_asked = time.monotonic()  # before the run is asked to start: the window holds its first tick
        if options.start_paused:
            from simulation_interfaces.msg import SimulationState  # deferred: a message package (see rclpy above)

            wait_for(mon.set_simulation_state.service_is_ready, options.wait_timeout_s, mon, sup,
                     "the plant's simulation_interfaces services")
            req = mon.set_simulation_state.srv_type.Request()  # type: ignore[attr-defined]  # rclpy's SrvType stub has no Request
            req.state.state = SimulationState.STATE_PAUSED
            paused = Resend.service(mon.set_simulation_state, req)  # already paused: the same answer
            wait_for(paused.done, options.wait_timeout_s, mon, sup, "SetSimulationState PAUSED")
            if options.on_paused is not None:
                options.on_paused()
        else:
            from vesselbot_msgs.srv import RunControl  # deferred: a message package (see rclpy above)

            started = Resend.service(mon.run_control, RunControl.Request(command=RunControl.Request.START))
            wait_for(started.done, options.wait_timeout_s, mon, sup, "RunControl START")  # again: 'already started'
        t_start = time.monotonic()
        _watch(mon, sup, roles, options, scenario, t_start)
        t_end = time.monotonic()
        # every node's final counts, then the run's series from every node that publishes some
        wait_for(lambda: mon.published(roles, require_finished=True) is not None, options.wait_timeout_s, mon, sup,
                 "every node's final diagnostics")
        wall = mon.run_wall_s(t_end - t_start)
        if options.mode == "lockstep" and "plant" not in roles:
            wait_for(lambda: mon.user_counts[topic("truth").name] >= n, options.wait_timeout_s, mon, sup,
                     "the last truth of the user's plant at the launcher")
        mon.request_series()
        wait_for(mon.series_ready, options.wait_timeout_s, mon, sup, "every node's run series (<role>/series)")
        series = mon.series()
        if sup.recorder is not None:
            try:
                wait_for(lambda: _recorder_caught_up(mon, roles), options.wait_timeout_s, mon, sup,
                         "the recorder's received counts to match the published counts")
            except NodeDied:
                raise
            except VesselbotError as exc:
                gaps = check_recorded_counts(mon.published(roles) or {}, mon.recorder_received() or {})
                raise RecordingMismatch(f"{exc}: " + "; ".join(gaps)) from None
        published = mon.published(roles, require_finished=True)
        finished_ok = True
        diagnostics = dict(mon.diag)
    finally:
        interrupted = sys.exc_info()[0] is KeyboardInterrupt
        if sup.recorder is not None and not finished_ok and not interrupted and sup.recorder.poll() is None:
            # a node died (or a wait timed out): before stopping anything, let the recorder catch up with
            # what the launcher saw, so the bag holds the run up to that moment (incl. the watchdog's ramp)
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline and not _recorder_has_seen(mon, roles):
                with contextlib.suppress(Exception):
                    mon.spin(0.05)
        # interrupted (Ctrl-C, SIGTERM, SIGHUP): the user waits, and a node hung in its shutdown must not hold
        # the run past the promised 5 s (docs/faults_and_safety.md): a shorter grace, then SIGKILL
        sup.stop_nodes(INTERRUPTED_GRACE_S if interrupted else 10.0)
        if sup.recorder is not None:
            # let the recorder take the nodes' final diagnostics, then finalise the bag
            deadline = time.monotonic() + 0.5
            while time.monotonic() < deadline:
                with contextlib.suppress(Exception):
                    mon.spin(0.05)
            sup.stop_recorder(30.0)
        sup.kill_all()  # nothing may outlive the launcher
        mon.close()
        rclpy.try_shutdown(context=context)
        restore_process_env(saved_env)
        lease.release()
        if interrupted:
            print("vesselbot run: interrupted; nodes stopped" + (", bag finalised" if sup.recorder else ""),
                  file=sys.stderr)
    if not finished_ok:  # pragma: no cover - exceptions propagate above
        raise RunError("run aborted")
    if options.record_dir is not None and published is not None:
        recorded = _bag_counts(Path(options.record_dir))
        problems = check_recorded_counts(published, recorded)
        if problems:
            raise RecordingMismatch("the bag does not hold what was published: " + "; ".join(problems))
    series = {"t_s": np.arange(n) * dt, **series}
    metrics: dict[str, Any] = dict(compute_metrics(series, scenario.sim.metrics_after_s,
                                                   vessel_diameter_m=scenario.physics.vessel.diameter_m))
    metrics.update(scenario=scenario.name, seed=scenario.seed)
    if scenario.physics.vessel.network:
        metrics.update(navigation_metrics(scenario, series["t_s"], series["p_true"]))
    for r, keys in diagnostic_counters().items():
        d = diagnostics.get(NODE_NAMES[r], {})
        for key in keys:
            if key in d:
                metrics[key] = int(d[key])
    reasons = diagnostics.get(NODE_NAMES["tracker"], {}).get("imager_rejected_reasons")
    if reasons:  # why the tracker rejected frames, as the pure runner's metrics say it
        metrics["imager_rejected_reasons"] = reasons
    if metrics.get("rejected_commands"):  # counted from the coil's command_rejected flags; why, from the nodes
        metrics.update(rejection_reasons(diagnostics))
    sim_s = _run_sim_s(mon, diagnostics, n, dt)
    rtf = sim_s / wall if wall > 0 else float("inf")
    result = GraphResult(metrics, series, wall, rtf, diagnostics, recorded_counts=recorded)
    if options.mode == "realtime":
        result.realtime = RealtimeReport(options.real_time_factor, sim_s, wall,
                                         tuple(realtime_report(diagnostics, roles, n)), (t_asked, t_end))
    return result


#: The coil driver's input rejections of a command (``rejected_reason:<name>``) -> the warning line's words.
_DRIVER_REJECT_WORDS = {"non_finite": "non-finite", "wrong_frame_id": "wrong frame_id", "nonzero_y": "non-zero y"}


def rejection_reasons(diagnostics: Mapping[str, Mapping[str, str]]) -> dict[str, str]:
    """Why the run's commands were rejected, as the ROS-free runner's metrics say it (the warning line's words).

    ``rejected_command_reasons``: the controller node's rejections (the core's :data:`~vesselbot_ros.sim.kinds.REJECT_REASONS`
    words, in code order), or, with a user's node in the controller's slot, what the coil driver rejected (a
    non-finite value, a wrong frame_id, a non-zero y); ``rejected_command_error`` / ``rejected_command_malformed``: the first
    exception or malformed value the controller returned, when there was one.
    """
    from vesselbot_ros.sim.kinds import REJECT_REASONS  # deferred: the core's registry (this module loads ROS-free)

    ctl = diagnostics.get(NODE_NAMES["controller"], {})
    drv = diagnostics.get(NODE_NAMES["coil_driver"], {})
    names = {1: "nonfinite", 2: "nonfinite_estimate", 3: "raised", 4: "malformed"}  # controller_node.REJECT_NAMES
    words = [REJECT_REASONS[c] for c, name in names.items() if int(ctl.get(f"command_rejected:{name}", "0") or 0) > 0]
    for key, word in _DRIVER_REJECT_WORDS.items() if not ctl else ():  # our controller's NaN reach it too
        if int(drv.get(f"rejected_reason:{key}", "0") or 0) > 0:
            words.append(word)
    out = {"rejected_command_reasons": ", ".join(words)} if words else {}
    for key in ("rejected_command_error", "rejected_command_malformed"):
        if ctl.get(key):
            out[key] = ctl[key]
    return out


def _run_sim_s(mon: Monitor, diagnostics: Mapping[str, Mapping[str, str]], n: int, dt: float) -> float:
    """Sim time advanced from the first to the last tick published: the plant's own figure, else a user's truths."""
    d = diagnostics.get(NODE_NAMES["plant"], {})
    if "run_sim_s" in d:
        return float(d["run_sim_s"])
    count = mon.user_counts.get(topic("truth").name)
    return max(0, (count if count is not None else n) - 1) * dt


def _bag_counts(bag_dir: Path) -> dict[str, int]:
    """Messages per topic in the finalised bag; raises RecordingMismatch if its metadata and MCAP disagree."""
    try:
        info = open_bag(bag_dir)
    except BagError as exc:
        raise RecordingMismatch(f"the bag {bag_dir} is not readable after the run: {exc}") from None
    if not info.consistent:
        raise RecordingMismatch(f"the bag {bag_dir}: metadata and MCAP disagree: " + "; ".join(info.problems))
    return {t.name: int(t.count) for t in info.topics}


def _wired(mon: Monitor, roles: list[str], without: tuple[str, ...], frames: bool) -> bool:
    for r in roles:
        d = mon.diag.get(NODE_NAMES[r])
        if d is None or d.get("wired") != "true":
            return False
        # every publisher matched every subscription the graph knows of (the recorder's too), so
        # no reader joins late and misses tick 0
        for key, val in d.items():
            if key.startswith("matched_subscribers:"):
                name = key.split(":", 1)[1]
                t = next((t for t in _topics_by_name() if t.name == name), None)
                if t is not None and int(val) < mon.subscribers(t.key):
                    return False
    # a user's node in a slot: its subscriptions known and stable for a moment after its publishers were seen
    # (announced separately), so that the matches checked above include them
    return all(mon.slot_settled([k for k in role(r).outputs_for(frames) if topic(k).qos != "reliable_latched"],
                                SLOT_SETTLE_S) for r in without)


def _topics_by_name() -> tuple[Any, ...]:
    return TOPICS


def _watch(mon: Monitor, sup: Supervisor, roles: list[str], options: GraphOptions, scenario: Scenario,
           t_start: float) -> None:
    """Spin until the plant finished; name a dead node; progress lines about once a second."""
    n = scenario.sim.n_ticks
    dt = scenario.sim.dt_control_s
    duration = n * dt
    timeout = options.run_timeout_s
    if timeout is None and options.start_paused:
        timeout = float("inf")  # a paused run goes on as long as its client drives it
    if timeout is None:
        timeout = 120.0 + (duration / options.real_time_factor if options.mode == "realtime" else 200.0 * duration)
    last_progress = t_start
    plant_name = NODE_NAMES["plant"]
    while True:
        mon.spin(0.05)
        try:
            sup.check_alive()
        except NodeDied as died:
            dead = sup.dead()
            if dead is not None and dead.label in _safe_stop_roles() and "coil_driver" in roles and "plant" in roles:
                sup.safe_stop(died, dead, mon, options.wait_timeout_s, dt)
            raise
        plant_done = mon.diag.get(plant_name, {}).get("finished") == "true" if "plant" in roles else False
        if plant_done or ("plant" not in roles and mon.user_counts[topic("truth").name] >= n):
            return
        now = time.monotonic()
        if options.progress is not None and now - last_progress >= 1.0:
            last_progress = now
            status = realtime_status(mon.diag, roles, dt) if options.mode == "realtime" else ""
            options.progress((mon.max_tick + 1) * dt, duration, now - t_start, status)
        if now - t_start > timeout:
            raise RunError(f"the run did not finish within {timeout:.0f} s (wall); reached tick {mon.max_tick}")


def _safe_stop_roles() -> tuple[str, ...]:
    return tuple(r.name for r in ROLES if r.safe_stop)


def _recorder_caught_up(mon: Monitor, roles: list[str]) -> bool:
    received = mon.recorder_received()
    published = mon.published(roles, require_finished=True)
    if received is None or published is None:
        return False
    return all(received.get(t, 0) >= c for t, c in published.items())


def _recorder_has_seen(mon: Monitor, roles: list[str]) -> bool:
    """True once the recorder reports at least what the nodes' latest diagnostics say they published.

    After a node died the launcher follows the coil state itself (the watchdog's ramp): the recorder must
    also hold a coil state for every tick up to the last one the launcher saw.  The nodes' diagnostics
    come once a second and could predate the ramp's end, which a bag then lacked.
    """
    received = mon.recorder_received()
    lc = mon.last_coil
    if received is not None and lc is not None and received.get(topic("coil_state").name, 0) < lc[0] + 1:
        return False
    published = mon.published(roles)
    if received is None or published is None:
        return received is not None
    return all(received.get(t, 0) >= c for t, c in published.items())


