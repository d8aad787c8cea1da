"""``vesselbot run``: the paper's closed loop as a ROS 2 node graph, recorded, with a metrics summary.

Examples::

    vesselbot run                                   # sound Section III-C scenario, lockstep, recorded to runs/
    vesselbot run --mode realtime --duration 5      # wall-clock plant, sim-time nodes
    vesselbot run --single-process --no-record      # all nodes in one process
    vesselbot run --without controller              # bring your own controller (see docs/graph.md)

    vesselbot run --namespace robot2                # a second graph on the same domain, under /robot2

Exit codes: 0 run completed; 1 a node died, a wait timed out (the message
names the node / what was awaited), the bag does not hold what was published
(names topic and counts), or a real-time run missed more than 1 % of its
control periods or held an average real-time factor more than 1 % below
the one asked (states both figures apart: docs/graph.md), or the run
completed but cannot be trusted: the coil rejected commands (non-finite, a
controller that raised or returned no command, a diverged estimate, a wrong
frame from a user's node: the coil ramped to zero at the slew limit from each
such tick; ``rejected_commands`` and ``first_rejected_command_s`` in the
summary and ``--metrics-json``, one warning line), a lockstep tick had no
valid command in time (the coil driver's watchdog answered it:
``watchdog_ticks``, one warning line) or the run diverged; 2
invalid arguments or configuration (every argument is checked before
anything is started or any directory is created: one line naming it; a
plug-in stage kind is built once in the launcher, so a constructor that
raises is one line naming the kind and the exception, before any node
starts); 130 interrupted (SIGINT, SIGTERM or SIGHUP: nodes stopped, bag
finalised).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import platform
import re
import signal
import sys
from collections.abc import Sequence
from datetime import UTC, datetime
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

import vesselbot_ros
from vesselbot_ros.atomic_io import check_output_file, write_text
from vesselbot_ros.bag import derived_dir
from vesselbot_ros.bag.writer import COMPRESSION_PRESETS, check_output_dir
from vesselbot_ros.config import ConfigError
from vesselbot_ros.errors import ModelInputError, VesselbotError
from vesselbot_ros.graph_spec import LOOP_ROLES, SIMULATION_SERVICES, loop_roles, namespace_of, resolve, service
from vesselbot_ros.graph_spec import role as graph_role
from vesselbot_ros.ros_env import DOMAIN_MAX, allocate_domain

__all__ = ["register", "run", "check_plugin_stages"]

DEFAULT_CONFIG = "sound_small_artery"  # vesselbot_ros.sim.scenario.DEFAULT_SCENARIO, without importing the core
ROLES_CHOICES = LOOP_ROLES
_NAMESPACE_RE = re.compile(r"^/?[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*$")


def register(parser: argparse.ArgumentParser) -> None:
    """Add the ``run`` arguments."""
    parser.add_argument("--config", default=DEFAULT_CONFIG,
                        help=f"a shipped scenario's name (vesselbot scenarios) or a scenario YAML (default {DEFAULT_CONFIG})")
    parser.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep",
                        help="lockstep: deterministic, as fast as the graph allows; realtime: wall-clock plant")
    parser.add_argument("--duration", type=float, default=None, metavar="S", help="override sim.duration_s (s)")
    parser.add_argument("--seed", type=int, default=None, metavar="N", help="override the scenario seed")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scenario value, dotted key, YAML value (as vesselbot simulate; e.g. "
                             "controller.kind=predictive); applied after --hardware; repeatable")
    parser.add_argument("--hardware", default=None, metavar="PRESET",
                        help="fly on a scanner preset's gradient coil and sequence (e.g. clinical_3t; an unknown "
                             "name lists the presets); --set applies after it")
    parser.add_argument("--real-time-factor", type=float, default=1.0, metavar="F",
                        help="sim seconds per wall second in realtime mode (default 1)")
    parser.add_argument("--without", action="append", default=[], choices=ROLES_CHOICES, metavar="NODE",
                        help=f"do not start NODE (one of {', '.join(ROLES_CHOICES)}); your own node takes its slot")
    parser.add_argument("--single-process", action="store_true", help="compose all nodes in one process")
    parser.add_argument("--no-intra-process", dest="intra_process", action="store_false",
                        help="with --single-process: every message over DDS (default: co-located nodes hand "
                             "messages to each other in lockstep, DDS only for readers outside the process)")
    parser.add_argument("--no-record", action="store_true", help="do not record a bag")
    parser.add_argument("--record-dir", type=Path, default=None, metavar="DIR",
                        help="bag directory (default runs/<UTC time>_<scenario>); it holds the bag only: the node "
                             "logs go beside it to DIR.logs, --report to DIR.report")
    parser.add_argument("--compression", choices=tuple(_compression_choices()), default="none",
                        help="MCAP chunk compression of the bag: rosbag2's storage presets on Jazzy "
                             "(zstd_fast: fastest zstd, 768 KiB chunks; zstd_small: strongest zstd, 4 MiB chunks)")
    parser.add_argument("--start-paused", action="store_true",
                        help="start paused at t = 0: drive the run through the simulation_interfaces services "
                             "(/NAMESPACE/step_simulation, set_simulation_state, reset_simulation, ...)")
    parser.add_argument("--live", action="store_true",
                        help="serve every topic live over the Foxglove WebSocket protocol (open it in Foxglove with "
                             "the layout config/foxglove/vesselbot.json)")
    parser.add_argument("--live-port", type=int, default=None, metavar="N",
                        help="port of the live view (default 8765; 0: any free port, printed once it listens); "
                             "implies --live")
    parser.add_argument("--live-rate", type=float, default=None, metavar="HZ",
                        help="messages per topic and wall second sent to the live view, at most (default 50; 0: "
                             "every message of the 1 kHz loop)")
    parser.add_argument("--report", action="store_true", help="write the report (figures, metrics) from the bag")
    parser.add_argument("--domain-id", type=int, default=None, help="ROS domain id (default: lease a free one)")
    parser.add_argument("--wait-timeout", type=float, default=60.0, metavar="S",
                        help="bound on each wait for the graph: start-up (incl. a user's node for --without) and "
                             "wind-down (final diagnostics, series, recorder) (default 60 s)")
    parser.add_argument("--run-timeout", type=float, default=None, metavar="S", help="bound on the run (wall s)")
    parser.add_argument("--stall-timeout", type=float, default=2.0, metavar="S",
                        help="lockstep: wall time before the coil driver's watchdog answers a silent tick")
    parser.add_argument("--metrics-json", type=Path, default=None, metavar="F",
                        help="also write the metrics (and run timing) to this JSON file")
    parser.add_argument("--namespace", default=None, metavar="NAME",
                        help="put the graph under /NAME instead of /vesselbot (two graphs can share one domain)")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    parser.add_argument("--all-metrics", action="store_true",
                        help="print every metric in SI units after the run, not only the one-line result "
                             "(--metrics-json and the report's metrics.json hold them all either way)")


def _live_port(args: argparse.Namespace) -> int | None:
    """The live view's port, or None when the live view is off."""
    # deferred: the live view's modules (sockets, views: ~10 ms) are not needed by `vesselbot run --help`
    from vesselbot_ros.live import DEFAULT_LIVE_PORT

    if args.live_port is not None:
        return int(args.live_port)
    return DEFAULT_LIVE_PORT if args.live else None


