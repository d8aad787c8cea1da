"""Regenerate the generated sections of README.md from the graph spec (architecture, topics, contract, lockstep, faults).

Generated sections sit between ``<!-- BEGIN name -->`` and ``<!-- END name -->``
markers; everything else in README.md is hand-written.  Run:
``.venv/bin/python tools/gen_readme_sections.py`` (test/unit/test_graph_spec.py fails
when the README is stale).
"""

from __future__ import annotations

import re
from pathlib import Path

from vesselbot_ros import graph_spec as topics
from vesselbot_ros.atomic_io import write_text

README = Path(__file__).resolve().parents[1] / "README.md"


def sections() -> dict[str, str]:
    doc = topics.__doc__ or ""
    protocol = doc.split("Lockstep protocol (the default mode; deterministic)")[1]
    protocol = re.sub(r"^-+\n", "", protocol.lstrip("\n")).strip()
    faults = (README.parent / "docs" / "faults_and_safety.md").read_text()
    faults = faults.split("\n", 1)[1].strip()  # drop the document's own heading
    faults += "\n\nNode loss, per process (from the graph spec):\n\n" + topics.faults_table()
    return {"architecture": topics.architecture_table(), "topics": topics.markdown_table(),
            "contract": topics.contract_table(), "lockstep": protocol, "faults": faults,
            "live_view": topics.view_table()}


def render(text: str) -> str:
    for name, body in sections().items():
        pat = re.compile(rf"(<!-- BEGIN {name} -->\n)(?:.*?\n)?(<!-- END {name} -->)", re.S)
        if not pat.search(text):
            raise SystemExit(f"README.md lacks the markers for section {name!r}")
        text = pat.sub(lambda m, b=body: m.group(1) + b + "\n" + m.group(2), text)
    return text


if __name__ == "__main__":
    write_text(README, render(README.read_text()))
