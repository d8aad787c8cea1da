"""Imports inside functions must say why they are deferred.

The package imports at module top level.  An import inside a function is
allowed only where it defers a heavy or optional dependency (rclpy and message
packages in a module also used without ROS, matplotlib, dask/distributed,
scikit-fem, foxglove, a numba-compiled module, anything that would slow
``vesselbot --help``), and it says so: a comment line ``# deferred: <what and
why>`` right above the import (or above the contiguous block of imports it
belongs to, or above the ``try:`` whose body or handler the block opens), or the same
comment at the end of the import's own line.  :func:`unexplained_imports` finds
every other function-level import, so that a cheap import cannot hide in a
function (where it also hides who depends on whom) without anyone noticing.
"""

from __future__ import annotations

import ast
import io
import tokenize
from pathlib import Path

PACKAGE = "vesselbot_ros"
ROOT = Path(__file__).resolve().parents[2] / PACKAGE
MARK = "# deferred:"

_Body = list[ast.stmt]


def _bodies(node: ast.AST) -> list[_Body]:
    """The statement lists directly held by ``node`` (a function's body, an if's branches, a try's handlers, ...)."""
    out: list[_Body] = []
    for field in ("body", "orelse", "finalbody"):
        value = getattr(node, field, None)
        if isinstance(value, list) and value and isinstance(value[0], ast.stmt):
            out.append(value)
    for handler in getattr(node, "handlers", ()):
        out.append(handler.body)
    for case in getattr(node, "cases", ()):
        out.append(case.body)
    return out


def _comments(source: str) -> dict[int, str]:
    """Line number -> the text of the comment on that line (tokenized, so a '#' in a string does not count)."""
    found: dict[int, str] = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            found[tok.start[0]] = tok.string
    return found


def _explained_above(line: int, comments: dict[int, str], lines: list[str]) -> bool:
    """Whether the run of comment-only lines right above ``line`` holds a ``# deferred:`` reason."""
    row = line - 1
    while row >= 1 and lines[row - 1].strip().startswith("#"):
        if comments.get(row, "").startswith(MARK):
            return True
        row -= 1
    return False


def unexplained_imports(source: str, filename: str = "<source>") -> list[int]:
    """Line numbers of the function-level imports in ``source`` that carry no ``# deferred:`` reason.

    An import is explained by the reason on its own lines (a trailing comment),
    or by the one above the contiguous block of imports it sits in; a block
    that opens a ``try:`` body or one of its handlers (an import with a
    fallback) may take the reason above the ``try:`` line.
    """
    tree = ast.parse(source, filename)
    comments = _comments(source)
    lines = source.splitlines()
    found: list[int] = []

    def check_body(body: _Body, in_function: bool, parent: ast.AST) -> None:
        block_start: int | None = None
        for i, stmt in enumerate(body):
            if isinstance(stmt, (ast.Import, ast.ImportFrom)):
                if block_start is None:
                    block_start = i
                if in_function:
                    own_lines = range(stmt.lineno, (stmt.end_lineno or stmt.lineno) + 1)
                    first = body[block_start]
                    ok = (any(MARK in comments.get(n, "") for n in own_lines)
                          or _explained_above(first.lineno, comments, lines)
                          or (block_start == 0 and isinstance(parent, ast.Try)
                              and _explained_above(parent.lineno, comments, lines)))
                    if not ok:
                        found.append(stmt.lineno)
            else:
                block_start = None
            visit(stmt, in_function)

    def visit(node: ast.AST, in_function: bool) -> None:
        inner = in_function or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
        for body in _bodies(node):
            check_body(body, inner, node)

    visit(tree, False)
    return sorted(found)


def offenders(root: Path = ROOT) -> list[str]:
    """``file:line`` of every unexplained function-level import under ``root``."""
    out = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root.parent)
        out += [f"{rel}:{line}" for line in unexplained_imports(path.read_text(), str(path))]
    return out


def test_every_function_level_import_says_why_it_is_deferred() -> None:
    found = offenders()
    assert not found, (
        "imports inside functions without a '# deferred: <what and why>' reason (move cheap ones to the top; "
        "a heavy or optional one gets the comment above its block or at the end of its line):\n" + "\n".join(found))


def test_the_checker_flags_an_unexplained_import_and_accepts_the_explained_forms() -> None:
    source = '''\
import json


def cheap():
    import os
    return os.sep


def explained_above():
    # deferred: matplotlib is heavy and only the report draws
    import matplotlib
    from matplotlib import pyplot
    return matplotlib, pyplot


def explained_on_the_line():
    import rclpy  # deferred: rclpy only when the graph runs
    return rclpy


def explained_above_try():
    # deferred: foxglove is an optional extra
    try:
        import foxglove
    except ImportError:
        from backports import foxglove
    return foxglove


def a_second_block_needs_its_own_reason():
    # deferred: gmsh is heavy
    import gmsh
    x = gmsh
    import shutil
    return x, shutil


def comment_is_not_a_reason():
    # matplotlib is heavy
    import matplotlib
    s = "# deferred: not a comment"; import glob
    return matplotlib, s, glob


class Holder:
    def method(self):
        if True:
            from collections import OrderedDict
        return OrderedDict
'''
    lines = source.splitlines()
    flagged = unexplained_imports(source)
    assert [lines[n - 1].strip() for n in flagged] == [
        "import os", "import shutil", "import matplotlib", 's = "# deferred: not a comment"; import glob',
        "from collections import OrderedDict"]


def test_offenders_names_file_and_line(tmp_path: Path) -> None:
    root = tmp_path / PACKAGE
    (root / "sub").mkdir(parents=True)
    (root / "__init__.py").write_text("")
    (root / "sub" / "mod.py").write_text("def f():\n    x = 1\n    import os\n    return os, x\n")
    assert offenders(root) == [f"{PACKAGE}/sub/mod.py:3"]
