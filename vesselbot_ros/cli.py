"""``vesselbot``: the one command-line entry point.

Sub-commands live in their own modules, imported lazily so that ``vesselbot
design-map`` never pays for importing rclpy.  Each module in ``COMMANDS``
provides::

    def register(parser: argparse.ArgumentParser) -> None   # add arguments
    def run(args: argparse.Namespace) -> int                # exit code

A :class:`~vesselbot_ros.errors.VesselbotError` (the root of the package's
errors: ``ConfigError``, ``ModelInputError``, ``BagError``, ``RunError``)
escaping ``run`` is printed as one clear line and exits with code 2; so is an
``OSError`` (a full disk, a missing permission).  A closed stdout (``vesselbot
bag info DIR | head -3``) ends the command quietly.

Exit codes (:data:`EXIT_CODES`, also in ``vesselbot --help``).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

from vesselbot_ros.errors import VesselbotError
from vesselbot_ros.progress import add_progress_argument, wanted
from vesselbot_ros.progress import session as progress_session

#: What the exit codes of every sub-command mean.
EXIT_CODES = """exit codes:
  0    done
  1    the run completed but its result cannot be trusted, said in one warning line on stderr (commands the coil
       rejected: non-finite, not a command, a controller that raised: it ramped to zero; a missed real-time verdict;
       campaign: every run failed, or some runs rejected commands or diverged)
  2    bad input or an error, in one line (config, model input, bag, run, file system)
  130  interrupted (Ctrl-C)
  141  stdout closed (| head)"""

# name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "design-map": ("vesselbot_ros.analysis.design_map_cli", "Fig. 7: F_m/F_tot maps over (lambda, Delta)"),
    "force-balance": ("vesselbot_ros.analysis.force_balance_cli", "Fig. 8a: every force term vs Delta"),
    "sensitivity": ("vesselbot_ros.analysis.sensitivity_cli", "Fig. 8b: +/-10 % on M, eps, q, V_f"),
    "simulate": ("vesselbot_ros.sim.simulate_cli", "ROS-free closed loop of a scenario"),
    "run": ("vesselbot_ros.launch.run_cli", "run the ROS 2 node graph (recorded)"),
    "scenarios": ("vesselbot_ros.sim.scenarios_cli", "list the shipped scenarios (names for --config)"),
    "kinds": ("vesselbot_ros.sim.kinds_cli", "list the stage kinds a scenario can name (controller, observer, ...)"),
    "bag": ("vesselbot_ros.bag.bag_cli", "inspect or repair a recorded bag (info, repair)"),
    "replay": ("vesselbot_ros.launch.replay_cli", "republish a recorded bag"),
    "report": ("vesselbot_ros.bag.report_cli", "figures and metrics from a bag"),
    "campaign": ("vesselbot_ros.campaign.campaign_cli", "Monte-Carlo runs and parameter sweeps on Dask (campaign report DIR: redraw)"),
    "plan": ("vesselbot_ros.analysis.plan_cli",
             "a reference the scanner can fly: re-timed, at the height the coil can hold, with its margins"),
    "plan-design": ("vesselbot_ros.analysis.plan_design_cli",
                    "which bead (radius, material) a scanner can fly along a path, and its coast floor"),
    "tree-design": ("vesselbot_ros.analysis.tree_design_cli",
                    "which outlets of a vessel tree a scanner can reach, with which bead and flow, and why not"),
    "vessels": ("vesselbot_ros.vessels.vessels_cli", "vessel networks: import a VMTK centreline file (.vtp) as a network YAML"),
    "scanner-study": ("vesselbot_ros.analysis.scanner_study_cli",
                      "tracking under MRI imaging/propulsion multiplexing and latency, per hardware and controller"),
    "benchmark": ("vesselbot_ros.analysis.benchmark_cli",
                  "the environments' task tiers over fixed seeds: a controller kind or a policy (success, tracking, energy)"),
}


#: The commands that can wait long on a step (a CFD solve, a 3-D wall field, a campaign's runs): they take
#: ``--no-progress`` (:func:`~vesselbot_ros.progress.add_progress_argument`) and draw bars on a terminal.
PROGRESS_COMMANDS = frozenset({"simulate", "run", "campaign", "plan", "plan-design", "tree-design", "scanner-study"})


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """Build the top-level parser; import only ``only``'s module if given."""
    parser = argparse.ArgumentParser(
        prog="vesselbot",
        description="MRI-guided magnetic microrobot navigation emulator (Arcese et al., IEEE TBME 2012).",
        epilog=EXIT_CODES, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        # argparse %-formats help strings: "+/-10 % on M" would read "% o" as a conversion
        p = sub.add_parser(name, help=help_text.replace("%", "%%"), description=help_text)
        if only == name:
            importlib.import_module(module).register(p)
        if name in PROGRESS_COMMANDS:
            add_progress_argument(p)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``vesselbot`` console script."""
    try:
        code = _main(argv)
        sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
        return code
    except BrokenPipeError:
        # the reader of our stdout went away (``| head``): stop quietly, as cat does
        _silence_stdout()
        return 141


def _silence_stdout() -> None:
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def _main(argv: Sequence[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(only=command if command in COMMANDS else None)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    module = importlib.import_module(COMMANDS[args.command][0])
    try:
        with progress_session(wanted(getattr(args, "no_progress", True))):  # bars on a terminal (progress.py)
            return int(module.run(args) or 0)
    except VesselbotError as exc:  # the root: config, model input, bag and run errors alike
        print(f"vesselbot {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        raise
    except OSError as exc:  # a full disk, a permission: one line, not a traceback
        where = f" ({exc.filename})" if exc.filename else ""
        print(f"vesselbot {args.command}: error: {exc.strerror or exc}{where}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"vesselbot {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
