"""Suppressions in the package say what they suppress and why.

`make lint` (ruff, mypy; pyproject.toml) fails on findings, so a finding that stays has to be silenced in
the line: these tests keep every such silencing narrow and explained.  A ``# type: ignore`` names its
error code(s) and is followed by a ``# reason``; a ``# noqa`` names its rule code(s).  mypy's
``warn_unused_ignores`` and ruff's RUF100 already drop the ones that silence nothing.
"""

from __future__ import annotations

import io
import re
import tokenize
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "vesselbot_ros"

# "type: ignore[code, code2]  # reason" (the reason: a further comment with at least one word in it)
TYPE_IGNORE = re.compile(r"type:\s*ignore(?P<codes>\[[a-z0-9_-]+(?:\s*,\s*[a-z0-9_-]+)*\])?(?P<rest>.*)")
REASON = re.compile(r"^\s*#\s*\S.*\w")
# "noqa: CODE, CODE2" (ruff's codes: letters then digits)
NOQA = re.compile(r"noqa(?P<codes>:\s*[A-Z]+[0-9]+(?:\s*,\s*[A-Z]+[0-9]+)*)?", re.IGNORECASE)


def _comments(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every comment token in ``path`` (strings that merely mention a pragma are not comments)."""
    tokens = tokenize.generate_tokens(io.StringIO(path.read_text(encoding="utf-8")).readline)
    return [(tok.start[0], tok.string) for tok in tokens if tok.type == tokenize.COMMENT]


def _sources() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def type_ignore_problems(comment: str) -> list[str]:
    """What is wrong with each ``type: ignore`` in one comment ([] when all are well formed)."""
    problems = []
    for m in TYPE_IGNORE.finditer(comment):
        if not m.group("codes"):
            problems.append("no error code: write type: ignore[code]")
        elif not REASON.match(m.group("rest")):
            problems.append("no reason: follow it with '  # why'")
    return problems


def noqa_problems(comment: str) -> list[str]:
    """What is wrong with each ``noqa`` in one comment ([] when all name their rule codes)."""
    return ["no rule code: write noqa: CODE" for m in NOQA.finditer(comment) if not m.group("codes")]


@pytest.mark.parametrize(
    ("comment", "ok"),
    [
        ("# type: ignore[misc]  # rclpy's Node is untyped", True),
        ("# type: ignore[arg-type, union-attr]  # checked above", True),
        ("# type: ignore[misc]", False),
        ("# type: ignore  # untyped", False),
        ("# type: ignore", False),
    ],
)
def test_type_ignore_rule(comment: str, ok: bool) -> None:
    """The checker itself: code and reason are both required."""
    assert (type_ignore_problems(comment) == []) is ok


@pytest.mark.parametrize(
    ("comment", "ok"),
    [("# noqa: BLE001 - a failing run is a result", True), ("# noqa: F401, E402", True), ("# noqa", False), ("# NOQA  why", False)],
)
def test_noqa_rule(comment: str, ok: bool) -> None:
    assert (noqa_problems(comment) == []) is ok


def test_every_type_ignore_in_the_package_has_a_code_and_a_reason() -> None:
    bad = [
        f"{path.relative_to(PACKAGE.parent)}:{line}: {problem}: {text.strip()}"
        for path in _sources()
        for line, text in _comments(path)
        for problem in type_ignore_problems(text)
    ]
    assert not bad, "\n".join(bad)


def test_every_noqa_in_the_package_names_its_rule() -> None:
    bad = [
        f"{path.relative_to(PACKAGE.parent)}:{line}: {problem}: {text.strip()}"
        for path in _sources()
        for line, text in _comments(path)
        for problem in noqa_problems(text)
    ]
    assert not bad, "\n".join(bad)


def test_the_package_has_suppressions_to_check() -> None:
    """Guards the scan itself: the package does carry both kinds, so an empty scan means a broken walk."""
    comments = [text for path in _sources() for _, text in _comments(path)]
    assert any("type: ignore[" in c for c in comments)
    assert any("noqa:" in c for c in comments)
