"""``vesselbot run``: the paper's closed loop as a ROS 2 node graph, recorded, with a metrics summary.

Examples::

    vesselbot run                                   # paper scenario, lockstep, recorded to runs/
    vesselbot run --mode realtime --duration 5      # wall-clock plant, sim-time nodes
    vesselbot run --single-process --no-record      # all nodes in one process
    vesselbot run --without controller              # bring your own controller (see docs/graph.md)

Exit codes: 0 run completed; 1 a node died or a wait timed out (the message
names the node / what was awaited); 2 invalid configuration (nothing is
started and no directory is created); 130 interrupted (nodes stopped, bag
finalised).
"""

from __future__ import annotations

import argparse
import json
import platform
import signal
import sys
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from vesselbot_ros.config import ConfigError
from vesselbot_ros.errors import VesselbotError

__all__ = ["register", "run", "apply_overrides"]

DEFAULT_CONFIG = "config/paper_small_artery.yaml"
ROLES_CHOICES = ("plant", "imager", "observer", "controller", "coil_driver", "reference")


def register(parser: argparse.ArgumentParser) -> None:
    """Add the ``run`` arguments."""
    parser.add_argument("--config", default=DEFAULT_CONFIG, help=f"scenario YAML (default {DEFAULT_CONFIG})")
    parser.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep",
                        help="lockstep: deterministic, as fast as the graph allows; realtime: wall-clock plant")
    parser.add_argument("--duration", type=float, default=None, metavar="S", help="override sim.duration_s (s)")
    parser.add_argument("--seed", type=int, default=None, metavar="N", help="override the scenario seed")
    parser.add_argument("--real-time-factor", type=float, default=1.0, metavar="F",
                        help="sim seconds per wall second in realtime mode (default 1)")
    parser.add_argument("--without", action="append", default=[], choices=ROLES_CHOICES, metavar="NODE",
                        help=f"do not start NODE (one of {', '.join(ROLES_CHOICES)}); your own node takes its slot")
    parser.add_argument("--single-process", action="store_true", help="compose all nodes in one process")
    parser.add_argument("--no-record", action="store_true", help="do not record a bag")
    parser.add_argument("--record-dir", type=Path, default=None, metavar="DIR",
                        help="bag directory (default runs/<UTC time>_<scenario>)")
    parser.add_argument("--report", action="store_true", help="write the report (figures, metrics) from the bag")
    parser.add_argument("--domain-id", type=int, default=None, help="ROS domain id (default: lease a free one)")
    parser.add_argument("--wait-timeout", type=float, default=60.0, metavar="S",
                        help="bound on start-up waits, incl. a user's node for --without (default 60 s)")
    parser.add_argument("--run-timeout", type=float, default=None, metavar="S", help="bound on the run (wall s)")
    parser.add_argument("--stall-timeout", type=float, default=2.0, metavar="S",
                        help="lockstep: wall time before the coil driver's watchdog answers a silent tick")
    parser.add_argument("--metrics-json", type=Path, default=None, metavar="F",
                        help="also write the metrics (and run timing) to this JSON file")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def apply_overrides(mapping: dict[str, Any], duration: float | None, seed: int | None) -> dict[str, Any]:
    """Apply ``--duration`` / ``--seed`` to a scenario mapping (validated later)."""
    out = json.loads(json.dumps(mapping))
    if duration is not None:
        out.setdefault("sim", {})["duration_s"] = duration
    if seed is not None:
        out["seed"] = seed
    return out


def _versions() -> dict[str, str]:
    from importlib import metadata

    import vesselbot_ros

    out = {"vesselbot_ros": vesselbot_ros.__version__, "python": platform.python_version()}
    try:
        out["rclpy"] = metadata.version("ros-rclpy")
    except metadata.PackageNotFoundError:
        out["rclpy"] = "unknown"
    return out