def _compression_choices() -> list[str]:
    return list(COMPRESSION_PRESETS)


def _check_number(flag: str, value: float | None, *, positive: bool = True) -> None:
    if value is None:
        return
    if not math.isfinite(value) or (positive and value <= 0):
        raise ConfigError(f"{flag} must be a finite number > 0, got {value!r}")


def validate_args(args: argparse.Namespace) -> None:
    """Check every argument of ``vesselbot run`` that the scenario does not (raise ConfigError naming it)."""
    _check_number("--real-time-factor", args.real_time_factor)
    _check_number("--duration", args.duration)
    _check_number("--wait-timeout", args.wait_timeout)
    _check_number("--run-timeout", args.run_timeout)
    _check_number("--stall-timeout", args.stall_timeout)
    dup = sorted({r for r in args.without if args.without.count(r) > 1})
    if dup:
        raise ConfigError(f"--without {dup[0]} given more than once")
    if args.domain_id is not None and not 0 <= args.domain_id <= DOMAIN_MAX:
        raise ConfigError(f"--domain-id must be in [0, {DOMAIN_MAX}], got {args.domain_id}")
    if args.namespace is not None and not _NAMESPACE_RE.match(args.namespace):
        raise ConfigError(f"--namespace must be a ROS name (letters, digits, _; segments separated by /), "
                          f"got {args.namespace!r}")
    if args.live_port is not None and not 0 <= args.live_port <= 65535:
        raise ConfigError(f"--live-port must be in [0, 65535], got {args.live_port}")
    if args.live_rate is not None and not (math.isfinite(args.live_rate) and args.live_rate >= 0):
        raise ConfigError(f"--live-rate must be a finite number >= 0, got {args.live_rate!r}")
    if args.compression != "none" and args.no_record:
        raise ConfigError(f"--compression {args.compression} needs a recording (drop --no-record)")
    if args.report and args.no_record:
        raise ConfigError("--report needs a recording (drop --no-record)")
    if args.metrics_json is not None:
        parent = args.metrics_json.resolve().parent
        if not parent.is_dir():
            raise ConfigError(f"--metrics-json {args.metrics_json}: folder {parent} does not exist")
        if args.metrics_json.is_dir():
            raise ConfigError(f"--metrics-json {args.metrics_json} is a directory")
        check_output_file(args.metrics_json, "--metrics-json")  # a read-only place is refused now, not after the run


