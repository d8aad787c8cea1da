"""``vesselbot plan``: a reference the scanner can fly, with the margin and coast floor of every segment.

Writes to ``--out``: ``plan.yaml`` (the scenario with the planned reference,
run until it ends, and the loop's options for a plan that rests on the lower
wall, :func:`~vesselbot_ros.analysis.plan.flying_changes`: ``vesselbot
simulate --config <out>/plan.yaml`` flies it),
``segments.csv`` (one row per segment, SI units) and ``plan.png`` (the path in
the lumen coloured by margin; the speed and the flow; the need against the
budget), and prints the segments and the time the path takes beside the same
hardware with continuous propulsion.  A path no reference can fly within the
coil's budget: one line naming the segment and the acceleration missing, exit 2.
See :mod:`vesselbot_ros.analysis.plan`.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
from pathlib import Path

import numpy as np
import yaml

from vesselbot_ros.analysis.plan import (
    Plan,
    PlanInfeasible,
    PlanOptions,
    flying_changes,
    make_plan,
    need,
    plan_scenario,
    segments_table,
    wall_rest,
)
from vesselbot_ros.atomic_io import atomic_open, check_output_dir, save_figure, write_text
from vesselbot_ros.control.model import DynamicsModel
from vesselbot_ros.physics.integrator import blood_velocity
from vesselbot_ros.physics.kernel import fluid_velocity_x
from vesselbot_ros.scanner.hardware import PRESETS
from vesselbot_ros.sim.closed_loop import build_stages
from vesselbot_ros.sim.scenario import Scenario, load_scenario, scenario_with, shipped_scenarios
from vesselbot_ros.vessels.cfd import packed_params

DEFAULT = "clinical_3t_small_artery"
#: Room the outputs need at most (plan.yaml, segments.csv, plan.png: about 0.3 MiB), bytes.
OUTPUT_BYTES = 4 * 2**20


def add_scenario_arguments(parser: argparse.ArgumentParser, default: str, what: str) -> None:
    """``--config`` (``what`` it is, default the shipped scenario ``default``), ``--hardware`` (a preset's coil and
    sequence instead of the scenario's) and ``--set`` (dotted overrides after it): the planners' scenario."""
    parser.add_argument("--config", default=str(shipped_scenarios()[default]), help=f"{what} (default {default})")
    parser.add_argument("--hardware", default=None, metavar="PRESET",
                        help=f"a scanner preset's coil and sequence instead of the scenario's (one of "
                             f"{', '.join(sorted(PRESETS))})")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scenario value, dotted key (applied after --hardware); repeatable")


def register(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``vesselbot plan``."""
    add_scenario_arguments(parser, DEFAULT, "the scenario whose path, bead, coil and sequence are planned for")
    parser.add_argument("--budget-fraction", type=float, default=PlanOptions.budget_fraction,
                        help="share of the duty-averaged coil acceleration the plan may use at first "
                             f"(default {PlanOptions.budget_fraction:g}; lowered by itself where the check fails)")
    parser.add_argument("--max-speed-m-per-s", type=float, default=0.0,
                        help="largest axial speed of the plan (m/s; default 0: the scenario's own mean speed)")
    parser.add_argument("--floor-anchor-spacing-m", type=float, default=0.0,
                        help="in a network or a tree, the anchors along a route that rests on the floor every this far "
                             "(m; default 0: half a millimetre); 1.25e-4 hugs a crest of the floor, where the path "
                             "through sparser anchors cuts into the wall")
    parser.add_argument("--height", choices=("auto", "free", "wall"), default="auto",
                        help="free: never rest on the lower wall; wall: the least need, the wall included; auto "
                             "(default): both, the lower coast floor wins")
    parser.add_argument("--out", default="out/plan", help="output folder (default out/plan)")


def run(args: argparse.Namespace) -> int:
    """Plan, write, print; exit 0 (PlanInfeasible: the caller's one line and exit 2)."""
    scenario = load_scenario(args.config, sets=args.set, hardware=args.hardware)
    options = PlanOptions(budget_fraction=args.budget_fraction, height=args.height,
                          max_speed_m_per_s=args.max_speed_m_per_s, floor_anchor_spacing_m=args.floor_anchor_spacing_m)
    out = Path(args.out)
    check_output_dir(out, "--out", need_bytes=OUTPUT_BYTES, need_why="plan.yaml, segments.csv and plan.png")
    label = run_label(scenario.name, args.hardware)
    plan = make_plan(scenario, options)
    planned = plan_scenario(scenario, plan.reference)
    changes = flying_changes(planned, plan)
    if changes:  # the plan rides the lower wall: the loop's options for it
        planned = scenario_with(planned, changes)
        print(f"{label}: the plan rests on the lower wall; flown with "
              + ", ".join(f"{k}: {v}" for k, v in changes.items()))
    mapping = dict(planned.to_mapping(), name=plan_name(scenario.name, args.hardware))
    write_text(out / "plan.yaml",
        f"# written by vesselbot plan: {label}, with a reference its coil can fly (vesselbot simulate --config this)\n"
        + yaml.safe_dump(mapping, sort_keys=False))
    rows = segments_table(plan.segments)
    with atomic_open(out / "segments.csv", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    continuous = _continuous_end(scenario, options)
    _print(label, scenario, plan, continuous)
    _figure(label, planned, plan, out / "plan.png")
    print(f"wrote {out / 'plan.yaml'}, {out / 'segments.csv'}, {out / 'plan.png'}")
    return 0


def _continuous_end(scenario: Scenario, options: PlanOptions) -> float | None:
    """When the same path ends with the same coil propelling all the time (``None``: infeasible even so)."""
    if scenario.sequence.mode == "continuous":
        return None
    cont = dataclasses.replace(scenario, sequence=dataclasses.replace(scenario.sequence, mode="continuous"))
    try:
        return make_plan(cont, options).end_s
    except PlanInfeasible:
        return None


def run_label(name: str, hardware: str | None) -> str:
    """How the output names the run: the scenario, and the ``--hardware`` preset that replaced its coil and sequence."""
    return name if hardware is None else f"{name} with --hardware {hardware}"


def plan_name(name: str, hardware: str | None) -> str:
    """The ``name`` of the written plan.yaml: ``<scenario>_plan``, ``<scenario>_<preset>_plan`` with ``--hardware``."""
    return f"{name}_plan" if hardware is None else f"{name}_{hardware}_plan"


def _print(label: str, scenario: Scenario, plan: Plan, continuous: float | None) -> None:
    n = len(plan.segments)
    print(f"{'segment':>8}{'x from-to (mm)':>18}  {'where':<24}{'t (s)':>15}{'need':>8}{'margin':>8}{'floor um':>10}")
    for s in plan.segments:
        where = s.describe(n).split(", ", 1)[1].rstrip(")")
        print(f"{s.index + 1:>8}{s.x_from_m * 1e3:>9.2f}-{s.x_to_m * 1e3:<8.2f}  {where:<24}"
              f"{s.t_from_s:>7.3f}-{s.t_to_s:<7.3f}{s.need_m_per_s2:>8.2f}{s.margin_m_per_s2:>8.2f}"
              f"{s.coast_floor_m * 1e6:>10.0f}")
    cont = ("" if scenario.sequence.mode == "continuous" else
            f" (continuous propulsion on the same coil: {continuous:.2f} s)" if continuous is not None else
            " (continuous propulsion on the same coil: infeasible too)")
    print(f"{label}: the path takes {plan.end_s:.2f} s{cont}; margin >= {plan.margin_m_per_s2:.2f} m/s^2 "
          f"of {plan.a_avail_m_per_s2:.2f} ({plan.a_sat_m_per_s2:.2f} at {plan.duty:.0%} duty, budget fraction "
          f"{plan.budget_fraction:.2f}); coast floor {plan.coast_floor_m * 1e6:.0f} um")


def _figure(label: str, planned: Scenario, plan: Plan, path: Path) -> None:
    # deferred: matplotlib (~0.5 s) loads only when the figure is drawn, not for `vesselbot plan --help`
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: matplotlib (see above)

    ref = build_stages(planned).reference
    ts = np.arange(0.0, plan.end_s + 5e-4, 1e-3)
    p, v, a = ref.sample_many(ts)
    model = DynamicsModel(planned.physics, planned.sim.integrator)
    needs = need(model, ts, p, v, a, wall_rest(planned, ts))
    if planned.physics.vessel.network:  # along a route: the blood's speed where the reference is
        flow = np.array([float(np.linalg.norm(blood_velocity(float(t), np.ascontiguousarray(q), model.geom)))
                         for t, q in zip(ts, p, strict=True)])
        flow_label, speed, speed_label = "blood at the reference", np.linalg.norm(v, axis=1), "reference speed"
    else:
        pk = packed_params(planned.physics)
        flow = np.array([fluid_velocity_x(float(t), float(q[0]), 0.0, pk) for t, q in zip(ts, p, strict=True)])
        flow_label, speed, speed_label = "blood at the centreline", v[:, 0], "reference axial speed"
    fig, (ax0, ax1, ax2) = plt.subplots(3, 1, figsize=(8.0, 8.5))
    d = planned.physics.vessel.diameter_m
    if not planned.physics.vessel.network:
        for sgn in (-1.0, 1.0):
            ax0.axhline(sgn * 0.5 * d * 1e3, color="k", lw=1.0)
    sc = ax0.scatter(p[:, 0] * 1e3, p[:, -1] * 1e3, c=plan.a_avail_m_per_s2 - needs, s=3, cmap="RdYlGn",
                     vmin=-1.0, vmax=plan.a_avail_m_per_s2)
    fig.colorbar(sc, ax=ax0, label="margin (m/s^2)")
    ax0.set_xlabel("x (mm)")
    ax0.set_ylabel("z (mm)")
    ax0.set_title(f"{label}: the planned path " + ("(x-z view)" if planned.physics.vessel.network else
                                                     "(walls at the nominal diameter)"))
    ax1.plot(ts, speed * 1e3, label=speed_label)
    ax1.plot(ts, flow * 1e3, label=flow_label, alpha=0.6)
    ax1.set_ylabel("mm/s")
    ax1.legend(loc="upper right")
    ax2.plot(ts, needs, label="need |Xdd_ref - F|")
    ax2.axhline(plan.a_avail_m_per_s2, color="r", ls="--", label="coil, duty-averaged")
    ax2.set_xlabel("t (s)")
    ax2.set_ylabel("m/s^2")
    ax2.legend(loc="upper right")
    for ax in (ax0, ax1, ax2):
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)
