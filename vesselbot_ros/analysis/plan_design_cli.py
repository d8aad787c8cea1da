"""``vesselbot plan-design``: which bead (radius, material) a scanner can fly along a path, and its floor.

Plans the scenario's path for every bead of a radius x material grid on the
scanner preset's coil and sequence (:mod:`vesselbot_ros.analysis.plan_design`),
prints the table, and writes ``design.csv``, ``design.md`` and ``design.png``
(the coast floor per bead; infeasible beads marked with the acceleration
missing) to ``--out``.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np

from vesselbot_ros.analysis.plan import PlanOptions
from vesselbot_ros.analysis.plan_design import MATERIALS, DesignCell, design_grid, rows
from vesselbot_ros.atomic_io import atomic_open, check_output_dir, save_figure, write_text
from vesselbot_ros.config import ConfigError
from vesselbot_ros.scanner.hardware import PRESETS
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios

DEFAULT = "clinical_3t_small_artery"


def _radii(text: str) -> list[float]:
    try:
        vals = [float(v) * 1e-6 for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated radii in um, got {text!r}") from None
    if not vals or any(not (5.0e-6 <= v <= 2e-3) for v in vals):
        raise argparse.ArgumentTypeError(f"radii must be in [5, 2000] um, got {text!r}")
    return vals


def register(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``vesselbot plan-design``."""
    parser.add_argument("--config", default=str(shipped_scenarios()[DEFAULT]),
                        help=f"the scenario whose path and vessel are planned for (default {DEFAULT})")
    parser.add_argument("--hardware", default="clinical_3t", metavar="PRESET",
                        help=f"the scanner preset's coil and sequence (one of {', '.join(sorted(PRESETS))}; "
                             f"default clinical_3t)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scenario value, dotted key (after --hardware); repeatable")
    parser.add_argument("--radii-um", type=_radii, default=_radii("100,175,250,375,500"),
                        help="bead radii in um, comma-separated (default 100,175,250,375,500)")
    parser.add_argument("--materials", default=",".join(MATERIALS),
                        help=f"comma-separated, of {', '.join(MATERIALS)} (default: all)")
    parser.add_argument("--out", default="out/plan-design", help="output folder (default out/plan-design)")


def run(args: argparse.Namespace) -> int:
    """Plan every bead, write and print the table; exit 0."""
    materials = [m for m in args.materials.split(",") if m]
    for m in materials:
        if m not in MATERIALS:
            raise ConfigError(f"--materials: each must be one of {sorted(MATERIALS)}, got {m!r}")
    base = load_scenario(args.config, sets=args.set, hardware=args.hardware)
    out = Path(args.out)
    check_output_dir(out, "--out")  # before the planning: an unwritable folder is one line, nothing computed
    cells = design_grid(base, args.radii_um, materials, PlanOptions())
    table = rows(cells)
    with atomic_open(out / "design.csv", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(table[0]))
        w.writeheader()
        w.writerows(table)
    write_text(out / "design.md", markdown(cells))
    print(f"{base.name} on {args.hardware}: which bead the coil can fly along the path")
    print(markdown(cells), end="")
    best = min((c for c in cells if c.status == "ok"), key=lambda c: c.coast_floor_m, default=None)
    if best is None:
        least = min(cells, key=lambda c: c.missing_m_per_s2)
        print(f"no bead of the grid is flyable; closest: r = {least.radius_m * 1e6:.0f} um {least.material}, "
              f"{least.missing_m_per_s2:.2f} m/s^2 missing")
    else:
        print(f"lowest coast floor: r = {best.radius_m * 1e6:.0f} um {best.material}, {best.coast_floor_m * 1e6:.0f} um "
              f"({best.where}, {best.end_s:.2f} s)")
    _figure(cells, out / "design.png", f"{base.name} on {args.hardware}")
    print(f"wrote {out / 'design.csv'}, {out / 'design.md'}, {out / 'design.png'}")
    return 0


def markdown(cells: list[DesignCell]) -> str:
    """The grid as a Markdown table."""
    lines = ["| material | radius (um) | flyable | rests | path takes (s) | margin (m/s^2) | coast floor (um) |",
             "|---|---|---|---|---|---|---|"]
    for c in cells:
        if c.status == "ok":
            lines.append(f"| {c.material} | {c.radius_m * 1e6:.0f} | yes | {c.where} | {c.end_s:.2f} | "
                         f"{c.margin_m_per_s2:.2f} | {c.coast_floor_m * 1e6:.0f} |")
        else:
            miss = f"no: {c.missing_m_per_s2:.2f} m/s^2 missing" if math.isfinite(c.missing_m_per_s2) else "no"
            lines.append(f"| {c.material} | {c.radius_m * 1e6:.0f} | {miss} | - | - | - | - |")
    return "\n".join(lines) + "\n"


def _figure(cells: list[DesignCell], path: Path, title: str) -> None:
    # deferred: matplotlib (~0.5 s) loads only when the figure is drawn, not for `vesselbot plan-design --help`
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: matplotlib (see above)

    materials = list(dict.fromkeys(c.material for c in cells))
    radii = sorted({c.radius_m for c in cells})
    grid = np.full((len(materials), len(radii)), np.nan)
    for c in cells:
        if c.status == "ok":
            grid[materials.index(c.material), radii.index(c.radius_m)] = c.coast_floor_m * 1e6
    fig, ax = plt.subplots(figsize=(1.4 * len(radii) + 3.0, 0.6 * len(materials) + 2.0))
    im = ax.imshow(grid, cmap="viridis_r", aspect="auto")
    fig.colorbar(im, ax=ax, label="coast floor (um)")
    for c in cells:
        i, j = materials.index(c.material), radii.index(c.radius_m)
        text = f"{c.coast_floor_m * 1e6:.0f}\n{c.where}" if c.status == "ok" else (
            f"-{c.missing_m_per_s2:.1f}\nm/s^2" if math.isfinite(c.missing_m_per_s2) else "no")
        ax.text(j, i, text, ha="center", va="center", fontsize=7, color="k" if c.status == "ok" else "r")
    ax.set_xticks(range(len(radii)), [f"{r * 1e6:.0f}" for r in radii])
    ax.set_yticks(range(len(materials)), materials)
    ax.set_xlabel("bead radius (um)")
    ax.set_title(f"{title}: coast floor of the plan (red: acceleration missing)")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)
