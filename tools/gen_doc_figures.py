"""Rewrite every marked figure of README.md and docs/*.md from the stored results; check the rest.

A marked figure is ``<!-- fig NAME -->TEXT<!-- /fig -->`` (see ``tools/docs_figures.py``).  Run::

    .venv/bin/python tools/gen_doc_figures.py            # rewrite the marks, then print the problems left
    .venv/bin/python tools/gen_doc_figures.py --check    # only print the problems (exit 1 if any)
    .venv/bin/python tools/gen_doc_figures.py --suspects # unmarked figures that may state one quantity twice
    .venv/bin/python tools/gen_doc_figures.py --ledger   # rewrite docs/figures_unverified.txt (see below)

``test/unit/test_docs_consistency.py`` fails on every problem ``--check`` prints.  ``--ledger``
writes the figures no stored result supports yet: it exists to move the ledger with text that was
moved between pages; a new figure belongs in a mark or a generated block, and the test caps the
ledger's length so it only shrinks.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import docs_figures as df

from vesselbot_ros.atomic_io import write_text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--check", action="store_true", help="print the problems only (exit 1 if any)")
    g.add_argument("--suspects", action="store_true", help="print unmarked figures that may contradict")
    g.add_argument("--ledger", action="store_true", help=f"rewrite {df.LEDGER} from the unsupported figures")
    args = ap.parse_args(argv)
    if args.suspects:
        for key, figs in df.suspects():
            print(key)
            for f in figs:
                print(f"    {f.file}:{f.line}: {f.text}  ({f.context})")
        return 0
    if args.ledger:
        _, unmarked, generated = df.collect(df.docs_files())
        keys = [f.key for f in df.unverified(unmarked, generated)]
        head = ("# Figures in README.md and docs/*.md that no stored result supports yet (tools/docs_figures.py).\n"
                "# Only shrinks: mark a figure (<!-- fig NAME -->...<!-- /fig -->) or qualify it, then delete its line.\n")
        write_text(df.ROOT / df.LEDGER, head + "".join(k + "\n" for k in keys))
        print(f"{df.LEDGER}: {len(keys)} figures")
        return 0
    if not args.check:
        for p in df.docs_files():
            text = p.read_text(encoding="utf-8")
            new = df.regenerate(text)
            if new != text:
                write_text(p, new)
                print(f"rewrote {p.relative_to(df.ROOT)}")
    problems = df.check()
    for pr in problems:
        print(pr)
    marked, unmarked, generated = df.collect(df.docs_files())
    print(f"{len(marked)} marked, {len(unmarked) - len(df.unverified(unmarked, generated))} quoted from generated "
          f"blocks or allowlisted, {len(df.read_ledger())} on the ledger; {len(problems)} problems", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
