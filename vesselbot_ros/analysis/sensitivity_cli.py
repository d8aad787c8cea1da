"""``vesselbot sensitivity``: Fig. 8b, F_m / F_tot vs Delta under +/-10 % on M, epsilon, q and V_f.

Also evaluates the ends of the Table II physiological ranges (epsilon, eta,
rho_f, E_w) and prints the relative change of F_tot at the centreline and near
the upper wall.  Writes ``sensitivity.csv`` and ``sensitivity.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from vesselbot_ros.analysis._common import add_config_arguments, load_physics, load_study_mapping
from vesselbot_ros.analysis.design_map import DesignStudy
from vesselbot_ros.analysis.force_balance_cli import delta_grid, force_balance_curve, steady
from vesselbot_ros.atomic_io import atomic_open, check_output_dir, save_figure
from vesselbot_ros.config import ConfigError
from vesselbot_ros.physics.kernel import I_CHARGE
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.vessels.cfd import packed_params

__all__ = ["register", "run", "PERTURBATIONS", "perturbed", "ratio_curve"]

# label -> dotted parameter key (the charge is perturbed through charge_scale)
PERTURBATIONS = {
    "M": "robot.magnetization_A_per_m",
    "epsilon": "blood.relative_permittivity",
    "q": "robot.charge_scale",
    "V_f": "flow.centreline_velocity_m_per_s",
}


def _get(params: PhysicsParams, key: str) -> Any:
    obj: Any = params
    for part in key.split("."):
        obj = getattr(obj, part)
    return obj


def perturbed(params: PhysicsParams, key: str, factor: float) -> PhysicsParams:
    """``params`` with the value at dotted ``key`` multiplied by ``factor``."""
    return params.with_overrides({key: float(_get(params, key)) * factor})


def ratio_curve(params: PhysicsParams, delta_m: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(F_m / F_tot, F_tot (N)) along Delta for a still robot at 80 mT/m."""
    c = force_balance_curve(params, delta_m)
    f_tot = np.linalg.norm(c.forces["load"], axis=1)
    return np.linalg.norm(c.forces["magnetic"], axis=1) / np.maximum(f_tot, 1e-300), f_tot


def register(parser: argparse.ArgumentParser) -> None:
    """Add the command's arguments."""
    add_config_arguments(parser, "out/sensitivity", study=True)
    parser.add_argument("--fraction", type=float, default=0.10, help="relative perturbation (default 0.10)")


def run(args: argparse.Namespace) -> int:
    """Compute, print and save the sensitivity study; returns 0."""
    base = steady(load_physics(args))
    study = DesignStudy.from_mapping(load_study_mapping(args))
    frac = float(args.fraction)
    if not 0.0 < frac < 1.0:
        raise ConfigError(f"--fraction must be in (0, 1), got {frac!r}")
    deltas = delta_grid(base, base.vessel.diameter_m, n=201, min_gap_m=100e-9)
    i_c = int(np.argmin(np.abs(deltas)))
    i_w = int(np.argmax(deltas))
    nominal, ftot0 = ratio_curve(base, deltas)
    curves: dict[str, npt.NDArray[np.float64]] = {"nominal": nominal}
    print(f"sensitivity (steady flow, still robot, 80 mT/m); nominal q = {packed_params(base)[I_CHARGE]:.3e} C")
    print(f"{'case':<32}{'Fm/Ftot centre':>16}{'Fm/Ftot wall':>14}{'dFtot centre':>14}{'dFtot wall':>12}")
    print(f"{'nominal':<32}{nominal[i_c]:16.4g}{nominal[i_w]:14.4g}{0:14.1%}{0:12.1%}")
    cases: list[tuple[str, PhysicsParams]] = []
    for label, key in PERTURBATIONS.items():
        for sign in (-1, 1):
            cases.append((f"{label} {'+' if sign > 0 else '-'}{frac:.0%}", perturbed(base, key, 1.0 + sign * frac)))
    t2 = study.table2
    for label, key, rng in (("Table II eps", "blood.relative_permittivity", t2.relative_permittivity),
                            ("Table II rho_f", "blood.density_kg_per_m3", t2.blood_density_kg_per_m3),
                            ("Table II E_w", "wall.young_modulus_Pa", t2.wall_young_modulus_Pa)):
        for v in rng:
            cases.append((f"{label} = {v:g}", base.with_overrides({key: v})))
    for v in t2.viscosity_Pa_s:
        overrides = {"blood.viscosity_model": "constant", "blood.constant_viscosity_Pa_s": v}
        cases.append((f"Table II eta = {v:g} Pa s", base.with_overrides(overrides)))
    for label, p in cases:
        ratio, ftot = ratio_curve(p, deltas)
        curves[label] = ratio
        print(f"{label:<32}{ratio[i_c]:16.4g}{ratio[i_w]:14.4g}{ftot[i_c] / ftot0[i_c] - 1:14.1%}{ftot[i_w] / ftot0[i_w] - 1:12.1%}")
    out = Path(args.out)
    check_output_dir(out, "--out")
    with atomic_open(out / "sensitivity.csv", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["delta_m", *curves])
        for i, z in enumerate(deltas):
            w.writerow([f"{z:.9g}"] + [f"{c[i]:.6g}" for c in curves.values()])
    # deferred: matplotlib (~0.5 s) loads only when the figure is drawn, not for `vesselbot sensitivity --help`
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: matplotlib (see above)

    fig, axes = plt.subplots(1, len(PERTURBATIONS), figsize=(4 * len(PERTURBATIONS), 4), sharey=True)
    for ax, label in zip(axes, PERTURBATIONS):
        ax.plot(deltas * 1e3, nominal, "k-", label="nominal")
        ax.plot(deltas * 1e3, curves[f"{label} -{frac:.0%}"], "b--", label=f"-{frac:.0%}")
        ax.plot(deltas * 1e3, curves[f"{label} +{frac:.0%}"], "r--", label=f"+{frac:.0%}")
        ax.set_title(f"{label} +/-{frac:.0%}")
        ax.set_xlabel("Delta (mm)")
        ax.legend(fontsize=8)
    axes[0].set_ylabel("F_m / F_tot")
    fig.tight_layout()
    save_figure(fig, out / "sensitivity.png", dpi=110)
    plt.close(fig)
    print(f"wrote {out / 'sensitivity.csv'} and {out / 'sensitivity.png'}")
    return 0
