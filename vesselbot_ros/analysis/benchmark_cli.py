"""``vesselbot benchmark``: a controller kind or a user's policy on each environment tier over fixed seeds.

Prints one row per (tier, controller): success, tracking error mean and worst, time outside the lumen and the
energy ``∫ |G|^2 dt`` (:mod:`vesselbot_ros.analysis.benchmark` defines each).  The shipped controllers (law (24)
with the scenario's observer, the EKF loop, ``predictive``) are the reference rows; ``--policy module:callable``
adds a row that runs the callable as the ``policy`` controller kind, with the numbers it has in the environment.
``--csv FILE`` also writes the rows.  An unknown tier or controller, a policy that does not load or malformed
seeds: one line, exit 2.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
from pathlib import Path

from vesselbot_ros.analysis.benchmark import CONTROLLERS, benchmark, format_table, parse_seeds
from vesselbot_ros.atomic_io import atomic_open
from vesselbot_ros.envs.registration import TIERS
from vesselbot_ros.errors import ConfigError


def register(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``vesselbot benchmark``."""
    parser.add_argument("--tiers", default=",".join(TIERS),
                        help=f"comma-separated tiers (default: all: {','.join(TIERS)})")
    parser.add_argument("--controllers", default=None,
                        help=f"comma-separated shipped controllers, or 'none' (default: {','.join(CONTROLLERS)})")
    parser.add_argument("--policy", default=None, metavar="MODULE:CALLABLE",
                        help="also run this policy (observation -> gradient, T/m) as the policy controller kind")
    parser.add_argument("--seeds", default="0-4", help="seeds as A-B or A,B,C (default 0-4)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scenario key in every run (e.g. sim.duration_s=0.5); repeatable")
    parser.add_argument("--workers", type=int, default=None,
                        help="parallel runs (threads; default: one per usable core)")
    parser.add_argument("--csv", default=None, metavar="FILE", help="also write the rows to this CSV file")


def run(args: argparse.Namespace) -> int:
    """Run the benchmark and print its table; exit 0."""
    seeds = parse_seeds(args.seeds)
    tiers = [t.strip() for t in str(args.tiers).split(",") if t.strip()]
    if not tiers:
        raise ConfigError("--tiers names no tier")
    if args.controllers is None:
        controllers = list(CONTROLLERS)
    elif args.controllers.strip() == "none":
        controllers = []
    else:
        controllers = [c.strip() for c in args.controllers.split(",") if c.strip()]
    unknown = [c for c in controllers if c not in CONTROLLERS]
    if unknown:
        raise ConfigError(f"--controllers: unknown controller {unknown[0]!r}; the shipped ones are "
                          f"{', '.join(CONTROLLERS)} (a policy: --policy module:callable)")
    if args.policy:
        controllers.append("policy")
    if not controllers:
        raise ConfigError("nothing to run: --controllers none and no --policy")
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {args.workers!r}")
    rows, notes = benchmark(tiers, controllers, seeds, policy=args.policy, sets=args.sets, workers=args.workers)
    print(format_table(rows), end="")
    for note in notes:
        print(note)
    if args.csv:
        fields = [f.name for f in dataclasses.fields(rows[0])] if rows else ["tier"]
        with atomic_open(Path(args.csv), newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=fields)
            w.writeheader()
            w.writerows(dataclasses.asdict(r) for r in rows)
        print(f"wrote {args.csv}")
    return 0
