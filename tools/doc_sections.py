"""Generated sections of the docs: the text between ``<!-- BEGIN name -->`` and ``<!-- END name -->``.

The generators in ``tools/`` write their tables into docs/reproduction.md (and the README) between such
markers; :func:`replace_section` is the one place that finds and replaces them.
"""

from __future__ import annotations

import re


def replace_section(text: str, name: str, body: str, where: str = "docs/reproduction.md") -> str:
    """``text`` with the section ``name`` replaced by ``body`` (a missing marker: SystemExit naming it)."""
    mark = re.compile(rf"(<!-- BEGIN {re.escape(name)} -->\n)(?:.*?\n)?(<!-- END {re.escape(name)} -->)", re.S)
    if not mark.search(text):
        raise SystemExit(f"{where} lacks the <!-- BEGIN {name} --> / <!-- END {name} --> markers")
    return mark.sub(lambda m: m.group(1) + body + m.group(2), text)
