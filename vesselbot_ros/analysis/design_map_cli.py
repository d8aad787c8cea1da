"""``vesselbot design-map``: Fig. 7, F_m / F_tot over (lambda, Delta) for 4 vessels x 3 designs.

Writes ``design_map.png``, ``design_map_summary.csv`` and one matrix CSV per
map (``map_<vessel>_<design>.csv``: first row xi = Delta/Delta_max, first
column lambda) to ``--out``, and prints each map's maximum, its (lambda, Delta)
and the lambda range within 90 % of the maximum.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path
from typing import Any

import numpy as np

from vesselbot_ros.analysis._common import add_config_arguments, load_physics, load_study_mapping
from vesselbot_ros.analysis.design_map import DESIGNS, DesignMap, DesignStudy, all_design_maps, summarize
from vesselbot_ros.atomic_io import atomic_open, atomic_path, check_output_dir, save_figure
from vesselbot_ros.config import ConfigError
from vesselbot_ros.resources import require_fits

__all__ = ["register", "run", "plot_maps"]


def register(parser: argparse.ArgumentParser) -> None:
    """Add the command's arguments."""
    add_config_arguments(parser, "out/design_map", study=True)
    parser.add_argument("--no-png", action="store_true", help="skip the figure")


def maps_figure(maps: list[DesignMap]) -> Any:
    """A (vessels x 3) grid of log10(F_m/F_tot) images.

    In every panel the white line is the contour F_m/F_tot = 1 (F_m = F_tot:
    inside it the robot can overcome the load; drawn only where the map
    crosses 1) and the red star is the panel's maximum of F_m/F_tot (its value
    is in the title).  A legend under the grid says so.
    """
    import matplotlib  # deferred: matplotlib (~0.5 s) loads only when a figure is drawn (not with --no-png)

    matplotlib.use("Agg")
    # deferred: matplotlib (see above)
    import matplotlib.pyplot as plt
    from matplotlib.font_manager import FontProperties
    from matplotlib.lines import Line2D

    vessels = list(dict.fromkeys(m.vessel for m in maps))
    fig, axes = plt.subplots(len(vessels), len(DESIGNS), squeeze=False,
                             figsize=(FIGURE_WIDTH_IN, FIGURE_ROW_IN * len(vessels) + FIGURE_EXTRA_IN))
    for m in maps:
        ax = axes[vessels.index(m.vessel), DESIGNS.index(m.design)]
        data = np.log10(np.maximum(m.ratio, 1e-12)).T
        im = ax.pcolormesh(m.lam, m.xi, data, shading="auto", cmap="viridis")
        if data.min() < 0.0 < data.max():
            ax.contour(m.lam, m.xi, data, levels=[0.0], colors="w", linewidths=1.0)
        s = summarize(m)
        ax.plot([s.lam_at_max], [s.xi_at_max], "r*", ms=9)
        ax.set_title(f"{m.design} in {m.vessel}: max {s.max_ratio:.3g}", fontsize=9)
        ax.set_xlabel("lambda = 2r/D")
        ax.set_ylabel("Delta / Delta_max (+1 = upper wall)")
        fig.colorbar(im, ax=ax, label="log10 F_m/F_tot")
    handles = [Line2D([], [], color="w", lw=1.5, path_effects=None, label="white line: F_m/F_tot = 1 "
                      "(F_m = F_tot; the robot beats the load where the map is above it)"),
               Line2D([], [], color="r", marker="*", ls="", ms=9, label="red star: maximum of F_m/F_tot "
                      "(value in the panel title)")]
    leg = fig.legend(handles=handles, loc="lower center", ncol=2, fontsize=8, facecolor="0.6", framealpha=1.0)
    leg.set_title("Fig. 7: log10 of F_m/F_tot over (lambda, Delta)", prop=FontProperties(size=8))
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return fig


#: The figure's resolution (dots per inch), its size per row of vessels and its fixed parts (inches).
FIGURE_DPI = 110
FIGURE_WIDTH_IN, FIGURE_ROW_IN, FIGURE_EXTRA_IN = 12.0, 3.2, 0.6
#: Matplotlib's Agg canvas is at most this many pixels along each side.
MAX_FIGURE_PIXELS = 2**16