def check_graph_roles(scenario: Any, without: Sequence[str] = ()) -> None:
    """``--without ROLE`` names a role of this scenario's graph (the tracker joins it only with MR frames)."""
    from vesselbot_ros.sim.kinds import delivers_frames  # deferred: the core's registry (see check_plugin_stages)

    frames = delivers_frames(scenario)
    for r in without:
        if r not in loop_roles(frames):
            raise ConfigError(f"--without {r}: this scenario's graph has no {r} (imager.kind {scenario.imager.kind!r} "
                              "delivers positions; the tracker joins the graph with imager.kind mr_images)")


def check_plugin_stages(scenario: Any, without: Sequence[str] = ()) -> None:
    """Build, once and in this process, every stage of a user's kind (not built in) whose node the launcher starts.

    A node builds its stage when it starts; a user's constructor that raises would then end a run whose graph
    is already up.  Built here first, it is one line naming the kind and the exception (ConfigError: exit 2),
    before any node starts or any directory is made.  The built stages are thrown away.
    """
    # deferred: the core's registry and stage builder (numba); `vesselbot run --help` imports this module
    from vesselbot_ros.sim import kinds
    from vesselbot_ros.sim.closed_loop import build_stage

    for r in LOOP_ROLES:
        stage = graph_role(r).stage  # the graph spec's role -> stage name
        if r in without or stage not in kinds.SECTIONS:
            continue
        section = kinds.SECTIONS[stage]
        if kinds.find(stage, getattr(scenario, section).kind, f"{section}.kind").source != "built-in":
            build_stage(scenario, stage)  # kinds.build: a constructor's exception is a ConfigError naming the kind


def _versions() -> dict[str, str]:
    out = {"vesselbot_ros": vesselbot_ros.__version__, "python": platform.python_version()}
    try:
        out["rclpy"] = importlib_metadata.version("ros-rclpy")
    except importlib_metadata.PackageNotFoundError:
        out["rclpy"] = "unknown"
    return out


