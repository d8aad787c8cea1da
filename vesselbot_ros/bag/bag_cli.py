"""``vesselbot bag info DIR`` and ``vesselbot bag repair DIR``."""

from __future__ import annotations

import argparse
import json

__all__ = ["register", "run"]


def register(parser: argparse.ArgumentParser) -> None:
    """Add the ``info`` and ``repair`` sub-commands."""
    sub = parser.add_subparsers(dest="bag_command", metavar="{info,repair}", required=True)
    p = sub.add_parser("info", help="topics, counts, coverage, scenario, seed and the run's key settings; checks "
                                    "metadata vs MCAP (--full: also the run's whole config)",
                       description="What a bag holds: the scenario, seed and mode, the settings that tell runs apart "
                                   "(loop, hardware, vessel), the command, the duration and sim-time coverage, the "
                                   "topics with their message counts, and whether metadata.yaml matches the MCAP; "
                                   "exit 1 if it does not.  --full adds the files, start and end times, chunks, "
                                   "versions and the run's whole config.")
    p.add_argument("bag", help="bag directory")
    p.add_argument("--full", action="store_true",
                   help="also print the files, start and end times, chunks, versions and the run's whole config")
    p.add_argument("--json", action="store_true", help="print JSON instead of text (everything, the config included)")
    p.add_argument("--no-config", action="store_true", help="with --full: leave the run's config out")
    r = sub.add_parser("repair", help="rebuild metadata.yaml (and a complete MCAP) after a hard kill")
    r.add_argument("bag", help="bag directory")
    r.add_argument("--force", action="store_true", help="rebuild even if the bag already validates")


def run(args: argparse.Namespace) -> int:
    """Run ``bag info`` / ``bag repair``; exit 1 if ``info`` finds an inconsistent bag."""
    # deferred: the bag modules pull in numpy, yaml and rosbags (~0.1 s); `vesselbot bag --help` imports this module
    from vesselbot_ros.bag.reader import open_bag

    if args.bag_command == "info":
        from vesselbot_ros.bag.info import format_info, info_dict  # deferred: see open_bag above

        info = open_bag(args.bag)
        if args.json:
            print(json.dumps(info_dict(info), indent=2, sort_keys=True))
        else:
            print(format_info(info, full=args.full, show_config=not args.no_config))
        return 0 if info.consistent else 1
    from vesselbot_ros.bag.info import coverage  # deferred: see open_bag above
    from vesselbot_ros.bag.repair import repair_bag  # deferred: see open_bag above

    res = repair_bag(args.bag, force=args.force)
    cov = coverage(open_bag(res.path))  # a repaired bag may end early: say how much of the run it holds
    span = f"  sim time: {cov.line()}" if cov is not None else "  sim time: no /clock recorded"
    if not res.repaired:
        print(f"{res.path}: already a valid bag ({res.message_count} messages); nothing to do (use --force to rebuild)")
        print(span)
        return 0
    if res.mcap_rewritten:
        print(f"{res.path}: rebuilt metadata.yaml and MCAP with {res.message_count} messages; "
              f"{res.dropped_bytes} trailing bytes were unreadable")
    else:
        print(f"{res.path}: the MCAP is intact ({res.message_count} messages); rebuilt metadata.yaml from it")
    print(span)
    for k in res.kept:
        print(f"  original kept as {k.name}")
    print("  run metadata: " + (f"from {res.run_metadata_from}" if res.run_metadata_from else "none found"))
    for name, n in sorted(res.counts.items()):
        print(f"  {name}: {n}")
    return 0
