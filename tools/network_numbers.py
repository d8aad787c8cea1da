#!/usr/bin/env python3
"""Tracking through the III-C network's bifurcation, seeds 0-4 (mean / worst); rewrites docs/reproduction.md's block.

Usage: .venv/bin/python tools/network_numbers.py [--write]
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np

from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "reproduction.md"
BEGIN, END = "<!-- BEGIN network_numbers -->", "<!-- END network_numbers -->"


def block() -> str:
    lines = ["| scenario | branch reached (seeds 0-4) | tracking max after 0.6 s (um) | tracking rms (um) | "
             "tracking max within 2 mm of the node (um) | estimation max (um) | wall contact (s) | outside lumen (s) |",
             "|---|---|---|---|---|---|---|---|"]
    for outlet in ("upper", "lower"):
        name = f"paper_iiic_network_{outlet}"
        sc = load_scenario(shipped_scenarios()[name])
        rows = []
        for seed in range(5):
            r = run_closed_loop(sc, seed)
            m = r.metrics
            ts = r.timeseries
            e = np.hypot(*(ts["p_true"] - ts["p_ref"]).T)
            near = np.hypot(ts["p_ref"][:, 0] - 10e-3, ts["p_ref"][:, 1]) < 2e-3  # the major bifurcation node at x = 10 mm
            rows.append((m["branch_final"], m["tracking_error_max_m"], m["tracking_error_rms_m"], float(e[near].max()),
                         m["estimation_error_max_m"], m["contact_time_s"], m["outside_lumen_time_s"]))
        reached = sum(1 for r in rows if r[0] == outlet)

        def mw(i: int, scale: float = 1e6, fmt: str = ".0f") -> str:
            v = np.array([r[i] for r in rows]) * scale
            return f"{v.mean():{fmt}} / {v.max():{fmt}}"

        lines.append(f"| `{name}` | {outlet}: {reached}/5 | {mw(1)} | {mw(2)} | {mw(3)} | {mw(4)} | {mw(5, 1, '.3f')} | {mw(6, 1, '.3f')} |")
    return "\n".join(lines)


def main() -> int:
    text = block()
    print(text)
    if "--write" in sys.argv[1:]:
        doc = DOC.read_text(encoding="utf-8")
        new = f"{BEGIN}\n{text}\n{END}"
        if BEGIN in doc:
            doc = re.sub(re.escape(BEGIN) + ".*?" + re.escape(END), lambda _m: new, doc, flags=re.S)
        else:
            doc += "\n" + new + "\n"
        DOC.write_text(doc, encoding="utf-8")
        print(f"wrote {DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
