"""Regenerate the scanner study of docs/reproduction.md (Section III-D in numbers).

Usage::

    .venv/bin/python tools/gen_scanner_study.py          # run the study (a few minutes on 2 cores), then write
    .venv/bin/python tools/gen_scanner_study.py --render # only re-render docs from docs/scanner_study/

Runs ``vesselbot scanner-study`` over the grid below into ``docs/scanner_study/``
(``table.csv``, ``table.md``, figures) and puts ``table.md`` into
docs/reproduction.md between ``<!-- BEGIN scanner_study -->`` and
``<!-- END scanner_study -->``.  test/unit/analysis/test_scanner_study.py checks
that the section is the stored table.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))  # loaded by file location in the tests too

from doc_sections import replace_section  # noqa: E402

DOC = ROOT / "docs" / "reproduction.md"
DATA = ROOT / "docs" / "scanner_study"
#: The grid quoted in docs/reproduction.md.
ARGS = ["--hardware", "clinical_3t,propulsion_insert", "--tracking-windows", "0.004,0.02",
        "--propulsion-windows", "0.01,0.03,0.06", "--latencies", "0.0,0.02", "--pairs", "paper,ekf,ekf_k300,ekf_predictive",
        "--seeds", "3", "--cell-timeout-s", "600"]


def render(text: str, table: str) -> str:
    """``text`` (docs/reproduction.md) with the scanner-study section replaced by ``table``."""
    return replace_section(text, "scanner_study", table)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--render", action="store_true", help="only re-render the docs from docs/scanner_study/")
    args = ap.parse_args()
    if not args.render:
        subprocess.run([sys.executable, "-m", "vesselbot_ros.cli", "scanner-study", *ARGS, "--out", str(DATA)],
                       cwd=ROOT, check=True)
    DOC.write_text(render(DOC.read_text(), (DATA / "table.md").read_text()))
    print(f"wrote {DOC.relative_to(ROOT)} from {DATA.relative_to(ROOT)}/table.md")


if __name__ == "__main__":
    main()
