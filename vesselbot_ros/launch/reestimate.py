"""Re-run one node of a recorded lockstep run on the bag's inputs, tick by tick, and compare.

``vesselbot replay DIR --into observer`` (or ``controller``) starts a *fresh*
node (ours, or the user's ``--node-cmd``) in a leased ROS domain, configured
from the bag alone (``custom_data["vesselbot.run"]`` holds the scenario
config and seed), and feeds it the recorded inputs in lockstep order:

=============  ==============================================  =========================================
``--into``     fed per tick k (in this order)                    collected, compared with the recording
=============  ==============================================  =========================================
observer       ``/clock`` k, ``coil/applied`` k-1 (k > 0),       ``/vesselbot/estimate`` stamped t_k
               ``measurement`` k (the n-th recorded one)
controller     ``/clock`` k, ``reference`` k, ``estimate`` k     ``/vesselbot/gradient_command`` at t_k
=============  ==============================================  =========================================

Tick k+1 is fed only after the node answered tick k (bounded wait), so the
node sees exactly the input sequence of the recorded run.  Our nodes are
deterministic functions of that sequence: a lockstep bag replayed into a fresh
node of the same scenario gives the recorded outputs bit for bit (difference
0.0; the CDR doubles round-trip exactly).

The result is a new bag (default ``<DIR>.reestimate_<role>/``, beside the bag) holding the
fed inputs and the recorded output with their original log times, the new
output under ``/vesselbot/replay/<name>`` (log time = the recorded output's
+ 1 ns), and the node's ``/diagnostics``; plus ``comparison.json``.

:func:`plan_feed` (no rclpy) reads the bag into per-tick inputs;
:func:`compare_outputs` (no rclpy) computes the differences;
:func:`reestimate` does the whole job.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import json
import math
import os
import shlex
import shutil
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore

from vesselbot_ros.atomic_io import failure_reason, write_text
from vesselbot_ros.bag import derived_dir
from vesselbot_ros.bag.reader import BagInfo, iter_messages, open_bag
from vesselbot_ros.bag.replay import _import_type
from vesselbot_ros.bag.writer import BagWriter, check_output_dir
from vesselbot_ros.errors import BagError, OutputError, VesselbotError
from vesselbot_ros.graph_spec import REPLAY_PREFIX, TOPICS, qos_profile, resolve, role, tick_of_ns, topic
from vesselbot_ros.launch.processes import ChildProcess
from vesselbot_ros.nodes.graph_params import GraphParams
from vesselbot_ros.nodes.params import scenario_to_parameters, write_params_file
from vesselbot_ros.ros_env import allocate_domain, apply_to_process, restore_process_env, ros_environment
from vesselbot_ros.sim.scenario import scenario_from_mapping

__all__ = [
    "ROLES",
    "reestimate_dir",
    "RoleIO",
    "Recorded",
    "TickFeed",
    "FeedPlan",
    "Comparison",
    "ReestimateResult",
    "plan_feed",
    "output_values",
    "compare_outputs",
    "node_command",
    "reestimate",
    "replay_topic",
]

CLOCK = topic("clock").name
#: A node that publishes the output and subscribes to some inputs but not all
#: (e.g. an observer ignoring ``coil/applied``) is fed after this wall time (s).
PARTIAL_WIRING_GRACE_S = 3.0
#: Free space a result bag needs besides the source bag's size (bytes): the node's log, params and comparison.json.
REESTIMATE_HEADROOM_BYTES = 16 * 2**20
DIAGNOSTICS = topic("diagnostics").name
REPLAY_NS = resolve(REPLAY_PREFIX)


@dataclasses.dataclass(frozen=True)
class RoleIO:
    """What a role takes and gives in lockstep.

    Attributes:
        inputs: Topic keys fed each tick (see :data:`ROLES` for the order).
        output: Topic key of the answer to tick k (stamped t_k).
        fields: Names of the compared output values (see :func:`output_values`).
    """

    inputs: tuple[str, ...]
    output: str
    fields: tuple[str, ...]


#: Compared output values of each role ``replay --into`` can re-run (see :func:`output_values`).
_FIELDS: dict[str, tuple[str, ...]] = {
    "observer": ("x_hat_x_m", "x_hat_y_m", "x_hat_z_m", "z_hat_x_m_per_s", "z_hat_y_m_per_s", "z_hat_z_m_per_s",
                 "measurement_age_s"),
    "controller": ("u_x_T_per_m", "u_y_T_per_m", "u_z_T_per_m"),
}


def _role_io(name: str) -> RoleIO:
    """A role's lockstep inputs (feed order, ``/clock`` aside) and answer, from the graph spec."""
    r = role(name)
    return RoleIO(tuple(k for k in r.inputs if k != "clock"), r.outputs[0], _FIELDS[name])


