#!/usr/bin/env python3
"""Fit the paper's rational profile p_r to our CFD across a major bifurcation; write the default table.

Reads (solving once if not cached) the CFD field of config/vessels/paper_iiic_artery.yaml, samples
the sections of vesselbot_ros.vessels.bifurcation_fit at Fig. 6's angles, fits p_r at each angle
with vesselbot_ros.physics.bifurcation.fit_profile_table, and writes
  vesselbot_ros/physics/data/major_bifurcation_cfd_samples.csv   (theta_deg, y, u)
  vesselbot_ros/physics/data/major_bifurcation_default.csv       (the default table)
  docs/figures/major_bifurcation_cfd_fit.png                     (CFD samples vs fitted profiles)
Usage: .venv/bin/python tools/fit_bifurcation_table.py
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from vesselbot_ros.atomic_io import atomic_open, save_figure
from vesselbot_ros.physics import bifurcation as bif
from vesselbot_ros.vessels.bifurcation_fit import cfd_profile_samples

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    samples = cfd_profile_samples()
    table, rms = bif.fit_profile_table(samples)
    with atomic_open(bif.CFD_SAMPLES, newline="") as fh:
        fh.write("# CFD profiles across the major bifurcation of config/vessels/paper_iiic_artery.yaml "
                 "(tools/fit_bifurcation_table.py); y = section coordinate, u = velocity / inlet V_f\n")
        w = csv.writer(fh)
        w.writerow(("theta_deg", "y", "u"))
        for th, (ys, us) in samples.items():
            for yv, uv in zip(ys, us):
                w.writerow((repr(float(th)), repr(float(yv)), repr(float(uv))))
    bif.save_profile_table(table, bif._DEFAULT_TABLE,
                           "Rational-profile parameters p_r(y) = a y^2 + b y + c + (d y + e)/((y-p)^2+q^2), u / inlet V_f.\n"
                           "Fitted by tools/fit_bifurcation_table.py to major_bifurcation_cfd_samples.csv: our CFD\n"
                           "(gmsh + scikit-fem Navier-Stokes) across the major bifurcation of paper_iiic_artery.\n"
                           + f"max rms over {len(rms)} angles: {max(rms.values()):.3g}")
    bif.load_profile_table.cache_clear()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    yy = np.linspace(-1, 1, 201)
    for ax, sel, title in ((axes[0], lambda t: t <= 30, "(a) before the apex"), (axes[1], lambda t: t >= 30, "(c) after the apex")):
        for k, (th, (ys, us)) in enumerate(samples.items()):
            if not sel(th):
                continue
            c = f"C{k}"
            ax.plot(ys, us, ".", color=c, ms=3)
            ax.plot(yy, table.profile(yy, th), "-", color=c, lw=1.2, label=f"theta = {th:g} deg (rms {rms[th]:.3f})")
        ax.set_title(f"{title}: CFD (dots), rational fit (lines)")
        ax.set_xlabel("y (lower wall -1, upper wall +1)")
        ax.legend(fontsize=7)
    axes[0].set_ylabel("u / V_f (inlet centreline)")
    fig.tight_layout()
    out = ROOT / "docs" / "figures" / "major_bifurcation_cfd_fit.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, out, dpi=120)
    print("rms per angle:", {k: round(v, 4) for k, v in rms.items()})
    print(f"wrote {bif._DEFAULT_TABLE}, {bif.CFD_SAMPLES}, {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
