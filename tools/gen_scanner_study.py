"""Regenerate the scanner study of docs/reproduction.md (Section III-D in numbers).

Usage::

    .venv/bin/python tools/gen_scanner_study.py          # run the study (a few minutes on 2 cores), then write
    .venv/bin/python tools/gen_scanner_study.py --render # only re-render docs from docs/scanner_study/
    .venv/bin/python tools/gen_scanner_study.py --planned  # the same grid flying each cell's own plan

Runs ``vesselbot scanner-study`` over the grid below into ``docs/scanner_study/``
(``table.csv``, ``table.md``, figures) and puts ``table.md`` into
docs/reproduction.md between ``<!-- BEGIN scanner_study -->`` and
``<!-- END scanner_study -->``.  test/unit/analysis/test_scanner_study.py checks
that the section is the stored table.  ``--planned`` runs the same grid with
``--reference planned`` (each cell flies the plan of its hardware and sequence,
against the plan's coast floor) into ``docs/scanner_study_planned/`` and the
section ``scanner_study_planned``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))  # loaded by file location in the tests too

from doc_sections import replace_section  # noqa: E402

from vesselbot_ros.atomic_io import write_text  # noqa: E402

DOC = ROOT / "docs" / "reproduction.md"
DATA = ROOT / "docs" / "scanner_study"
PLANNED = ROOT / "docs" / "scanner_study_planned"
#: The grid quoted in docs/reproduction.md.
ARGS = ["--hardware", "clinical_3t,propulsion_insert", "--tracking-windows", "0.004,0.02",
        "--propulsion-windows", "0.01,0.03,0.06", "--latencies", "0.0,0.02", "--pairs", "paper,ekf,ekf_k300,ekf_predictive",
        "--seeds", "3", "--cell-timeout-s", "600"]


def render(text: str, table: str, planned: str | None = None) -> str:
    """``text`` (docs/reproduction.md) with the scanner-study section replaced by ``table`` (and the planned one)."""
    text = replace_section(text, "scanner_study", table)
    return text if planned is None else replace_section(text, "scanner_study_planned", planned)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--render", action="store_true", help="only re-render the docs from docs/scanner_study/")
    ap.add_argument("--planned", action="store_true", help="run the grid flying each cell's plan instead")
    args = ap.parse_args()
    if not args.render:
        out, extra = (PLANNED, ["--reference", "planned"]) if args.planned else (DATA, [])
        subprocess.run([sys.executable, "-m", "vesselbot_ros.cli", "scanner-study", *ARGS, *extra, "--out", str(out)],
                       cwd=ROOT, check=True)
    planned = PLANNED / "table.md"
    write_text(DOC, render(DOC.read_text(), (DATA / "table.md").read_text(),
                          planned.read_text() if planned.is_file() else None))
    print(f"wrote {DOC.relative_to(ROOT)} from {DATA.relative_to(ROOT)}/table.md")


if __name__ == "__main__":
    main()