ROLES: dict[str, RoleIO] = {name: _role_io(name) for name in _FIELDS}


def replay_topic(role: str) -> str:
    """Topic name of the re-computed output in the result bag, e.g. ``/vesselbot/replay/estimate``."""
    return f"{REPLAY_NS}/{topic(ROLES[role].output).name.rsplit('/', 1)[-1]}"


@dataclasses.dataclass(frozen=True)
class Recorded:
    """One recorded message: topic, type, log time (ns), CDR bytes."""

    topic: str
    msgtype: str
    log_time_ns: int
    data: bytes


@dataclasses.dataclass(frozen=True)
class TickFeed:
    """The inputs of tick k, in publication order, and the recorded answer.

    Attributes:
        k: Tick index (t_k = k * dt).
        clock: The recorded ``/clock`` of tick k (None: synthesised from t_k).
        inputs: Recorded input messages, published in this order.
        recorded_output: The recorded answer to tick k (None if the run had none).
    """

    k: int
    clock: Recorded | None
    inputs: tuple[Recorded, ...]
    recorded_output: Recorded | None


@dataclasses.dataclass(frozen=True)
class FeedPlan:
    """Everything needed to re-run a role on a bag.

    Attributes:
        role: ``observer`` or ``controller``.
        run_metadata: The bag's run description (scenario, seed, mode, config, ...).
        dt_s: Control period (s).
        n_ticks: Ticks of the recorded scenario.
        ticks: Ticks 0..m-1 whose inputs are all in the bag (m <= n_ticks).
        stop_reason: Why the plan ends before ``n_ticks`` ("" if it does not).
        recorded_types: Message type of every topic used (name -> ``pkg/msg/Name``).
        warnings: Signs of a lossy recording (fewer per-tick messages than
            ticks): measurements are assigned to ticks by order, so a lost one
            shifts the rest and the re-run differs from the recording.
    """

    role: str
    run_metadata: dict[str, Any]
    dt_s: float
    n_ticks: int
    ticks: tuple[TickFeed, ...]
    stop_reason: str
    recorded_types: dict[str, str]
    warnings: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class Comparison:
    """Re-computed vs recorded outputs.

    Attributes:
        compared: Ticks with both a recorded and a re-computed output.
        identical: Of those, ticks where every compared value is bit-identical.
        max_abs: Largest |new - recorded| per field (SI units, see
            :attr:`RoleIO.fields`); 0.0 when nothing differs.
        first_difference_tick: First tick with any difference (None if none).
        missing_recorded: Ticks answered by the node but absent from the recording.
    """

    compared: int
    identical: int
    max_abs: dict[str, float]
    first_difference_tick: int | None
    missing_recorded: int

    @property
    def max_abs_overall(self) -> float:
        """Largest difference over every field (mixed units; 0.0 means bit-identical)."""
        return max(self.max_abs.values(), default=0.0)


@dataclasses.dataclass(frozen=True)
class ReestimateResult:
    """What a re-run produced.

    Attributes:
        role: The role re-run.
        out_dir: The result bag.
        fed: Ticks fed.
        answered: Ticks the node answered (stamp t_k) within the timeout.
        planned: Ticks whose inputs the bag holds.
        comparison: Differences against the recording.
        error: Why feeding stopped early ("" when every planned tick was answered).
        wall_s: Wall time of the feeding loop (s).
        node_exit_code: The node process's exit code after SIGINT.
    """

    role: str
    out_dir: Path
    fed: int
    answered: int
    planned: int
    comparison: Comparison
    error: str
    wall_s: float
    node_exit_code: int | None


