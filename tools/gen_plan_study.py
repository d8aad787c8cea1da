"""Regenerate the planned-navigation table of docs/reproduction.md ("Plans the scanner can fly").

Usage::

    .venv/bin/python tools/gen_plan_study.py              # plan, fly, write docs/plan_study/, config/plans/, docs
    .venv/bin/python tools/gen_plan_study.py --campaigns  # and the 100-seed campaigns of the planned scenarios
    .venv/bin/python tools/gen_plan_study.py --design     # and the bead design grid on clinical 3 T
    .venv/bin/python tools/gen_plan_study.py --network    # and which III-C network branch each preset reaches
    .venv/bin/python tools/gen_plan_study.py --render     # only re-render the docs from docs/plan_study/

The auto-height plans are also written as scenarios, ``config/plans/<preset>.yaml``
(with the loop's options for a plan on the wall), the bases of the campaigns
``config/campaigns/plans/<preset>.yaml``: 100 seeds each, with law (24) and with
the predictive controller; ``--campaigns`` runs them (``vesselbot campaign``)
and tabulates, per preset and controller, the tracking error's mean, worst and
share of seeds within 2x the plan's coast floor.

For each scanner preset, ``vesselbot plan`` plans the Section III-C path of
``clinical_3t_small_artery`` (its bead and vessel) on that preset's coil and
sequence (heights ``auto``, and ``free`` for comparison), then flies the
written plan over seeds 0-4 with the extended Kalman filter and law (24)
(the plan's own options) and with the predictive controller, and prints and
writes per row: the plan (where in the lumen, time beside continuous
propulsion, margin, coast floor) and the tracking error after 0.6 s (mean /
worst) with its ratio to the coast floor against the target (2x).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from doc_sections import replace_section  # noqa: E402

from vesselbot_ros.analysis.plan import Plan, PlanInfeasible, PlanOptions, flying_changes, make_plan, plan_scenario  # noqa: E402
from vesselbot_ros.analysis.scanner_study import fmt_um, preset_changes  # noqa: E402
from vesselbot_ros.atomic_io import atomic_open, write_bytes, write_text  # noqa: E402
from vesselbot_ros.sim.closed_loop import run_many  # noqa: E402
from vesselbot_ros.sim.scenario import Scenario, load_scenario, scenario_with  # noqa: E402

DOC = ROOT / "docs" / "reproduction.md"
DATA = ROOT / "docs" / "plan_study"
PLANS = ROOT / "config" / "plans"
CAMPAIGNS = ROOT / "config" / "campaigns" / "plans"
BASE = "clinical_3t_small_artery"
CELLS = (("clinical_3t", "auto"), ("clinical_3t_mfde", "auto"), ("propulsion_insert", "auto"),
         ("propulsion_insert", "free"))
SEEDS = range(5)
TARGET = 2.0
DESIGN_RADII_M = (175e-6, 250e-6, 375e-6, 500e-6)


def _fly(scenario: Scenario) -> tuple[float, float, float]:
    rs = run_many(scenario, SEEDS)
    for seed, r in zip(SEEDS, rs):  # a run that diverged (sim/metrics.py's rule) is no number of the study
        if r.metrics["status"] != "ok":
            raise SystemExit(f"gen_plan_study: {scenario.name} seed {seed}: status {r.metrics['status']} "
                             f"({r.metrics.get('divergence') or r.metrics.get('rejected_command_reasons')}); "
                             f"not tabulated")
    track = np.array([r.metrics["tracking_error_max_m"] for r in rs])
    est = np.array([r.metrics["estimation_error_rms_m"] for r in rs])
    return float(track.mean()), float(track.max()), float(est.mean())


def rows() -> list[dict]:
    out = []
    for hardware, height in CELLS:
        base = scenario_with(load_scenario(BASE), preset_changes(hardware))
        row = {"hardware": hardware, "height": height}
        try:
            plan = make_plan(base, PlanOptions(height=height))
        except PlanInfeasible as exc:
            out.append({**row, "status": str(exc)})
            continue
        cont = dataclasses.replace(base, sequence=dataclasses.replace(base.sequence, mode="continuous"))
        try:
            t_cont = make_plan(cont, PlanOptions(height=height)).end_s
        except PlanInfeasible:
            t_cont = float("nan")
        planned = plan_scenario(base, plan.reference)
        flown = scenario_with(planned, flying_changes(planned, plan))
        if height == "auto":
            _write_plan(hardware, flown, plan)
        wall = any(s.mode != "free" for s in plan.segments)
        row.update(status="ok", where="lower wall" if wall else "free lumen", end_s=plan.end_s, continuous_s=t_cont,
                   margin_m_per_s2=plan.margin_m_per_s2, a_avail_m_per_s2=plan.a_avail_m_per_s2,
                   coast_floor_m=plan.coast_floor_m)
        predictive = scenario_with(planned, {"controller.kind": "predictive"})
        for pair, scenario in (("law24", flown),
                               ("predictive", scenario_with(predictive, flying_changes(predictive, plan)))):
            mean, worst, est = _fly(scenario)
            row.update({f"{pair}_mean_m": mean, f"{pair}_worst_m": worst, f"{pair}_est_rms_m": est})
        out.append(row)
        print(_line(row), flush=True)
    return out


def _write_plan(hardware: str, flown: Scenario, plan: Plan) -> None:
    import yaml

    PLANS.mkdir(parents=True, exist_ok=True)
    mapping = dict(flown.to_mapping(), name=f"{hardware}_plan")
    write_text(PLANS / f"{hardware}.yaml",
        f"# written by tools/gen_plan_study.py: vesselbot plan of {BASE} on the {hardware} preset, its coil and\n"
        f"# sequence; {plan.end_s:.2f} s, margin {plan.margin_m_per_s2:.2f} m/s^2, coast floor "
        f"{plan.coast_floor_m * 1e6:.0f} um (COAST_FLOOR_M below: the campaigns' target).  Do not edit: regenerate.\n"
        f"# COAST_FLOOR_M: {plan.coast_floor_m!r}\n" + yaml.safe_dump(mapping, sort_keys=False))


def floor_of(path: Path) -> float:
    """The coast floor written in a plan scenario's header (m)."""
    for line in path.read_text().splitlines():
        if line.startswith("# COAST_FLOOR_M:"):
            return float(line.split(":", 1)[1])
    raise SystemExit(f"{path} has no '# COAST_FLOOR_M:' line: regenerate it with tools/gen_plan_study.py")


