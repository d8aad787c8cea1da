"""``vesselbot scenarios``: the shipped scenarios, each with its whole description, and whether it can be flown.

Any of these names works as ``--config NAME`` of ``vesselbot run`` and
``vesselbot simulate``, from any directory; ``--config`` also takes a path.

Each scenario is loaded by the one loader the commands use
(:func:`~vesselbot_ros.sim.scenario.load_scenario`) and checked as ``vesselbot
simulate`` checks it before it runs
(:func:`~vesselbot_ros.sim.scenario.check_resources`): a scenario they would
refuse is marked ``cannot be flown as shipped`` with the first line of the
refusal.  A planar scenario whose coil cannot hold the bead against its weight
(:func:`~vesselbot_ros.scanner.hardware.hover_shortfall`: a bound for every
controller) is marked ``cannot hover on its coil``: only a path along the
lower wall flies there (``vesselbot plan``).  Loading a 3-D tree's scenario
plans its route, so the list takes seconds, not a fraction of one.
"""

from __future__ import annotations

import argparse
import re
import shutil
import textwrap
from pathlib import Path

from vesselbot_ros.config import load_yaml
from vesselbot_ros.errors import ConfigError

__all__ = ["register", "run", "describe", "refusal", "hover_note"]

#: The legend every shipped file ends its comment block with: not part of what the scenario is.
_LEGEND = re.compile(r"\s*Sources:\s*\"T3\".*$")
#: Indent of a description under its scenario's name.
INDENT = "    "


def register(parser: argparse.ArgumentParser) -> None:
    """``scenarios`` takes no arguments."""
    parser.add_argument("--paths", action="store_true", help="also print each scenario's file")


def describe(path: str | Path) -> str:
    """The scenario's whole description: its leading comment block, joined, without the shared sources legend."""
    lines = []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if not line.startswith("#"):
                break
            lines.append(line.lstrip("#").strip())
    return _LEGEND.sub("", " ".join(" ".join(lines).split()))


def refusal(path: str | Path) -> str | None:
    """Why the scenario at ``path`` cannot be flown as shipped (the loader's one line), or None if it can.

    The check is the loader's own: :func:`~vesselbot_ros.sim.scenario.load_scenario`
    and :func:`~vesselbot_ros.sim.scenario.check_resources`, the two ``vesselbot
    simulate`` runs before anything else; their ``ConfigError`` is caught.
    """
    # deferred: the scenario module pulls in the compiled core; `vesselbot --help` imports this module
    from vesselbot_ros.sim.scenario import check_resources, load_scenario

    try:
        check_resources(load_scenario(path))
    except ConfigError as exc:
        return (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    return None


def hover_note(path: str | Path) -> str | None:
    """Why no controller hovers the bead of the planar scenario at ``path`` (one line), or None if its coil can."""
    # deferred: the scenario module pulls in the compiled core; `vesselbot --help` imports this module
    from vesselbot_ros.scanner.hardware import hover_shortfall
    from vesselbot_ros.sim.scenario import load_scenario

    try:
        scenario = load_scenario(path)
    except ConfigError:
        return None  # refusal() says why
    short = (hover_shortfall(scenario.physics, scenario.coil.saturation_T_per_m, scenario.sequence)
             if scenario.dims == 2 else None)  # the vessel kind's edge: the bound reads the planar model's input gain
    if short is None:
        return None
    a_avail, a_weight = short
    return (f"cannot hover on its coil: the saturated coil gives at most {a_avail:.2f} m/s^2 at its duty cycle, the "
            f"apparent weight pulls {a_weight:.2f} m/s^2 down, so no controller holds a reference off the lower wall; "
            f"only a path along the wall flies (`vesselbot plan --config {Path(path).stem}` plans one)")


def run(args: argparse.Namespace) -> int:
    """Print each shipped scenario's name (the default marked), its description wrapped and indented, its refusal."""
    from vesselbot_ros.sim.scenario import DEFAULT_SCENARIO, shipped_scenarios  # deferred: see refusal

    width = max(40, shutil.get_terminal_size((100, 24)).columns - 1)
    for name, path in shipped_scenarios().items():
        load_yaml(path)  # a broken shipped file is an error here, not at run time
        mark = " (default)" if name == DEFAULT_SCENARIO else ""
        print(f"{name}{mark}" + (f"  [{path}]" if args.paths else ""))
        why = refusal(path)
        if why is not None:
            print(textwrap.fill(f"cannot be flown as shipped: {why}", width, initial_indent=INDENT + "! ",
                                subsequent_indent=INDENT + "  "))
        elif (hover := hover_note(path)) is not None:
            print(textwrap.fill(hover, width, initial_indent=INDENT + "! ", subsequent_indent=INDENT + "  "))
        print(textwrap.fill(describe(path), width, initial_indent=INDENT, subsequent_indent=INDENT,
                            break_on_hyphens=False))
    return 0
