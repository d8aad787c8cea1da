"""``vesselbot force-balance``: Fig. 8a, every force term vs Delta in the small artery (Table III).

Evaluates :func:`vesselbot_ros.physics.force_balance.force_terms` (the plant's
own kernel) for a still robot across the vessel, with the maximum BP gradient
applied along +z.  By default the flow is the steady mean (a_f = 0, no diameter
pulsation); ``--time`` evaluates the pulsatile flow at that instant instead.
Writes ``force_balance.csv`` and ``force_balance.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from vesselbot_ros.analysis._common import add_config_arguments, load_physics
from vesselbot_ros.atomic_io import atomic_open, check_output_dir, save_figure
from vesselbot_ros.config import ConfigError
from vesselbot_ros.physics.force_balance import ContactState, ForceTerms, force_terms
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.vessels.cfd import packed_params

__all__ = ["register", "run", "BalanceCurve", "force_balance_curve", "delta_grid", "TERMS"]

TERMS = ("magnetic", "drag", "apparent_weight", "contact", "van_der_waals", "electrostatic", "steric")


class BalanceCurve(NamedTuple):
    """Force terms along Delta.

    Attributes:
        delta_m: (N,) robot-centre position Delta = z (m).
        gap_m: (N,) gap to the nearest wall (m).
        forces: term name -> (N, 2) force (N) in W; includes ``total`` and ``load``
            (total without the magnetic term).
    """

    delta_m: npt.NDArray[np.float64]
    gap_m: npt.NDArray[np.float64]
    forces: dict[str, npt.NDArray[np.float64]]


def delta_grid(params: PhysicsParams, diameter_m: float, n: int = 401, min_gap_m: float = 1e-9) -> npt.NDArray[np.float64]:
    """Delta values (m): uniform across the vessel plus geometric refinement near both walls."""
    dmax = 0.5 * diameter_m - params.robot.radius_m - min_gap_m
    near = 1.0 - np.geomspace(min_gap_m / dmax, 0.1, 60)
    xi = np.unique(np.concatenate([np.linspace(-1.0, 1.0, n), near, -near, [1.0, -1.0]]))
    return xi * dmax


def steady(params: PhysicsParams) -> PhysicsParams:
    """``params`` with the mean flow only (a_f = 0, no diameter pulsation)."""
    return params.with_overrides({"flow.pulsatility": 0.0, "flow.diameter_pulsation": 0.0})


def force_balance_curve(
    params: PhysicsParams, delta_m: npt.NDArray[np.float64], t_s: float = 0.0, gradient_T_per_m: float = 0.08
) -> BalanceCurve:
    """Evaluate every term at each Delta for a still robot (gradient along +z)."""
    packed = packed_params(params)
    rows: list[ForceTerms] = [
        force_terms(t_s, [0.0, z], [0.0, 0.0], [0.0, gradient_T_per_m], ContactState(), params, packed=packed) for z in delta_m
    ]
    forces = {name: np.array([getattr(ft, name) for ft in rows]) for name in (*TERMS, "total")}
    forces["load"] = forces["total"] - forces["magnetic"]
    gap = np.array([-ft.delta_m for ft in rows])
    return BalanceCurve(np.asarray(delta_m, dtype=float), gap, forces)


def register(parser: argparse.ArgumentParser) -> None:
    """Add the command's arguments."""
    add_config_arguments(parser, "out/force_balance")
    parser.add_argument("--time", type=float, default=None, help="evaluate the pulsatile flow at this time (s) instead of the steady mean")
    parser.add_argument("--min-gap", type=float, default=1e-9, help="closest gap to a wall on the grid (m), default 1e-9")