def campaigns() -> str:
    """Run the plan campaigns (or resume them) and tabulate them against 2x each plan's coast floor."""
    import subprocess

    import pyarrow.parquet as pq

    lines = ["| scanner preset | controller | runs | tracking max after 0.6 s: mean / worst (um) | p95 (um) | "
             "coast floor (um) | share within 2x the floor |", "|---|---|---|---|---|---|---|"]
    for spec in sorted(CAMPAIGNS.glob("*.yaml")):
        out = ROOT / "out" / "campaigns" / "plans" / spec.stem
        subprocess.run([sys.executable, "-m", "vesselbot_ros.cli", "campaign", str(spec), "--out", str(out),
                        "--no-progress"], cwd=ROOT, check=True)
        floor = floor_of(PLANS / f"{spec.stem}.yaml")
        rows = pq.read_table(out / "results.parquet").to_pylist()
        dest = DATA / "campaigns" / spec.stem
        dest.mkdir(parents=True, exist_ok=True)
        write_bytes(dest / "results.parquet", (out / "results.parquet").read_bytes())
        for variant in sorted({r["variant"] for r in rows}):
            vals = np.array([r["tracking_error_max_m"] for r in rows if r["variant"] == variant and r["status"] == "ok"])
            n_all = sum(1 for r in rows if r["variant"] == variant)
            within = np.count_nonzero(vals <= TARGET * floor) / n_all
            lines.append(f"| {spec.stem} | {variant} | {vals.size} of {n_all} | {vals.mean() * 1e6:.0f} / "
                         f"{vals.max() * 1e6:.0f} | {np.percentile(vals, 95) * 1e6:.0f} | {floor * 1e6:.0f} | "
                         f"{within:.0%} |")
    return "\n".join(lines) + "\n"


def _line(r: dict) -> str:
    return (f"{r['hardware']:<18}{r['height']:<6}{r['where']:<12}{r['end_s']:6.2f} s (cont. {r['continuous_s']:.2f})"
            f" margin {r['margin_m_per_s2']:6.2f} floor {r['coast_floor_m'] * 1e6:5.0f} um | law24 "
            f"{r['law24_mean_m'] * 1e6:5.0f}/{r['law24_worst_m'] * 1e6:5.0f} | predictive "
            f"{r['predictive_mean_m'] * 1e6:5.0f}/{r['predictive_worst_m'] * 1e6:5.0f}")