def run(args: argparse.Namespace) -> int:
    """Run the graph (see module docstring)."""
    from vesselbot_ros.config import load_yaml
    from vesselbot_ros.sim.scenario import scenario_from_mapping

    # 1. validate everything before touching the disk or starting anything
    scenario = scenario_from_mapping(apply_overrides(load_yaml(args.config), args.duration, args.seed))
    if args.real_time_factor <= 0:
        raise ConfigError(f"--real-time-factor must be > 0, got {args.real_time_factor!r}")
    record = not args.no_record
    if record:
        import importlib.util

        if importlib.util.find_spec("vesselbot_ros.nodes.recorder_node") is None:
            raise VesselbotError("recording needs vesselbot_ros.nodes.recorder_node, which is not installed; "
                                 "use --no-record")
    stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    run_dir = args.record_dir or Path("runs") / f"{stamp}_{scenario.name}"
    if record:
        from vesselbot_ros.bag.writer import check_output_dir

        run_dir = check_output_dir(run_dir)  # clear error if unwritable or already a bag
    log_dir = (run_dir / "logs") if record else Path("runs") / "logs" / f"{stamp}_{scenario.name}"

    from vesselbot_ros.launch.graph import GraphOptions, NodeDied, run_graph

    metadata = {"scenario": scenario.name, "seed": scenario.seed, "mode": args.mode, "config": scenario.to_mapping(),
                "versions": _versions(), "command": list(sys.argv)}

    def progress(t_sim: float, duration: float, wall: float) -> None:
        if not args.quiet:
            print(f"  sim {t_sim:7.3f} / {duration:.3f} s   wall {wall:6.1f} s   RTF {t_sim / wall if wall else 0:5.2f}",
                  flush=True)

    def contract(text: str) -> None:
        print(text, flush=True)

    opts = GraphOptions(mode=args.mode, real_time_factor=args.real_time_factor, without=tuple(args.without),
                        single_process=args.single_process, record_dir=run_dir if record else None,
                        run_metadata=metadata, log_dir=log_dir, domain_id=args.domain_id,
                        wait_timeout_s=args.wait_timeout, run_timeout_s=args.run_timeout,
                        stall_timeout_s=args.stall_timeout, progress=progress, on_contract=contract)
    procs = "1 process" if args.single_process else "one process per node"
    print(f"vesselbot run: {scenario.name} seed {scenario.seed}, {args.mode}, {scenario.sim.duration_s} s at "
          f"{scenario.sim.control_rate_Hz:g} Hz, {procs}" + (f", recording to {run_dir}" if record else ""), flush=True)

    def on_term(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, on_term)
    try:
        result = run_graph(scenario, opts)
    except NodeDied as exc:
        print(f"vesselbot run: error: {exc}", file=sys.stderr)
        return 1
    except VesselbotError as exc:
        print(f"vesselbot run: error: {exc}", file=sys.stderr)
        return 1
    finally:
        signal.signal(signal.SIGTERM, old)
    _print_summary(result)
    if args.metrics_json is not None:
        payload = {"metrics": result.metrics, "wall_s": result.wall_s, "real_time_factor": result.real_time_factor,
                   "final": {k: [float(x) for x in result.timeseries[k][-1]] for k in ("p_true", "x_hat", "g_applied")}}
        args.metrics_json.write_text(json.dumps(payload, indent=2, default=float))
    if record:
        print(f"bag: {run_dir}")
        if args.report:
            try:
                from vesselbot_ros.bag.report import write_report
            except ImportError:
                print("vesselbot run: --report needs vesselbot_ros.bag.report, which is not installed", file=sys.stderr)
                return 1
            write_report(run_dir, after_s=scenario.sim.metrics_after_s)  # same window as the printed metrics
            print(f"report: {run_dir / 'report'}")
    elif args.report:
        print("vesselbot run: --report needs a recording (drop --no-record)", file=sys.stderr)
        return 1
    return 0


def _print_summary(result: Any) -> None:
    m = result.metrics
    print(f"run finished: {m['n_ticks']} ticks in {result.wall_s:.2f} s wall (RTF {result.real_time_factor:.2f})")
    for k, v in m.items():
        if isinstance(v, float):
            print(f"  {k:40s} {v:.6g}")
        else:
            print(f"  {k:40s} {v}")