# --------------------------------------------------------------------------
# planning (no rclpy)
# --------------------------------------------------------------------------
def _tick_of_ns(ns: int, dt_s: float) -> int | None:
    """Tick of a stamp (:func:`~vesselbot_ros.graph_spec.tick_of_ns`), None if off the grid."""
    k, on_grid = tick_of_ns(ns, dt_s)
    return k if on_grid else None


def _stamp_ns(msg: Any) -> int:
    st = msg.clock if hasattr(msg, "clock") else msg.header.stamp
    return int(st.sec) * 1_000_000_000 + int(st.nanosec)


def plan_feed(bag: str | Path | BagInfo, role: str) -> FeedPlan:
    """Read a lockstep bag into the per-tick inputs of ``role`` (see module docstring).

    Measurements are assigned to ticks by order (the n-th belongs to tick n,
    as the lockstep protocol says); every other topic by its stamp (the first
    message of a tick wins, as in the live nodes).

    Raises:
        BagError: unknown role, no run metadata / config, a non-lockstep run,
            or an input topic missing from the bag.
        ConfigError: the recorded config does not validate.
    """
    if role not in ROLES:
        raise BagError(f"cannot re-run {role!r}: --into must be one of {sorted(ROLES)}")
    info = bag if isinstance(bag, BagInfo) else open_bag(bag)
    run = dict(info.run_metadata)
    if not isinstance(run.get("config"), Mapping):
        raise BagError(f"bag {info.path} has no run config (custom_data 'vesselbot.run'); "
                       f"--into needs a bag recorded by `vesselbot run`")
    if run.get("mode") != "lockstep":
        raise BagError(f"bag {info.path} was recorded in mode {run.get('mode')!r}; --into needs a lockstep run "
                       f"(its inputs are one message per tick)")
    scenario = scenario_from_mapping(run["config"])
    dt = float(scenario.sim.dt_control_s)
    n = int(scenario.sim.n_ticks)
    io = ROLES[role]
    in_names = [topic(k).name for k in io.inputs]
    out_name = topic(io.output).name
    missing = [t for t in in_names if info.topic(t) is None]
    if missing:
        raise BagError(f"bag {info.path} has no {', '.join(missing)}; cannot feed a {role}")
    wanted = [t for t in (CLOCK, *in_names, out_name) if info.topic(t) is not None]
    types = {t: info.topic(t).msgtype for t in wanted}  # type: ignore[union-attr]  # wanted: topics the bag has

    by_tick: dict[str, dict[int, Recorded]] = {t: {} for t in wanted}
    n_meas = 0
    meas_name = topic("measurement").name
    for m in iter_messages(info, topics=wanted):
        rec = Recorded(m.topic, m.msgtype, m.log_time_ns, m.data)
        if m.topic == meas_name:  # the n-th measurement belongs to tick n
            by_tick[m.topic].setdefault(n_meas, rec)
            n_meas += 1
            continue
        k = _tick_of_ns(_stamp_ns(m.decode()), dt)
        if k is not None and 0 <= k < n:
            by_tick[m.topic].setdefault(k, rec)

    ticks: list[TickFeed] = []
    stop = ""
    for k in range(n):
        inputs: list[Recorded] = []
        for key, name in zip(io.inputs, in_names):
            j = k - 1 if (role == "observer" and key == "coil_applied") else k
            if j < 0:
                continue
            got = by_tick[name].get(j)
            if got is None:
                stop = f"the bag has no {name} for tick {j} (t = {j * dt:.6f} s)"
                break
            inputs.append(got)
        if stop:
            break
        ticks.append(TickFeed(k, by_tick.get(CLOCK, {}).get(k), tuple(inputs), by_tick.get(out_name, {}).get(k)))
    warnings = []
    for name in (CLOCK, *in_names, out_name):
        t = info.topic(name)
        if t is not None and t.count < n:
            warnings.append(f"the bag holds {t.count} {name} messages for {n} ticks: the recording lost some or "
                            f"the run ended early" + ("; measurements are assigned to ticks by order, so the re-run "
                                                      "may differ" if name == meas_name else ""))
    return FeedPlan(role, run, dt, n, tuple(ticks), stop, types, tuple(warnings))