def _plot(curve: BalanceCurve, params: PhysicsParams, path: Path) -> None:
    # deferred: matplotlib (~0.5 s) loads only when the figure is drawn, not for `vesselbot force-balance --help`
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: matplotlib (see above)

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(13, 5))
    z_mm = curve.delta_m * 1e3
    for name in (*TERMS, "load"):
        mag = np.linalg.norm(curve.forces[name], axis=1)
        if np.any(mag > 0):
            ax.semilogy(z_mm, np.where(mag > 0, mag, np.nan), label=name)
            upper = curve.delta_m > 0
            ax2.loglog(curve.gap_m[upper], np.where(mag[upper] > 0, mag[upper], np.nan), label=name)
    top = max(float(np.max(np.linalg.norm(curve.forces[n], axis=1))) for n in (*TERMS, "load"))
    for a in (ax, ax2):
        a.set_ylim(1e-14, 3.0 * top)  # below 1e-14 N nothing matters next to the uN terms
    ax.set_xlabel("Delta (mm), +: upper wall")
    ax.set_ylabel("|F| (N)")
    ax.set_title(f"Force balance, D = {params.vessel.diameter_m * 1e3:g} mm, r = {params.robot.radius_m * 1e6:g} um")
    ax.legend(fontsize=8)
    ax2.set_xlabel("gap to the upper wall (m)")
    ax2.set_ylabel("|F| (N)")
    ax2.set_title("near the upper wall")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    """Compute, print and save the force balance; returns 0."""
    params = load_physics(args)
    if args.time is not None and not math.isfinite(args.time):
        raise ConfigError(f"--time must be a finite time (s), got {args.time!r}")
    t = 0.0 if args.time is None else float(args.time)
    p_eval = steady(params) if args.time is None else params
    d_t = p_eval.vessel.diameter_m * (
        1.0 + p_eval.flow.diameter_pulsation * np.sin(p_eval.flow.angular_frequency_rad_per_s * t + p_eval.flow.phase_rad)
    )
    room = 0.5 * d_t - p_eval.robot.radius_m  # largest gap to the upper wall (robot on the centreline)
    if not (math.isfinite(args.min_gap) and 0.0 < args.min_gap < room):
        raise ConfigError(f"--min-gap must be in (0, {room:.4g}) m (the gap with the robot on the centreline), "
                          f"got {args.min_gap!r}")
    curve = force_balance_curve(p_eval, delta_grid(p_eval, d_t, min_gap_m=args.min_gap), t_s=t)
    out = Path(args.out)
    check_output_dir(out, "--out")
    names = (*TERMS, "total", "load")
    with atomic_open(out / "force_balance.csv", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["delta_m", "gap_m"] + [f"{n}_{c}_N" for n in names for c in ("x", "z")])
        for i, z in enumerate(curve.delta_m):
            w.writerow([f"{z:.9g}", f"{curve.gap_m[i]:.6g}"] + [f"{curve.forces[n][i, c]:.6g}" for n in names for c in (0, 1)])
    print(f"force balance: D(t) = {d_t:.4g} m, r = {params.robot.radius_m:.4g} m, "
          f"{'steady mean flow' if args.time is None else f't = {t:g} s'}; |F| in N")
    picks = [0.0, 0.5, 0.9]
    header = f"{'position':<24}{'gap (m)':>11}" + "".join(f"{n[:12]:>13}" for n in (*TERMS, "load"))
    print(header)
    dmax = float(np.max(curve.delta_m))
    rows = [(f"Delta = {f:.1f} Delta_max", f * dmax) for f in (-0.9, *picks)]
    rows += [(f"upper gap {g:.0e} m", dmax + args.min_gap - g) for g in (1e-6, 1e-7, 1e-8, args.min_gap)]
    rows += [(f"lower gap {g:.0e} m", -(dmax + args.min_gap - g)) for g in (1e-7, args.min_gap)]
    # every row is evaluated at exactly the position its label names (not at the nearest grid point)
    at = force_balance_curve(p_eval, np.array([z for _, z in rows]), t_s=t)
    for i, (label, _) in enumerate(rows):
        print(f"{label:<24}{at.gap_m[i]:11.4g}" + "".join(f"{np.linalg.norm(at.forces[n][i]):13.3e}"
                                                      for n in (*TERMS, "load")))
    _plot(curve, params, out / "force_balance.png")
    print(f"wrote {out / 'force_balance.csv'} and {out / 'force_balance.png'}")
    return 0
