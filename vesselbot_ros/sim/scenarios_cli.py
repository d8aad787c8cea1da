"""``vesselbot scenarios``: the shipped scenarios, one line each (name, then what it is).

Any of these names works as ``--config NAME`` of ``vesselbot run`` and
``vesselbot simulate``, from any directory; ``--config`` also takes a path.
"""

from __future__ import annotations

import argparse
import re

from vesselbot_ros.config import load_yaml

__all__ = ["register", "run", "describe"]

# words whose full stop does not end a description's first sentence
_ABBREVIATIONS = frozenset({"ref", "refs", "al", "e.g", "i.e", "fig", "eq", "sec", "cf", "vs"})


def register(parser: argparse.ArgumentParser) -> None:
    """``scenarios`` takes no arguments."""
    parser.add_argument("--paths", action="store_true", help="also print each scenario's file")


def describe(path: str) -> str:
    """The scenario's one-line description: the first sentence of its leading comment block."""
    lines = []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if not line.startswith("#"):
                break
            lines.append(line.lstrip("#").strip())
    text = " ".join(x for x in lines if x)
    for m in re.finditer(r"(\S*)\. ", text):
        if m.group(1).lstrip("([").lower() not in _ABBREVIATIONS:  # "the paper's ref. [23]" does not end the sentence
            return text[: m.end() - 1]
    return text


def run(args: argparse.Namespace) -> int:
    """Print ``NAME  description`` per shipped scenario (the default marked)."""
    # deferred: the scenario module pulls in the compiled core; `vesselbot --help` imports this module
    from vesselbot_ros.sim.scenario import DEFAULT_SCENARIO, shipped_scenarios

    found = shipped_scenarios()
    width = max((len(n) for n in found), default=0)
    for name, path in found.items():
        load_yaml(path)  # a broken shipped file is an error here, not at run time
        mark = " (default)" if name == DEFAULT_SCENARIO else ""
        print(f"{name:<{width}}  {describe(str(path))}{mark}" + (f"  [{path}]" if args.paths else ""))
    return 0