def output_values(role: str, msg: Any) -> np.ndarray:
    """The compared values of an output message (rclpy or rosbags object), in :attr:`RoleIO.fields` order."""
    if role == "observer":
        p, v = msg.pose.pose.position, msg.twist.twist.linear
        return np.array([p.x, p.y, p.z, v.x, v.y, v.z, msg.pose.covariance[35]], dtype=np.float64)
    if role == "controller":
        u = msg.vector
        return np.array([u.x, u.y, u.z], dtype=np.float64)
    raise BagError(f"unknown role {role!r}")


def compare_outputs(role: str, recorded: Mapping[int, np.ndarray], new: Mapping[int, np.ndarray]) -> Comparison:
    """Compare re-computed outputs with recorded ones, tick by tick.

    Args:
        role: ``observer`` or ``controller``.
        recorded: Tick -> values of the recorded output (:func:`output_values`).
        new: Tick -> values of the re-computed output.

    NaN in the same place on both sides counts as equal.
    """
    fields = ROLES[role].fields
    max_abs = dict.fromkeys(fields, 0.0)
    compared = identical = missing = 0
    first: int | None = None
    for k in sorted(new):
        if k not in recorded:
            missing += 1
            continue
        a, b = np.asarray(new[k], dtype=np.float64), np.asarray(recorded[k], dtype=np.float64)
        both_nan = np.isnan(a) & np.isnan(b)
        diff = np.where(both_nan, 0.0, np.abs(a - b))
        diff = np.where(np.isnan(diff), np.inf, diff)  # NaN on one side only
        compared += 1
        if np.all(diff == 0.0):
            identical += 1
        elif first is None:
            first = k
        for f, d in zip(fields, diff):
            max_abs[f] = max(max_abs[f], float(d))
    return Comparison(compared, identical, max_abs, first, missing)


def node_command(role: str, node_cmd: str | Sequence[str] | None, params_file: Path) -> list[str]:
    """The argv of the node under test.

    Args:
        role: ``observer`` or ``controller``.
        node_cmd: The user's command (a shell-like string or argv), or None
            for ours (``python -m vesselbot_ros.nodes.<role>_node``).  A
            leading ``python`` means this interpreter.  ``{params}`` in it is
            replaced by the scenario's ``--params-file``; without it,
            ``--ros-args --params-file <file>`` is appended.
        params_file: The ROS parameters file of the recorded scenario.

    Raises:
        BagError: an empty command.
    """
    if node_cmd is None:
        return [sys.executable, "-m", f"vesselbot_ros.nodes.{role}_node", "--ros-args", "--params-file",
                str(params_file)]
    argv = shlex.split(node_cmd) if isinstance(node_cmd, str) else list(node_cmd)
    if not argv:
        raise BagError("--node-cmd is empty")
    if argv[0] in ("python", "python3"):
        argv[0] = sys.executable
    if any("{params}" in a for a in argv):
        return [a.replace("{params}", str(params_file)) for a in argv]
    return [*argv, "--ros-args", "--params-file", str(params_file)]


