"""Regenerate the campaign result tables of docs/reproduction.md from the example campaigns.

Usage::

    .venv/bin/python tools/gen_campaign_tables.py --run   # run (or resume) every config/campaigns/*.yaml, then
    .venv/bin/python tools/gen_campaign_tables.py         # only copy and render what out/campaigns/ holds
    .venv/bin/python tools/gen_campaign_tables.py --run --only trees_3d   # one campaign (the others as stored)

For every spec in ``config/campaigns/`` it takes ``out/campaigns/<name>/``
(``results.parquet``, ``campaign.json``, the figures), copies them
to ``docs/campaigns/<name>/`` and renders the summary table of each into
docs/reproduction.md between ``<!-- BEGIN campaigns -->`` and
``<!-- END campaigns -->``.  test/unit/campaign/test_summary.py checks that
the section is what this script renders from ``docs/campaigns/``.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq

from vesselbot_ros.atomic_io import write_text

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "reproduction.md"
DATA = ROOT / "docs" / "campaigns"
SPECS = ROOT / "config" / "campaigns"
MARK = re.compile(r"(<!-- BEGIN campaigns -->\n)(?:.*?\n)?(<!-- END campaigns -->)", re.S)


def render_section(data: Path = DATA) -> str:
    """The Markdown of the campaigns section, from ``data/<name>/results.parquet`` and ``campaign.json``."""
    from vesselbot_ros.campaign.summary import format_markdown, summarize

    parts = []
    for d in sorted(p for p in data.iterdir() if (p / "campaign.json").is_file()):
        meta = json.loads((d / "campaign.json").read_text())
        rows = pq.read_table(d / "results.parquet").to_pylist()
        ok = sum(1 for r in rows if r.get("status") == "ok")
        failed = sum(1 for r in rows if r.get("status") == "error")
        parts.append(
            f"**`{meta['spec']}`**: {len(rows)} of {meta['n_runs']} runs finished ({ok} ok, {failed} failed), "
            f"code version `{meta['code_version']}`; table `docs/campaigns/{d.name}/results.parquet`, "
            f"figures `docs/campaigns/{d.name}/*.png`.\n\n"
            + format_markdown(summarize(rows, meta.get("grid_keys", ())))
        )
    return "\n".join(parts)


def render(text: str, data: Path = DATA) -> str:
    """``text`` (docs/reproduction.md) with its campaigns section regenerated."""
    if not MARK.search(text):
        raise SystemExit("docs/reproduction.md lacks the <!-- BEGIN campaigns --> / <!-- END campaigns --> markers")
    body = render_section(data)
    return MARK.sub(lambda m: m.group(1) + body + m.group(2), text)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--run", action="store_true", help="run (or resume) the example campaigns first")
    ap.add_argument("--only", action="append", default=[], metavar="NAME",
                    help="this campaign only (repeatable); the others' stored results are rendered as they are")
    args = ap.parse_args()
    for spec in sorted(SPECS.glob("*.yaml")):
        if args.only and spec.stem not in args.only:
            continue
        name = spec.stem
        out = ROOT / "out" / "campaigns" / name
        if args.run:
            subprocess.run([sys.executable, "-m", "vesselbot_ros.cli", "campaign", str(spec.relative_to(ROOT)),
                            "--no-progress"], cwd=ROOT, check=True)
        if not (out / "results.parquet").is_file():
            raise SystemExit(f"{out}/results.parquet is missing: run with --run")
        dest = DATA / name
        dest.mkdir(parents=True, exist_ok=True)
        for f in [out / "results.parquet", out / "campaign.json", *sorted((out / "figures").glob("*.png"))]:
            shutil.copy2(f, dest / f.name)
    write_text(DOC, render(DOC.read_text()))
    print(f"wrote {DOC.relative_to(ROOT)} from {DATA.relative_to(ROOT)}/")


if __name__ == "__main__":
    main()
