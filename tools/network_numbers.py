#!/usr/bin/env python3
"""Tracking through the network scenarios' bifurcations, seeds 0-4 (mean / worst); rewrites docs/reproduction.md's block.

The planar networks' scenarios, then the 3-D trees' (the III-C route written as a 3-D tree right after its planar
twin's row): distances and errors are Euclidean over the scenario's axes, (x, z) or (x, y, z).

Usage: .venv/bin/python tools/network_numbers.py [--write]
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np

from vesselbot_ros.atomic_io import write_text
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios
from vesselbot_ros.vessels.network import load_network

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "reproduction.md"
SCENARIOS = ("paper_iiic_network_upper", "paper_iiic_network_upper_3d", "paper_iiic_network_lower", "small_artery_4gen_udu",
             "carotid_bifurcation_3d_eca", "synthetic_tree_3d_deep")
BEGIN, END = "<!-- BEGIN network_numbers -->", "<!-- END network_numbers -->"


def block() -> str:
    lines = ["| scenario | branch reached (seeds 0-4) | tracking max after 0.6 s (um) | tracking rms (um) | "
             "tracking max within 2 mm of a major node (um) | estimation max (um) | wall contact (s) | outside lumen (s) |",
             "|---|---|---|---|---|---|---|---|"]
    for name in SCENARIOS:
        sc = load_scenario(shipped_scenarios()[name])
        outlet = sc.reference.route_outlet
        net = load_network(sc.physics.vessel.network)
        axes = [0, 1, 2] if sc.dims == 3 else [0, 2]
        # the major bifurcations the route passes: nodes whose daughters are not much narrower than the parent
        nodes = np.array([b.points_3d()[-1, axes] for b in net.branches
                          if len(net.children(b.name)) > 1 and min(max(c.radius_m) for c in net.children(b.name)) > 0.5 * b.radius_m[-1]])
        rows = []
        for seed in range(5):
            r = run_closed_loop(sc, seed)
            m = r.metrics
            ts = r.timeseries
            e = np.linalg.norm(ts["p_true"] - ts["p_ref"], axis=1)
            d_node = np.min(np.linalg.norm(ts["p_ref"][:, None, :] - nodes[None, :, :], axis=2), axis=1)
            near = d_node < 2e-3
            rows.append((m["branch_final"], m["tracking_error_max_m"], m["tracking_error_rms_m"], float(e[near].max()),
                         m["estimation_error_max_m"], m["contact_time_s"], m["outside_lumen_time_s"]))
        reached = sum(1 for r in rows if r[0] == outlet)

        def mw(i: int, scale: float = 1e6, fmt: str = ".0f", rows: list[tuple[float, ...]] = rows) -> str:
            v = np.array([r[i] for r in rows]) * scale
            return f"{v.mean():{fmt}} / {v.max():{fmt}}"

        lines.append(f"| `{name}` | {outlet}: {reached}/5 | {mw(1)} | {mw(2)} | {mw(3)} | {mw(4)} "
                     f"| {mw(5, 1, '.3f')} | {mw(6, 1, '.3f')} |")
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
        write_text(DOC, doc)
        print(f"wrote {DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