def run(args: argparse.Namespace) -> int:
    """Run the graph (see module docstring)."""
    # deferred: the scenario module pulls in the compiled core (numba); `vesselbot run --help` imports this module
    from vesselbot_ros.sim.scenario import check_resources, load_scenario

    # 1. validate everything before touching the disk or starting anything
    validate_args(args)
    # the one config path of every command: --set, --duration and --seed as vesselbot simulate applies them
    scenario = load_scenario(args.config, sets=args.set, duration=args.duration, seed=args.seed,
                             hardware=args.hardware)
    record = not args.no_record
    # a run that does not fit in memory or on disk is refused here, one line naming the keys
    check_resources(scenario, bag_dir=(args.record_dir or Path("runs")) if record else None)
    if scenario.physics.vessel.network:
        # a network's CFD field (a tree's flow and wall samples) is solved or built, or read from the cache, once,
        # here, before any node starts
        from vesselbot_ros.vessels.tree_field import packed_vessel  # deferred: the CFD stack, only for a network

        packed_vessel(scenario.physics, scenario.dims)
    check_graph_roles(scenario, args.without)
    check_plugin_stages(scenario, args.without)  # a user's kind that cannot be built: one line, nothing started
    if record and importlib.util.find_spec("vesselbot_ros.nodes.recorder_node") is None:
        raise VesselbotError("recording needs vesselbot_ros.nodes.recorder_node, which is not installed; "
                             "use --no-record")
    try:  # a busy --domain-id is a bad argument too: lease before anything is created
        # a chosen domain may hold graphs in other namespaces; a leased one is ours alone
        lease = allocate_domain(args.domain_id, namespace_of(args.namespace) if args.domain_id is not None else None)
    except VesselbotError:
        raise  # our errors are RuntimeErrors too: only the lease's own RuntimeError is about --domain-id
    except RuntimeError as exc:
        raise ConfigError(f"--domain-id: {exc}") from None
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    run_dir = args.record_dir or Path("runs") / f"{stamp}_{scenario.name}"
    if record:
        try:
            # clear error if unwritable or already a bag; its free space was checked above, by the one rule
            run_dir = check_output_dir(run_dir, min_free_bytes=0)
        except BaseException:
            lease.release()
            raise
    # beside the bag, not in it: the bag folder holds what rosbag2 writes (ros2 bag info, Foxglove see a clean bag)
    log_dir = derived_dir(run_dir, "logs") if record else Path("runs") / "logs" / f"{stamp}_{scenario.name}"

    # deferred: the launcher pulls in the compiled core and the node modules; `vesselbot run --help` imports this module
    from vesselbot_ros.launch.graph import GraphOptions, NodeDied, RecordingMismatch, run_graph

    metadata = {"scenario": scenario.name, "seed": scenario.seed, "mode": args.mode, "config": scenario.to_mapping(),
                "versions": _versions(), "command": list(sys.argv), "namespace": namespace_of(args.namespace),
                "compression": args.compression, "dims": scenario.dims}

    def progress(t_sim: float, duration: float, wall: float, status: str = "") -> None:
        if not args.quiet:
            print(f"  sim {t_sim:7.3f} / {duration:.3f} s   wall {wall:6.1f} s   RTF {t_sim / wall if wall else 0:5.2f}"
                  + (f"   {status}" if status else ""), flush=True)

    def contract(text: str) -> None:
        print(text, flush=True)

    def live(url: str) -> None:  # printed once the server accepts connections, with the port it bound
        print(f"live view: {url} (Foxglove: Open connection -> Foxglove WebSocket; "
              f"layout config/foxglove/vesselbot.json)", flush=True)

    def paused() -> None:  # printed once the run is paused and its services answer
        print("paused at t = 0; simulation_interfaces: " + ", ".join(resolve(service(k).rel, args.namespace)
                                                                     for k in SIMULATION_SERVICES), flush=True)

    opts = GraphOptions(mode=args.mode, real_time_factor=args.real_time_factor, without=tuple(args.without),
                        single_process=args.single_process, intra_process=args.intra_process, record_dir=run_dir if record else None,
                        run_metadata=metadata, log_dir=log_dir, domain_id=args.domain_id, lease=lease,
                        namespace=args.namespace,
                        wait_timeout_s=args.wait_timeout, run_timeout_s=args.run_timeout,
                        stall_timeout_s=args.stall_timeout, progress=progress, on_contract=contract,
                        compression=args.compression, live_port=_live_port(args), start_paused=args.start_paused,
                        live_rate_Hz=args.live_rate, on_live=live, on_paused=paused)
    procs = "1 process" if args.single_process else "one process per node"
    print(f"vesselbot run: {scenario.name} seed {scenario.seed}, {args.mode}, {scenario.sim.duration_s} s at "
          f"{scenario.sim.control_rate_Hz:g} Hz, {procs}" + (f", recording to {run_dir}" if record else ""), flush=True)

    def on_term(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    old = {sig: signal.signal(sig, on_term) for sig in (signal.SIGTERM, signal.SIGHUP)}
    try:
        result = run_graph(scenario, opts)
    except (ConfigError, ModelInputError):
        raise  # bad input: the CLI's one line and exit 2, not a failed run
    except (NodeDied, RecordingMismatch, VesselbotError) as exc:
        print(f"vesselbot run: error: {exc}", file=sys.stderr)
        return 1
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
    _print_summary(result, scenario.name, all_metrics=args.all_metrics)
    if args.metrics_json is not None:
        payload = {"metrics": result.metrics, "wall_s": result.wall_s, "real_time_factor": result.real_time_factor,
                   "final": {k: [float(x) for x in result.timeseries[k][-1]] for k in ("p_true", "x_hat", "g_applied")}}
        if result.realtime is not None:  # the same figures and verdict as the printed lines
            payload["real_time"] = result.realtime.as_dict()
        write_text(args.metrics_json, json.dumps(payload, indent=2, default=float))
    if record:
        print(f"bag: {run_dir}")
        if args.report:
            # deferred: the report draws with matplotlib (heavy) and is an optional part of an install
            try:
                from vesselbot_ros.bag.report import report_dir, write_report
            except ImportError:
                print("vesselbot run: --report needs vesselbot_ros.bag.report, which is not installed", file=sys.stderr)
                return 1
            write_report(run_dir, after_s=scenario.sim.metrics_after_s)  # same window as the printed metrics
            print(f"report: {report_dir(run_dir)}")
    rt = result.realtime
    if rt is not None:
        if rt.failed:
            print(f"vesselbot run: error: {rt.verdict_line()}", file=sys.stderr)
            _trust(result.metrics)  # rejected commands are said too: a real-time failure does not hide them
            return 1
        for line in rt.warnings:
            print(f"vesselbot run: warning: real time held, but {line}", file=sys.stderr)
    return _trust(result.metrics, lockstep_watchdog=args.mode == "lockstep")


def _trust(m: dict[str, Any], lockstep_watchdog: bool = False) -> int:
    """The run completed: 0, or 1 with one line per reason it cannot be trusted (diverged, commands rejected,
    lockstep ticks the coil driver's watchdog answered), as simulate."""
    from vesselbot_ros.sim.kinds import rejection_warning  # deferred: the core (see run)

    code = 0 if m.get("status", "ok") == "ok" else 1
    if m.get("diverged_at_s") is not None:  # it left the vessel (sim/metrics.py's rule)
        from vesselbot_ros.sim.metrics import status_line  # deferred: the core (see run)

        print(f"vesselbot: {status_line(m)}", file=sys.stderr)
    warning = rejection_warning(m)
    if warning:  # the coil rejected commands and ramped to zero: the run flew on no command
        print(f"vesselbot: warning: {warning}", file=sys.stderr)
        code = 1
    n_wd = int(m.get("watchdog_ticks") or 0)
    if lockstep_watchdog and n_wd > 0:  # no valid command came in time: the coil held, then ramped to zero
        print(f"vesselbot: warning: {n_wd} of {m.get('n_ticks', '?')} ticks got no valid controller command in "
              "time: the coil driver's watchdog answered them (held for coil.command_timeout_s of sim time, then "
              "ramped to zero)", file=sys.stderr)
        code = 1
    return code


def _print_summary(result: Any, name: str, *, all_metrics: bool = False) -> None:
    """The run's result as simulate prints it (one line, um), then the real-time figures; ``all_metrics``: every metric."""
    from vesselbot_ros.sim.metrics import headline  # deferred: the core (see run)

    m = result.metrics
    print(f"run finished: {m['n_ticks']} ticks in {result.wall_s:.3f} s wall (RTF {result.real_time_factor:.4g})")
    print(f"{name}: {headline(m)}")
    if all_metrics:
        for k, v in m.items():
            if isinstance(v, float):
                print(f"  {k:40s} {v:.6g}")
            elif v is None:  # a metric that does not apply to this run (diverged_at_s of a run that did not diverge)
                print(f"  {k:40s} -")
            else:
                print(f"  {k:40s} {v}")
    rt = result.realtime
    if rt is not None:
        print(f"real time: {rt.factor_text()}")
        print("real time, deadlines (a period is missed when its work ends more than one period late, or is skipped):")
        for st in rt.nodes:
            print(f"  {st.role:12s} missed {st.missed:6d} of {st.periods} periods ({100 * st.fraction:6.2f} %)   "
                  f"late by {st.lateness_mean_s * 1e3:7.3f} ms mean, {st.lateness_max_s * 1e3:8.2f} ms worst (wall)   "
                  f"input age max {st.input_age_max_s * 1e3:8.2f} ms, mean {st.input_age_mean_s * 1e3:7.2f} ms (sim)")
        print(f"real time: verdict: {'not held (' + ' and '.join(rt.reasons) + ')' if rt.failed else 'held'}")

