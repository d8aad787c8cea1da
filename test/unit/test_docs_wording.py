"""What users read says what a thing is, not which tracker item or work session made it.

"The meshed wall (issue 28)" or "Before (session 5)" means nothing to a user; the README, the docs,
the shipped configuration files (their leading comment is what ``vesselbot scenarios`` prints), the
package's docstrings and the command-line help name the thing instead.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

import vesselbot_ros
from vesselbot_ros.cli import COMMANDS, build_parser
from vesselbot_ros.sim.scenario import shipped_scenarios
from vesselbot_ros.sim.scenarios_cli import describe

# "issue 12", "Issue #28", "issue-19", "session 11", "stop 3"
TRACKER = re.compile(r"\b(?:issues?|sessions?|stops?)[ -]?#?\d+\b", re.IGNORECASE)
# "#28" in prose (not a heading, an anchor, a colour or a path)
HASH_NUMBER = re.compile(r"(?<![\w&/#`'\"\[{(-])#\d+\b")


def _mentions(text: str, *, hash_numbers: bool = True) -> list[str]:
    found = [m.group(0) for m in TRACKER.finditer(text)]
    if hash_numbers:
        found += [m.group(0) for m in HASH_NUMBER.finditer(TRACKER.sub("", text))]
    return found


def _offending_lines(path: Path, *, hash_numbers: bool = True) -> list[str]:
    return [f"{path.name}:{i}: {line.strip()}" for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
            if _mentions(line, hash_numbers=hash_numbers)]


@pytest.mark.parametrize("text, expected", [
    ("## Reproducibility across machines (issue 19)", ["issue 19"]),
    ("since Issue #28 the check reads the meshed wall", ["Issue #28"]),
    ("### Before (session 5)", ["session 5"]),
    ("see issue-12 and #14", ["issue-12", "#14"]),
    ("the tracking issue at 25 frames/s; # a comment; [#anchor](#x); `#1`", []),
])
def test_the_pattern_finds_tracker_numbers_and_only_those(text, expected):
    assert _mentions(text) == expected


def test_readme_and_docs_name_things_not_tracker_numbers(repo):
    files = [repo / "README.md", *sorted((repo / "docs").rglob("*.md"))]
    assert len(files) > 5
    bad = [line for f in files for line in _offending_lines(f)]
    assert bad == [], "tracker numbers in user-facing docs:\n" + "\n".join(bad)


def test_shipped_configuration_files_name_things_not_tracker_numbers(repo):
    files = sorted((repo / "config").rglob("*.yaml"))
    assert len(files) > 10
    # YAML comments start with "#": only the words are checked there
    bad = [line for f in files for line in _offending_lines(f, hash_numbers=False)]
    assert bad == [], "tracker numbers in shipped configuration files:\n" + "\n".join(bad)


def test_scenario_descriptions_name_things_not_tracker_numbers():
    found = shipped_scenarios()
    assert len(found) >= 5
    bad = {name: describe(str(path)) for name, path in found.items() if _mentions(describe(str(path)))}
    assert bad == {}


def test_package_docstrings_name_things_not_tracker_numbers():
    root = Path(vesselbot_ros.__file__).parent
    bad = []
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
                doc = ast.get_docstring(node) or ""
                if _mentions(doc, hash_numbers=False):
                    bad.append(f"{path.relative_to(root)}: {getattr(node, 'name', '<module>')}: {_mentions(doc)}")
    assert bad == [], "tracker numbers in docstrings:\n" + "\n".join(bad)


@pytest.mark.parametrize("command", [None, *COMMANDS])
def test_command_help_names_things_not_tracker_numbers(command):
    parser = build_parser(only=command)
    text = parser.format_help()
    if command is not None:
        sub = next(a for a in parser._actions if a.dest == "command")
        text = sub.choices[command].format_help()
    assert _mentions(text) == []