# --------------------------------------------------------------------------
# feeding (rclpy)
# --------------------------------------------------------------------------
class _Feeder:
    """The replaying node: publishes the inputs, collects the answers."""

    def __init__(self, context: Any, plan: FeedPlan) -> None:
        # deferred: rclpy, the message packages and nodes.process (which imports rclpy); the planning and comparing
        # halves of this module run ROS-free
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rosgraph_msgs.msg import Clock

        from vesselbot_ros.nodes.process import make_executor

        self.plan = plan
        io = ROLES[plan.role]
        self.node = rclpy.create_node("vesselbot_replayer", context=context)
        self.ex = make_executor(context)
        self.ex.add_node(self.node)
        self.clock_pub = self.node.create_publisher(Clock, CLOCK, qos_profile(topic("clock")))
        self.pubs = {}
        for key in io.inputs:
            spec = topic(key)
            self.pubs[spec.name] = self.node.create_publisher(_import_type(spec.msgtype), spec.name, qos_profile(spec))
        out = topic(io.output)
        self.out_name = out.name
        self.out_cls = _import_type(out.msgtype)
        self.answers: dict[int, tuple[bytes, Any]] = {}
        self.extra_answers = 0
        self.diagnostics: list[tuple[int, bytes]] = []  # (index of the tick being fed, CDR)
        self.current = 0
        self.node.create_subscription(self.out_cls, out.name, self._on_output, qos_profile(out), raw=True)
        self.node.create_subscription(DiagnosticArray, DIAGNOSTICS, self._on_diag, qos_profile(topic("diagnostics")),
                                      raw=True)

    def _on_output(self, data: bytes) -> None:
        from rclpy.serialization import deserialize_message, serialize_message  # deferred: rclpy (see __init__)

        msg = deserialize_message(data, self.out_cls)
        k = _tick_of_ns(_stamp_ns(msg), self.plan.dt_s)
        if k is None or k in self.answers:
            self.extra_answers += 1
            return
        self.answers[k] = (serialize_message(msg), msg)  # re-serialised: no garbage padding bytes

    def _on_diag(self, data: bytes) -> None:
        # deferred: rclpy and a message package (see __init__)
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.serialization import deserialize_message, serialize_message

        msg = deserialize_message(data, DiagnosticArray)
        if any(st.name != "vesselbot_replayer" for st in msg.status):
            self.diagnostics.append((self.current, serialize_message(msg)))

    def wired(self) -> bool:
        """Every input has a subscriber and the output a publisher."""
        return (all(p.get_subscription_count() > 0 for p in self.pubs.values())
                and self.node.count_publishers(self.out_name) > 0)

    def partly_wired(self) -> bool:
        """The output has a publisher and some input a subscriber (a node may ignore an input)."""
        return (any(p.get_subscription_count() > 0 for p in self.pubs.values())
                and self.node.count_publishers(self.out_name) > 0)

    def unsubscribed(self) -> list[str]:
        return [n for n, p in self.pubs.items() if p.get_subscription_count() == 0]

    def spin(self, timeout_s: float) -> None:
        self.ex.spin_once(timeout_sec=timeout_s)

    def feed(self, tick: TickFeed) -> None:
        from rosgraph_msgs.msg import Clock  # deferred: a message package (see __init__)

        self.current = tick.k
        if tick.clock is not None:
            self.clock_pub.publish(tick.clock.data)
        else:
            c = Clock()
            c.clock.sec, c.clock.nanosec = divmod(int(round(tick.k * self.plan.dt_s * 1e9)), 1_000_000_000)
            self.clock_pub.publish(c)
        for rec in tick.inputs:
            self.pubs[rec.topic].publish(rec.data)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.ex.remove_node(self.node)
            self.ex.shutdown()
            self.node.destroy_node()


def _tail(path: Path, n: int = 15) -> str:
    with contextlib.suppress(OSError):
        return "\n".join(path.read_text(errors="replace").splitlines()[-n:])
    return ""


def reestimate_dir(bag_dir: str | Path, role: str) -> Path:
    """The default result bag of ``replay --into role``: ``<bag_dir>.reestimate_<role>``, beside the bag (never in it)."""
    return derived_dir(bag_dir, f"reestimate_{role}")