def check_figure(n_vessels: int) -> None:
    """Refuse, before any map is computed, a figure of ``n_vessels`` rows matplotlib cannot draw or memory cannot hold.

    Raises:
        ConfigError: one line naming ``design_study.vessels``, the count and the figure's size.
    """
    w = FIGURE_WIDTH_IN * FIGURE_DPI
    h = (FIGURE_ROW_IN * n_vessels + FIGURE_EXTRA_IN) * FIGURE_DPI
    if h > MAX_FIGURE_PIXELS:
        raise ConfigError(f"design_study.vessels={n_vessels} vessels: the figure would be {w:.0f} x {h:.0f} pixels, more "
                          f"than matplotlib's {MAX_FIGURE_PIXELS} along a side: list at most "
                          f"{int((MAX_FIGURE_PIXELS / FIGURE_DPI - FIGURE_EXTRA_IN) / FIGURE_ROW_IN)} vessels or use --no-png")
    require_fits("design_study.vessels", f"{n_vessels} vessels", 12.0 * w * h,  # RGBA canvas, its copies and the PNG
                 what=f"the figure of {w:.0f} x {h:.0f} pixels", hint="fewer vessels or --no-png")


def plot_maps(maps: list[DesignMap], path: Path) -> None:
    """Save :func:`maps_figure` to ``path``."""
    import matplotlib.pyplot as plt  # deferred: matplotlib (see maps_figure)

    fig = maps_figure(maps)
    save_figure(fig, path, dpi=FIGURE_DPI)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    """Compute, print and save the design maps; returns 0."""
    params = load_physics(args)
    study = DesignStudy.from_mapping(load_study_mapping(args))
    if not args.no_png:
        check_figure(len(study.vessels))
    out = Path(args.out)
    check_output_dir(out, "--out")
    t0 = time.perf_counter()
    maps = all_design_maps(params, study)
    elapsed = time.perf_counter() - t0
    summaries = [summarize(m) for m in maps]
    print(f"{len(maps)} maps of {study.grid.n_lambda}x{study.grid.n_delta} in {elapsed:.3f} s")
    print(f"{'vessel':<13} {'design':<6} {'max Fm/Ftot':>11} {'lambda':>7} {'Delta (m)':>11} {'Delta/Dmax':>10}"
          "  lambda range >= 90 % of max")
    with atomic_open(out / "design_map_summary.csv", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(("vessel", "design", "max_ratio", "lambda_at_max", "delta_at_max_m", "xi_at_max", "lambda90_lo", "lambda90_hi"))
        for s in summaries:
            print(f"{s.vessel:<13} {s.design:<6} {s.max_ratio:11.4g} {s.lam_at_max:7.3f} {s.delta_at_max_m:11.3e} {s.xi_at_max:10.2f}  "
                  f"[{s.lam_range_90[0]:.3f}, {s.lam_range_90[1]:.3f}]")
            w.writerow((s.vessel, s.design, f"{s.max_ratio:.6g}", f"{s.lam_at_max:.6g}", f"{s.delta_at_max_m:.6g}",
                        f"{s.xi_at_max:.6g}", f"{s.lam_range_90[0]:.6g}", f"{s.lam_range_90[1]:.6g}"))
    for m in maps:
        mat = np.empty((m.lam.size + 1, m.xi.size + 1))
        mat[0, 0] = np.nan
        mat[0, 1:] = m.xi
        mat[1:, 0] = m.lam
        mat[1:, 1:] = m.ratio
        with atomic_path(out / f"map_{m.vessel}_{m.design}.csv") as tmp:
            np.savetxt(tmp, mat, delimiter=",", fmt="%.6g",
                       header=f"F_m/F_tot for {m.design} in {m.vessel}; row 0: xi = Delta/Delta_max; column 0: lambda")
    if not args.no_png:
        plot_maps(maps, out / "design_map.png")
        print(f"wrote {out / 'design_map.png'}")
    print(f"wrote {out / 'design_map_summary.csv'} and {len(maps)} map CSVs")
    return 0
