"""``vesselbot simulate``: run the ROS-free closed loop of a scenario.

Writes to ``--out`` (default ``out/simulate/<scenario>/``):

* ``metrics.json``: :func:`~vesselbot_ros.sim.metrics.compute_metrics` keys
  (SI units in the names) plus run statistics and the wall time;
* ``timeseries.npz``: one array per column of
  :mod:`vesselbot_ros.sim.closed_loop` (``t_s`` in s, positions in m,
  velocities in m/s, gradients in T/m, vectors as (n, 2) over (x, z));
* ``scenario.yaml``: the scenario as run (after ``--set`` overrides).

Exit codes: 0 the run completed; 1 it completed but its result cannot be
trusted: the coil rejected commands (non-finite, not a command, a controller
that raised, a non-finite estimate: ``rejected_commands`` in ``metrics.json``;
the coil ramped towards zero at the slew limit from each such tick), or the
run diverged (the bead or its estimate left the vessel:
``status: diverged`` and ``diverged_at_s``, :mod:`vesselbot_ros.sim.metrics`),
said in one warning line on stderr; 2 bad input (one error line).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from vesselbot_ros.atomic_io import atomic_path, check_output_dir, fmt_size, write_text
from vesselbot_ros.sim.closed_loop import prepared, run_closed_loop
from vesselbot_ros.sim.kinds import rejection_warning
from vesselbot_ros.sim.metrics import headline, metrics_window_note, status_line
from vesselbot_ros.sim.scenario import DEFAULT_SCENARIO, check_resources, load_scenario
from vesselbot_ros.vessels.cfd import womersley_numbers
from vesselbot_ros.vessels.network import load_network

__all__ = ["register", "run"]

#: Room for the outputs besides the time series (metrics.json, scenario.yaml), bytes.
OUTPUT_MARGIN_BYTES = 2**20


def register(parser: argparse.ArgumentParser) -> None:
    """Add the ``simulate`` arguments."""
    parser.add_argument("--config", default=DEFAULT_SCENARIO,
                        help=f"a shipped scenario's name (vesselbot scenarios) or a scenario YAML (default {DEFAULT_SCENARIO})")
    parser.add_argument("--seed", type=int, default=None, help="imager seed (default: the scenario's)")
    parser.add_argument("--duration", type=float, default=None, metavar="S", help="override sim.duration_s (s)")
    parser.add_argument("--out", default=None, help="output directory (default out/simulate/<scenario>/)")
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE",
        help="override a scenario value, dotted key, YAML value (e.g. imager.frame_rate_Hz=50); applied after "
             "--hardware; repeatable",
    )
    parser.add_argument("--path", default="auto", choices=("auto", "compiled", "per_tick"),
                        help="which loop runs: auto (compiled when every stage is built in), compiled, or per_tick "
                             "(the stages' Python methods, tick by tick: the same numbers, slower; for debugging)")
    parser.add_argument("--hardware", default=None, metavar="PRESET",
                        help="fly on a scanner preset's gradient coil and sequence (e.g. clinical_3t; an unknown "
                             "name lists the presets); --set applies after it")


def _wall_split(setup_s: float, wall_s: float) -> str:
    """Where the wall time went: the set-up (flow field, walls, stages) and the loop, in one phrase."""
    return f"set-up {setup_s:.2f} s incl. any CFD and wall build, loop {max(wall_s - setup_s, 0.0):.2f} s"


def run(args: argparse.Namespace) -> int:
    """Run the scenario and write metrics and time series; return 0, or 1 if commands were rejected."""
    scenario = load_scenario(args.config, sets=args.set, duration=args.duration, seed=args.seed,
                             hardware=args.hardware)
    est = check_resources(scenario)  # before any work: one line if the run does not fit in memory
    out = Path(args.out) if args.out else Path("out") / "simulate" / scenario.name
    # before any work too: a folder that cannot be written, or too little room for the outputs, is one line
    check_output_dir(out, "--out", need_bytes=est.memory_bytes + OUTPUT_MARGIN_BYTES,
                     need_why=f"{fmt_size(est.memory_bytes)} of time series at most, and 1 MiB for metrics.json and scenario.yaml")
    t0 = time.perf_counter()
    prepared(scenario)  # the set-up apart: the vessel's flow field and wall lookups (CFD, cached per machine), the stages
    setup = time.perf_counter() - t0
    result = run_closed_loop(scenario, path=args.path)
    wall = time.perf_counter() - t0
    metrics = dict(result.metrics, wall_time_s=wall, setup_wall_time_s=setup, loop_path=result.path)
    # each output whole or not at all (a full disk leaves the earlier files, never a 0-byte one)
    write_text(out / "metrics.json", json.dumps(metrics, indent=2, sort_keys=True) + "\n")
    with atomic_path(out / "timeseries.npz") as tmp:
        np.savez_compressed(tmp, **result.timeseries)  # type: ignore[arg-type]  # numpy's stub: a ** dict could hold allow_pickle
    write_text(out / "scenario.yaml", yaml.safe_dump(scenario.to_mapping(), sort_keys=False))
    m = metrics
    note = metrics_window_note(m, scenario.sim.metrics_after_s)
    if note:
        print(f"{scenario.name}: {note}")
    print(f"{scenario.name}: {headline(m)}; wall time {wall:.2f} s ({_wall_split(setup, wall)}, {result.path} loop) -> {out}")
    if scenario.physics.vessel.network:
        wo = womersley_numbers(load_network(scenario.physics.vessel.network), scenario.physics.blood,
                               scenario.physics.flow.angular_frequency_rad_per_s)
        print(f"{scenario.name}: Womersley numbers {min(wo.values()):.2f} to {max(wo.values()):.2f} "
              f"(quasi-steady flow field, docs/vessels.md)")
    if "branch_final" in m:
        target = m["route_outlet"] or "-"
        print(f"{scenario.name}: branch reached {m['branch_final']} (target {target}: "
              f"{'reached' if m['reached_target'] else 'NOT reached'}); outside the lumen {m['outside_lumen_time_s']:.3f} s")
    if m.get("diverged_at_s") is not None:  # it left the vessel (sim/metrics.py's rule): one line, exit 1
        print(f"vesselbot: {status_line(m)}", file=sys.stderr)
    warning = rejection_warning(m)
    if warning:  # the run completed, but it flew on rejected commands: exit 1 (module docstring)
        print(f"vesselbot: warning: {warning}", file=sys.stderr)
        return 1
    return 0 if m.get("status", "ok") == "ok" else 1
