"""``vesselbot kinds``: the stage kinds a scenario can name, per role.

Lists the built-in kinds and those installed packages register through the
entry point group ``vesselbot_ros.stages``; ``--check module:Class`` loads a
user's kind the way a scenario naming it would, and says what it is or why it
is refused (exit 2).  See :mod:`vesselbot_ros.sim.kinds`.
"""

from __future__ import annotations

import argparse
import dataclasses

from vesselbot_ros.sim.kinds import ROLES, SECTIONS, StageKind, find, kinds


def register(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``vesselbot kinds``."""
    parser.add_argument("--role", choices=ROLES, help="only this role's kinds")
    parser.add_argument("--check", metavar="[ROLE=]KIND",
                        help="load KIND (a name or module:Class) as a scenario naming it would, print its "
                             "parameters, exit 2 with the reason if it is refused; ROLE defaults to controller")


def _describe(kind: StageKind) -> str:
    """The kind's parameters with their defaults (``name`` alone for a required one)."""
    return ", ".join(f"{f.name}={f.default!r}" if f.default is not dataclasses.MISSING else f.name
                     for f in dataclasses.fields(kind.params) if f.name != "kind")


def run(args: argparse.Namespace) -> int:
    """Print the kinds; exit 0 (2 if ``--check`` refuses the kind, through the command line's error path)."""
    if args.check:
        role, sep, name = args.check.partition("=")
        if not sep:
            role, name = args.role or "controller", args.check
        kind = find(role, name, f"--check {SECTIONS.get(role, role)}.kind")
        print(f"{kind.role} kind {kind.name!r} ({kind.source}): {kind.summary or kind.params.__name__}")
        print(f"  section {SECTIONS[kind.role]}: {kind.params.__name__}({_describe(kind)})")
        print(f"  compiled loop: {'yes' if kind.compiled else 'no (the per-tick loop runs it, same numbers)'}")
        return 0
    for role in ROLES if args.role is None else (args.role,):
        print(f"{role} (scenario section '{SECTIONS[role]}', key 'kind'):")
        for k in kinds(role):
            tag = "" if k.source == "built-in" else f" [{k.source}]"
            print(f"  {k.name:<24}{'compiled ' if k.compiled else 'per-tick '} {k.summary}{tag}")
    print("A scenario may also name a class of your own: kind: module:Class (examples/plugin_controller.py).")
    return 0