def markdown(rs: list[dict]) -> str:
    lines = ["| scanner preset | heights | plan rests | path takes (s) | continuous propulsion (s) | "
             "margin / coil (m/s^2) | coast floor (um) | EKF + law (24): tracking mean / worst (um) | worst / floor | "
             "EKF + predictive: mean / worst (um) | worst / floor | estimation rms, law (24) (um) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rs:
        if r["status"] != "ok":
            lines.append(f"| {r['hardware']} | {r['height']} | {r['status']} |" + " - |" * 9)
            continue
        f = r["coast_floor_m"]

        def ratio(w: float, f: float = f) -> str:
            q = w / f
            return f"{q:.2f}x {'(meets 2x)' if q <= TARGET else '(misses 2x)'}"

        lines.append(
            f"| {r['hardware']} | {r['height']} | {r['where']} | {r['end_s']:.2f} | {r['continuous_s']:.2f} | "
            f"{r['margin_m_per_s2']:.2f} / {r['a_avail_m_per_s2']:.2f} | {fmt_um(f)} | "
            f"{fmt_um(r['law24_mean_m'])} / {fmt_um(r['law24_worst_m'])} | {ratio(r['law24_worst_m'])} | "
            f"{fmt_um(r['predictive_mean_m'])} / {fmt_um(r['predictive_worst_m'])} | {ratio(r['predictive_worst_m'])} | "
            f"{fmt_um(r['law24_est_rms_m'])} |")
    return "\n".join(lines) + "\n"


def design() -> str:
    """``vesselbot plan-design`` on the clinical 3 T preset: the grid's Markdown (and design.png, design.csv)."""
    from vesselbot_ros.analysis.plan_design import MATERIALS, design_grid
    from vesselbot_ros.analysis.plan_design import rows as design_rows
    from vesselbot_ros.analysis.plan_design_cli import _figure
    from vesselbot_ros.analysis.plan_design_cli import markdown as design_markdown

    base = scenario_with(load_scenario(BASE), preset_changes("clinical_3t"))
    cells = design_grid(base, DESIGN_RADII_M, list(MATERIALS))
    table = design_rows(cells)
    with atomic_open(DATA / "design.csv", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(table[0]))
        w.writeheader()
        w.writerows(table)
    _figure(cells, DATA / "design.png", f"{BASE} on clinical_3t")
    return design_markdown(cells)


def network() -> str:
    """Which branch of the III-C network each preset can reach along its route, and if not, why."""
    from vesselbot_ros.analysis.plan import PlanInfeasible, PlanOptions, make_plan

    lines = ["| outlet | scanner preset | reachable | path takes (s) | margin (m/s^2) | coast floor (um) | why not |",
             "|---|---|---|---|---|---|---|"]
    for outlet in ("upper", "lower"):
        for hardware in ("paper", "clinical_3t", "clinical_3t_mfde", "propulsion_insert"):
            scenario = scenario_with(load_scenario(f"paper_iiic_network_{outlet}"), preset_changes(hardware))
            try:
                plan = make_plan(scenario, PlanOptions(height="free"))
            except PlanInfeasible as exc:
                lines.append(f"| {outlet} | {hardware} | no | - | - | - | {str(exc).removeprefix('infeasible: ')} |")
                continue
            lines.append(f"| {outlet} | {hardware} | yes | {plan.end_s:.2f} | {plan.margin_m_per_s2:.2f} | "
                         f"{plan.coast_floor_m * 1e6:.0f} | - |")
    return "\n".join(lines) + "\n"


SECTIONS = (("plan_campaigns", "campaigns.md"), ("plan_design", "design.md"), ("plan_network", "network.md"))


def render(text: str, table: str, stored: dict[str, str] | None = None) -> str:
    """``text`` with the plan table and every stored section (``{section name: Markdown}``) replaced."""
    text = replace_section(text, "plan_study", table)
    for name, body in (stored or {}).items():
        text = replace_section(text, name, body)
    return text


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--render", action="store_true", help="only re-render the docs from docs/plan_study/")
    ap.add_argument("--campaigns", action="store_true", help="also run the 100-seed campaigns of the plans")
    ap.add_argument("--design", action="store_true", help="also plan the bead design grid on clinical 3 T")
    ap.add_argument("--network", action="store_true", help="also plan the III-C network's branches per preset")
    args = ap.parse_args()
    DATA.mkdir(parents=True, exist_ok=True)
    if not args.render:
        rs = rows()
        keys = sorted({k for r in rs for k in r})
        with atomic_open(DATA / "table.csv", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=keys)
            w.writeheader()
            w.writerows(rs)
        write_text(DATA / "table.md", markdown(rs))
    if args.campaigns:
        write_text(DATA / "campaigns.md", campaigns())
    if args.design:
        write_text(DATA / "design.md", design())
    if args.network:
        write_text(DATA / "network.md", network())
    stored = {name: (DATA / f).read_text() for name, f in SECTIONS if (DATA / f).is_file()}
    write_text(DOC, render(DOC.read_text(), (DATA / "table.md").read_text(), stored))
    print(f"wrote {DOC.relative_to(ROOT)} from {DATA.relative_to(ROOT)}/table.md")


if __name__ == "__main__":
    main()
