"""Regenerate the graph spec's generated sections of docs/graph.md (architecture, topics, contract, lockstep, live view)
and docs/faults_and_safety.md (node loss).

Generated sections sit between ``<!-- BEGIN name -->`` and ``<!-- END name -->``
markers; everything else is hand-written.  Run:
``.venv/bin/python tools/gen_readme_sections.py`` (test/unit/test_graph_spec.py fails
when a page is stale).
"""

from __future__ import annotations

import re
from pathlib import Path

from vesselbot_ros import graph_spec as topics
from vesselbot_ros.atomic_io import write_text

ROOT = Path(__file__).resolve().parents[1]
TARGETS = {"docs/graph.md": ("architecture", "topics", "contract", "lockstep", "live_view"),
           "docs/faults_and_safety.md": ("node_loss",)}


def sections() -> dict[str, str]:
    doc = topics.__doc__ or ""
    protocol = doc.split("Lockstep protocol (the default mode; deterministic)")[1]
    protocol = re.sub(r"^-+\n", "", protocol.lstrip("\n")).strip()
    return {"architecture": topics.architecture_table(), "topics": topics.markdown_table(),
            "contract": topics.contract_table(), "lockstep": protocol, "node_loss": topics.faults_table(),
            "live_view": topics.view_table()}


def render(text: str, names: tuple[str, ...] | None = None, where: str = "the page") -> str:
    for name, body in sections().items():
        if names is not None and name not in names:
            continue
        pat = re.compile(rf"(<!-- BEGIN {name} -->\n)(?:.*?\n)?(<!-- END {name} -->)", re.S)
        if not pat.search(text):
            raise SystemExit(f"{where} lacks the markers for section {name!r}")
        text = pat.sub(lambda m, b=body: m.group(1) + b + "\n" + m.group(2), text)
    return text


if __name__ == "__main__":
    for rel, names in TARGETS.items():
        path = ROOT / rel
        write_text(path, render(path.read_text(), names, rel))