def reestimate(
    bag: str | Path | BagInfo,
    role: str,
    *,
    out_dir: str | Path | None = None,
    node_cmd: str | Sequence[str] | None = None,
    answer_timeout_s: float = 10.0,
    wait_timeout_s: float = 60.0,
    domain_id: int | None = None,
    log: Callable[[str], None] = lambda s: None,
) -> ReestimateResult:
    """Re-run ``role`` on a lockstep bag's inputs in a fresh node and compare (see module docstring).

    Args:
        bag: The recorded bag (directory or validated :class:`BagInfo`).
        role: ``observer`` or ``controller``.
        out_dir: The result bag (default ``<bag>.reestimate_<role>``, beside the bag); must not
            hold a bag yet.
        node_cmd: The node under test (see :func:`node_command`); None: ours.
        answer_timeout_s: Wall time to wait for the answer to each tick (s).
        wait_timeout_s: Wall time to wait for the node to start and match (s).
        domain_id: ROS domain (None: lease a free one).
        log: Receives progress lines.

    Returns:
        The result; ``error`` says why feeding stopped early (node died, a tick
        unanswered), in which case the bag holds what was collected.

    Raises:
        BagError: invalid bag, unusable output directory, bad arguments.
        VesselbotError: the node did not start or match within ``wait_timeout_s``.
    """
    import rclpy  # deferred: rclpy; the planning and comparing halves of this module run ROS-free

    if not answer_timeout_s > 0 or not wait_timeout_s > 0:
        raise BagError(f"timeouts must be > 0 s, got answer {answer_timeout_s}, wait {wait_timeout_s}")
    info = bag if isinstance(bag, BagInfo) else open_bag(bag)
    plan = plan_feed(info, role)
    if not plan.ticks:
        raise BagError(f"bag {info.path}: nothing to feed ({plan.stop_reason})")
    # the result bag re-records the fed inputs: about the source bag's size, plus the node's log and the comparison
    need = sum(p.stat().st_size for p in info.mcap_paths) + REESTIMATE_HEADROOM_BYTES
    out = check_output_dir(Path(out_dir) if out_dir is not None else reestimate_dir(info.path, role), min_free_bytes=need)
    log_dir = out / "logs"
    scenario = scenario_from_mapping(plan.run_metadata["config"])
    params = scenario_to_parameters(scenario)
    graph = GraphParams(mode="lockstep")
    params.update({f"graph.{f.name}": getattr(graph, f.name) for f in dataclasses.fields(GraphParams)})
    log_dir.mkdir(parents=True, exist_ok=True)
    params_file = write_params_file(log_dir / "params.yaml", params)
    argv = node_command(role, node_cmd, params_file)

    lease = allocate_domain(domain_id)
    env = ros_environment(lease.domain_id, log_dir)
    saved = apply_to_process(env)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=lease.domain_id, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    feeder: _Feeder | None = None
    node_log = log_dir / f"{role}.log"
    proc: ChildProcess | None = None
    error = ""
    fed = 0
    exit_code: int | None = None
    t_feed = 0.0
    try:
        feeder = _Feeder(context, plan)
        try:
            proc = ChildProcess(role, argv, env, node_log, hold_fds=lease.fds)
        except OSError as exc:
            raise BagError(f"cannot start the node {shlex.join(argv)}: {exc.strerror or exc}") from None
        log(f"started {role}: {shlex.join(argv)} (domain {lease.domain_id})")

        def died() -> str:
            code = proc.poll() if proc is not None else None
            return "" if code is None else (f"the {role} node exited with code {code}; its last output:\n"
                                            f"{_tail(node_log)}")

        deadline = time.monotonic() + wait_timeout_s
        partly_since: float | None = None
        while not feeder.wired():
            if died():
                raise VesselbotError(died())
            if feeder.partly_wired():
                partly_since = partly_since or time.monotonic()
                if time.monotonic() - partly_since > PARTIAL_WIRING_GRACE_S:
                    log(f"the {role} node does not subscribe to {', '.join(feeder.unsubscribed())}; feeding anyway")
                    break
            else:
                partly_since = None
            if time.monotonic() > deadline:
                raise VesselbotError(
                    f"timed out after {wait_timeout_s:.0f} s waiting for the {role} node to subscribe to "
                    f"{', '.join(feeder.pubs)} and publish {feeder.out_name}; its last output:\n{_tail(node_log)}")
            feeder.spin(0.05)
        # our side matched; give the node's side of DDS discovery a moment too
        settle = time.monotonic() + 0.5
        while time.monotonic() < settle:
            feeder.spin(0.05)

        t0 = time.monotonic()
        for tick in plan.ticks:
            feeder.feed(tick)
            fed += 1
            limit = time.monotonic() + answer_timeout_s
            while tick.k not in feeder.answers:
                if time.monotonic() > limit:
                    error = (f"the {role} node did not answer tick {tick.k} (t = {tick.k * plan.dt_s:.6f} s) within "
                             f"{answer_timeout_s:g} s; stopped there")
                    break
                msg = died()
                if msg:
                    error = msg
                    break
                feeder.spin(0.01)
            if error:
                break
        t_feed = time.monotonic() - t0
        # let late diagnostics in
        grace = time.monotonic() + 0.2
        while time.monotonic() < grace:
            feeder.spin(0.02)
    finally:
        if proc is not None:
            exit_code = proc.stop(10.0)
        answers = dict(feeder.answers) if feeder is not None else {}
        diags = list(feeder.diagnostics) if feeder is not None else []
        if feeder is not None:
            feeder.close()
        rclpy.try_shutdown(context=context)
        restore_process_env(saved)
        lease.release()

    # ---- compare
    ts = get_typestore(Stores.ROS2_JAZZY)
    out_type = plan.recorded_types.get(_out_name(role)) or _out_type(role)
    recorded_vals = {t.k: output_values(role, ts.deserialize_cdr(t.recorded_output.data, out_type))
                     for t in plan.ticks[:fed] if t.recorded_output is not None}
    new_vals = {k: output_values(role, msg) for k, (_, msg) in answers.items()}
    comparison = compare_outputs(role, recorded_vals, new_vals)
    answered = sum(1 for t in plan.ticks[:fed] if t.k in answers)
    if not error and plan.stop_reason:
        log(f"the bag's inputs end early: {plan.stop_reason}")
    for w in plan.warnings:
        log(f"warning: {w}")

    # ---- write the result bag
    metadata = dict(plan.run_metadata)
    summary = {
        "into": role, "source_bag": str(info.path), "node_command": argv, "ticks_planned": len(plan.ticks),
        "ticks_fed": fed, "ticks_answered": answered, "compared": comparison.compared,
        "identical": comparison.identical, "max_abs_difference": comparison.max_abs,
        "first_difference_tick": comparison.first_difference_tick, "error": error,
        "plan_stop_reason": plan.stop_reason, "plan_warnings": list(plan.warnings), "feed_wall_s": t_feed, "node_exit_code": exit_code,
    }
    summary["source_command"] = metadata.get("command")
    metadata["command"] = list(sys.argv)
    metadata["reestimate"] = summary
    entries: list[tuple[int, int, str, bytes]] = []  # (log time, order, topic, data)
    new_topic = replay_topic(role)
    tick_last_ns: dict[int, int] = {}
    for t in plan.ticks[:fed]:
        last = 0
        for rec in ((t.clock,) if t.clock is not None else ()) + t.inputs:
            entries.append((rec.log_time_ns, len(entries), rec.topic, rec.data))
            last = max(last, rec.log_time_ns)
        if t.recorded_output is not None:
            entries.append((t.recorded_output.log_time_ns, len(entries), t.recorded_output.topic,
                            t.recorded_output.data))
            last = max(last, t.recorded_output.log_time_ns)
        tick_last_ns[t.k] = last
        if t.k in answers:
            entries.append((last + 1, len(entries), new_topic, answers[t.k][0]))
    for k, data in diags:
        entries.append((tick_last_ns.get(k, 0) + 2, len(entries), DIAGNOSTICS, data))
    entries.sort()

    specs = {s.name: s for s in TOPICS}
    # the result bag whole or not at all: written in a work folder inside ``out`` (the MCAP keeps its name), then
    # its files are renamed in, metadata.yaml last; a full disk leaves ``out`` without a bag and no work folder
    work = out / f".result-{os.getpid()}" / out.name
    try:
        writer = BagWriter(work, run_metadata=metadata).open()
        try:
            conns: dict[str, Any] = {}
            for t_ns, _order, name, data in entries:
                if name not in conns:
                    msgtype = (_out_type(role) if name == new_topic
                               else plan.recorded_types.get(name) or specs[name].msgtype)
                    depth = specs[name].depth if name in specs else 100
                    conns[name] = writer.add_topic(name, msgtype, depth=depth)
                writer.write(conns[name], data, t_ns)
        except BaseException:
            writer.abort()
            raise
        writer.finish()
        for f in sorted(work.iterdir(), key=lambda f: f.name == "metadata.yaml"):
            f.replace(out / f.name)
    except (OSError, BagError) as exc:  # BagError: the writer's own wrapping of an OSError (could not finalise ...)
        why = (failure_reason(exc) if isinstance(exc, OSError) else str(exc)).replace(str(work), str(out))
        raise OutputError(getattr(exc, "errno", None) or errno.EIO,
                          f"cannot write the result bag {out} ({why}); no partial bag was left (the node's log is "
                          f"in {out / 'logs'})", str(out)) from None
    finally:
        shutil.rmtree(work.parent, ignore_errors=True)
    write_text(out / "comparison.json", json.dumps(_jsonable(summary), indent=2, sort_keys=True) + "\n")
    return ReestimateResult(role, out, fed, answered, len(plan.ticks), comparison, error, t_feed, exit_code)


def _out_name(role: str) -> str:
    return topic(ROLES[role].output).name


def _out_type(role: str) -> str:
    return topic(ROLES[role].output).msgtype


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    return x
