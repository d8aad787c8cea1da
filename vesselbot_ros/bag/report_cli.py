"""``vesselbot report DIR [--out OUT] [--after S]``: figures and metrics JSON from a bag alone, into ``DIR.report/``."""

from __future__ import annotations

import argparse

__all__ = ["register", "run"]


def register(parser: argparse.ArgumentParser) -> None:
    """Add the report arguments."""
    parser.add_argument("bag", help="bag directory")
    parser.add_argument("--out", help="output folder (default: <bag>.report, beside the bag folder, which holds "
                                      "the bag only)")
    parser.add_argument("--after", type=float, default=None, metavar="S",
                        help="start of the steady-state window of the metrics, s "
                             "(default: the run's sim.metrics_after_s, else 0.6 as in the paper)")


def run(args: argparse.Namespace) -> int:
    """Write the report; print where and the headline metrics."""
    # deferred: the report pulls in the bag reader and the compiled core (~0.4 s); `vesselbot report --help` imports this module
    from vesselbot_ros.bag.report import FIGURES, report_dir, write_report

    metrics = write_report(args.bag, args.out, after_s=args.after)
    out = report_dir(args.bag, args.out)
    print(f"report written to {out}: {', '.join(FIGURES)}, metrics.json")
    after = metrics["after_s"]
    print(f"  the bag {metrics['coverage']}")
    if metrics.get("metrics_window_note"):
        print(f"  {metrics['metrics_window_note']}")
    print(f"  tracking error after {after} s: max {metrics['tracking_error_max_m'] * 1e6:.1f} um, "
          f"RMS {metrics['tracking_error_rms_m'] * 1e6:.1f} um (bound 150 um)")
    print(f"  estimation error after {after} s: max {metrics['estimation_error_max_m'] * 1e6:.1f} um")
    print(f"  saturated {metrics['saturation_time_s']:.3f} s, slew-limited {metrics['slew_limited_time_s']:.3f} s, "
          f"wall contacts {metrics['wall_contacts']}, max |G| {metrics['max_gradient_T_per_m'] * 1e3:.1f} mT/m")
    n_rej = int(metrics.get("rejected_commands") or 0)
    first = metrics.get("first_rejected_command_s")
    print(f"  rejected commands {n_rej}" + (f" (the first at t = {float(first):.3f} s; the coil ramped to zero)"
                                           if n_rej and first is not None else ""))
    return 0
