"""``vesselbot tree-design``: which outlets of a vessel tree a scanner can reach, with which bead and flow, and why not.

Plans the route to every outlet for every bead (radius x material) and flow
condition on the scanner preset's coil and sequence
(:mod:`vesselbot_ros.analysis.tree_design`), prints the table, and writes
``tree_design.csv``, ``tree_design.md`` and ``tree_design.png`` (per outlet and
flow, the beads that fly and the acceleration the others miss) to ``--out``.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np

from vesselbot_ros.analysis.plan import PlanOptions
from vesselbot_ros.analysis.plan_cli import add_scenario_arguments
from vesselbot_ros.analysis.plan_design import MATERIALS
from vesselbot_ros.analysis.plan_design_cli import _radii
from vesselbot_ros.analysis.tree_design import TABLE3, TreeCell, flow_changes, tree_design, tree_rows
from vesselbot_ros.atomic_io import atomic_open, check_output_dir, save_figure, write_text
from vesselbot_ros.config import ConfigError
from vesselbot_ros.sim.scenario import load_scenario
from vesselbot_ros.vessels.network import load_network

DEFAULT = "carotid_bifurcation_3d_eca"


def register(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``vesselbot tree-design``."""
    add_scenario_arguments(parser, DEFAULT, "a network or tree scenario: its tree, start, bead and flow")
    parser.add_argument("--outlets", default="",
                        help="comma-separated outlets to reach (default: every outlet of the tree)")
    parser.add_argument("--radii-um", type=_radii, default=_radii("250,375,500"),
                        help="comma-separated bead radii in um (default 250,375,500)")
    parser.add_argument("--materials", default="paper",
                        help=f"comma-separated bead materials, of {', '.join(MATERIALS)} (default paper)")
    parser.add_argument("--flows", default="",
                        help=f"comma-separated flow conditions: {TABLE3} (the scenario's), a preset of the tree's "
                             f"file, or <preset>@<inflow fraction> (default: {TABLE3}, every preset, and every "
                             f"preset at 10 %% inflow)")
    parser.add_argument("--out", default="out/tree-design", help="output folder (default out/tree-design)")


def run(args: argparse.Namespace) -> int:
    """Plan every cell, write and print the table; exit 0 (a bad argument: one line, exit 2)."""
    base = load_scenario(args.config, sets=args.set, hardware=args.hardware)
    if not base.physics.vessel.network:
        raise ConfigError(f"--config: the tree design needs a network or tree scenario, got {args.config!r} "
                          f"(a straight vessel: vesselbot plan-design)")
    net = load_network(base.physics.vessel.network)
    outlets = [o for o in args.outlets.split(",") if o] or list(net.outlets)
    for o in outlets:
        if o not in net.outlets:
            raise ConfigError(f"--outlets: {o!r} is not an outlet of {net.name!r} ({', '.join(net.outlets)})")
    materials = [m for m in args.materials.split(",") if m]
    for m in materials:
        if m not in MATERIALS:
            raise ConfigError(f"--materials: each must be one of {sorted(MATERIALS)}, got {m!r}")
    presets = [p.name for p in net.flow_presets]
    flows = [f for f in args.flows.split(",") if f] or [TABLE3, *presets, *(f"{p}@0.1" for p in presets)]
    for f in flows:
        name = f.partition("@")[0]
        flow_changes(f)  # a malformed fraction: its line
        if f != TABLE3 and name not in presets:
            raise ConfigError(f"--flows: {name!r} is not a flow preset of {net.name!r} "
                              f"({', '.join(presets) or 'it has none'}; or {TABLE3})")
    out = Path(args.out)
    check_output_dir(out, "--out")  # before the planning: an unwritable folder is one line, nothing computed
    label = base.name if args.hardware is None else f"{base.name} on {args.hardware}"
    cells = tree_design(base, outlets, args.radii_um, materials, flows, PlanOptions())
    table = tree_rows(cells)
    with atomic_open(out / "tree_design.csv", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(table[0]))
        w.writeheader()
        w.writerows(table)
    write_text(out / "tree_design.md", markdown(cells))
    print(f"{label}: which outlets of {net.name} the coil can reach, with which bead and flow")
    print(markdown(cells), end="")
    _figure(cells, out / "tree_design.png", label)
    print(f"wrote {out / 'tree_design.csv'}, {out / 'tree_design.md'}, {out / 'tree_design.png'}")
    return 0


def markdown(cells: list[TreeCell]) -> str:
    """The design as a Markdown table: one row per cell, why not where not."""
    lines = ["| outlet | flow | material | radius (um) | reachable | path takes (s) | margin (m/s^2) | why not |",
             "|---|---|---|---|---|---|---|---|"]
    for c in cells:
        if c.status == "ok":
            lines.append(f"| {c.outlet} | {c.flow} | {c.material} | {c.radius_m * 1e6:.0f} | yes | {c.end_s:.2f} | "
                         f"{c.margin_m_per_s2:.2f} | - |")
        else:
            miss = f"no: {c.missing_m_per_s2:.2f} m/s^2 missing" if math.isfinite(c.missing_m_per_s2) else "no"
            why = c.status.replace("|", "/")
            lines.append(f"| {c.outlet} | {c.flow} | {c.material} | {c.radius_m * 1e6:.0f} | {miss} | - | - | {why} |")
    return "\n".join(lines) + "\n"


def _figure(cells: list[TreeCell], path: Path, title: str) -> None:
    # deferred: matplotlib (~0.5 s) loads only when the figure is drawn, not for `vesselbot tree-design --help`
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: matplotlib (see above)

    cols = list(dict.fromkeys((c.outlet, c.flow) for c in cells))
    beads = list(dict.fromkeys((c.material, c.radius_m) for c in cells))
    grid = np.full((len(beads), len(cols)), np.nan)
    for c in cells:
        i, j = beads.index((c.material, c.radius_m)), cols.index((c.outlet, c.flow))
        grid[i, j] = c.margin_m_per_s2 if c.status == "ok" else -c.missing_m_per_s2
    fig, ax = plt.subplots(figsize=(1.3 * len(cols) + 3.0, 0.55 * len(beads) + 2.4))
    lim = float(np.nanmax(np.abs(grid))) if np.isfinite(grid).any() else 1.0
    im = ax.imshow(grid, cmap="RdYlGn", vmin=-lim, vmax=lim, aspect="auto")
    fig.colorbar(im, ax=ax, label="margin (m/s^2); negative: acceleration missing")
    for c in cells:
        i, j = beads.index((c.material, c.radius_m)), cols.index((c.outlet, c.flow))
        text = f"{c.end_s:.1f} s" if c.status == "ok" else (
            f"-{c.missing_m_per_s2:.1f}" if math.isfinite(c.missing_m_per_s2) else "n/a")
        ax.text(j, i, text, ha="center", va="center", fontsize=7)
    ax.set_xticks(range(len(cols)), [f"{o}\n{f}" for o, f in cols], fontsize=7, rotation=30, ha="right")
    ax.set_yticks(range(len(beads)), [f"{m} {r * 1e6:.0f} um" for m, r in beads], fontsize=7)
    ax.set_title(f"{title}: reachable outlets (the plan's time; red: m/s^2 missing)", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)
