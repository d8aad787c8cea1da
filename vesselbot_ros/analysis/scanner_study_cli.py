"""``vesselbot scanner-study``: tracking under MRI multiplexing and latency, per hardware and controller.

Writes ``table.csv`` (one row per cell), ``table.md`` (the same as Markdown,
what docs/reproduction.md quotes), ``tracking_vs_duty.png`` and
``tracking_vs_latency.png`` to ``--out`` and prints the table.  The runs go
through the campaign engine (a local Dask cluster, or ``--scheduler``), with a
wall-clock budget per run (``--run-timeout-s``); they are kept in the campaign
folder ``--out``/runs/ (``results.parquet``), from which a study run again
reuses the finished runs.  See :mod:`vesselbot_ros.analysis.scanner_study`.

Every cell is reported against its coast floor, the estimation bound of
every causal estimator fed its seeds' frames
(:mod:`vesselbot_ros.analysis.estimation_bound`) and the reference strategy
(the former "tracking floor": a strategy, not a floor).  Any shipped
scenario is a base: a straight vessel, a planar network or a 3-D tree.
"""

from __future__ import annotations

import argparse
import csv
from collections.abc import Callable
from pathlib import Path

from vesselbot_ros.analysis.scanner_study import PAIRS, fmt_um, run_study, study_cells
from vesselbot_ros.atomic_io import atomic_open, check_output_dir, save_figure, write_text
from vesselbot_ros.config import ConfigError, check_positive
from vesselbot_ros.progress import add_progress_argument, suppressed
from vesselbot_ros.scanner.hardware import PRESETS
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios


def _tracking(text: str) -> list[float | None]:
    if text.strip() == "preset":
        return [None]
    vals = _floats(text)
    if any(v <= 0.0 for v in vals):
        raise argparse.ArgumentTypeError(f"tracking windows must be > 0 s, got {text!r}")
    return list(vals)


def _floats(text: str) -> list[float]:
    try:
        vals = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if not vals or any(not (0.0 <= v <= 10.0) for v in vals):
        raise argparse.ArgumentTypeError(f"expected numbers in [0, 10] s, got {text!r}")
    return vals


def register(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``vesselbot scanner-study``."""
    parser.add_argument("--config", default=str(shipped_scenarios()["sound_small_artery_ekf"]),
                        help="base scenario: any shipped one (a straight vessel, a planar network or a 3-D tree) or "
                             "a YAML file (default: sound_small_artery_ekf)")
    parser.add_argument("--hardware", default=",".join(PRESETS), help="comma-separated presets (default: all)")
    parser.add_argument("--propulsion-windows", type=_floats, default=[0.01, 0.03, 0.06, 0.12],
                        help="propulsion window lengths in s (duty cycle and frame rate follow)")
    parser.add_argument("--tracking-windows", type=_tracking, default=[None],
                        help="tracking (imaging) window lengths in s, or 'preset' (default: each preset's)")
    parser.add_argument("--latencies", type=_floats, default=[0.0, 0.02, 0.05], help="latencies in s")
    parser.add_argument("--pairs", default=",".join(PAIRS), help="observer/controller pairs (default: all)")
    parser.add_argument("--seeds", type=int, default=3, help="seeds 0..N-1 per cell (default 3)")
    parser.add_argument("--workers", type=int, default=None,
                        help="parallel runs (threads of the local cluster's worker process; default: one per usable core)")
    parser.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                        help="run on this existing Dask scheduler instead of a local cluster")
    parser.add_argument("--run-timeout-s", "--cell-timeout-s", dest="run_timeout_s", type=float, default=300.0,
                        metavar="S", help="wall-clock budget of each run; a run over it is stopped and its cell "
                                          "recorded as 'timeout' (default 300; --cell-timeout-s is the former name)")
    parser.add_argument("--reference", choices=("scenario", "planned"), default="scenario",
                        help="scenario: every cell flies the base scenario's reference; planned: the plan of its own "
                             "hardware and sequence (vesselbot plan), against the plan's coast floor")
    parser.add_argument("--out", default="out/scanner-study", help="output folder")
    add_progress_argument(parser)


def run(args: argparse.Namespace) -> int:
    """Run the study; exit 0."""
    if not 1 <= args.seeds <= 100:
        raise ConfigError(f"--seeds must be in 1..100, got {args.seeds}")
    base = load_scenario(args.config)
    cells = study_cells([h for h in args.hardware.split(",") if h], args.propulsion_windows, args.latencies,
                        [p for p in args.pairs.split(",") if p], args.tracking_windows)
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {args.workers!r}")
    if args.scheduler and args.workers is not None:
        raise ConfigError("--workers sizes the local cluster; it does not apply with --scheduler")
    check_positive("--run-timeout-s", args.run_timeout_s)
    out = Path(args.out)
    check_output_dir(out, "--out")
    rows = run_study(base, cells, range(args.seeds), args.workers, args.run_timeout_s, scheduler=args.scheduler,
                     runs_dir=out / "runs", progress=not suppressed(getattr(args, "no_progress", False)), reference=args.reference)
    keys = ["hardware", "tracking_window_s", "propulsion_window_s", "duty_cycle", "frame_rate_Hz", "latency_s",
            "pair", "status", "hold_margin_m_per_s2", "gradient_to_fly_T_per_m", "coast_floor_m", "estimation_floor_m",
            "estimation_bound_m", "estimation_bound_observer_rms_m", "estimation_bound_excluded",
            "estimation_bound_seeds", "strategy_tracking_m", "tracking_max_mean_m", "tracking_max_worst_m", "tracking_rms_mean_m",
            "estimation_rms_mean_m", "estimation_rms_worst_m"]
    with atomic_open(out / "table.csv", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    write_text(out / "table.md", markdown_table(rows))
    print(f"{'hardware':<18}{'T win':>7}{'P win':>7}{'duty':>6}{'fps':>6}{'lat':>6}  {'pair':<9}{'hold':>7}{'floor':>7}"
          f"{'est bd':>7}{'strat':>7}"
          f"{'track max mean/worst um':>25}{'est rms mean um':>17}  status")
    for r in rows:
        print(f"{r['hardware']:<18}{_f(r.get('tracking_window_s'), 3, 7)}{r['propulsion_window_s']:>7.3f}"
              f"{_f(r.get('duty_cycle'), 2, 6)}{_f(r.get('frame_rate_Hz'), 1, 6)}{r['latency_s']:>6.3f}  {r['pair']:<9}"
              f"{_f(r.get('hold_margin_m_per_s2'), 2, 7)}{fmt_um(r.get('coast_floor_m')):>7}"
              f"{fmt_um(r.get('estimation_bound_m')):>7}{fmt_um(r.get('strategy_tracking_m')):>7}"
              f"{fmt_um(r.get('tracking_max_mean_m')):>14} / {fmt_um(r.get('tracking_max_worst_m')):<8}"
              f"{fmt_um(r.get('estimation_rms_mean_m')):>15}    {r['status'][:60]}")
    _figures(rows, out)
    print("floor: coast floor (um); est bd: estimation bound of every causal estimator, rms (um); strat: reference "
          "strategy's worst tracking (um), a strategy, not a floor")
    print(f"wrote {out / 'table.csv'}, {out / 'table.md'}, {out / 'tracking_vs_duty.png'}, {out / 'tracking_vs_latency.png'}"
          f"; every run in {out / 'runs' / 'results.parquet'}")
    return 0


def _mt(v: object) -> str:
    """T/m as whole mT/m (``-`` if absent)."""
    return f"{v * 1e3:.0f}" if isinstance(v, float) else "-"


def _f(v: object, digits: int, width: int) -> str:
    return f"{v:>{width}.{digits}f}" if isinstance(v, float) else f"{'-':>{width}}"


def _ratio(a: object, b: object) -> str:
    return f"{a / b:.2f}x" if isinstance(a, float) and isinstance(b, float) and b > 0 else "-"


def markdown_table(rows: list[dict]) -> str:
    """The study's rows as a Markdown table (micrometres; ``-`` where a cell did not run).

    Against each cell: its coast floor, the estimation bound of every causal estimator (rms, with the pair's
    observer's rms on the bound's window beside it), and the reference strategy's worst tracking error (a
    strategy, not a floor: the ratio says how the loop compares with it, never that it is infeasible).
    """
    lines = ["| hardware | tracking window (ms) | propulsion window (ms) | duty | frames/s | latency (ms) | pair | "
             "hold margin (m/s^2) | gradient to fly (mT/m) | coast floor (um) | estimation bound, rms (um) | "
             "observer rms on the bound's window (um) | reference strategy (not a floor), worst of the seeds (um) | "
             "tracking max, mean / worst (um) | worst / reference strategy | "
             "tracking rms, mean (um) | estimation rms, mean (um) | status |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        tw = r.get("tracking_window_s")
        lines.append(
            f"| {r['hardware']} | {'-' if tw is None else f'{tw * 1e3:g}'} | {r['propulsion_window_s'] * 1e3:g} | "
            f"{_f(r.get('duty_cycle'), 2, 0).strip()} | {_f(r.get('frame_rate_Hz'), 1, 0).strip()} | "
            f"{r['latency_s'] * 1e3:g} | {r['pair']} | {_f(r.get('hold_margin_m_per_s2'), 1, 0).strip()} | "
            f"{_mt(r.get('gradient_to_fly_T_per_m'))} | {fmt_um(r.get('coast_floor_m'))} | "
            f"{fmt_um(r.get('estimation_bound_m'))} | {fmt_um(r.get('estimation_bound_observer_rms_m'))} | "
            f"{fmt_um(r.get('strategy_tracking_m'))} | "
            f"{fmt_um(r.get('tracking_max_mean_m'))} / {fmt_um(r.get('tracking_max_worst_m'))} | "
            f"{_ratio(r.get('tracking_max_worst_m'), r.get('strategy_tracking_m'))} | {fmt_um(r.get('tracking_rms_mean_m'))} | "
            f"{fmt_um(r.get('estimation_rms_mean_m'))} | "
            f"{r['status'].split(':')[0]} |")
    return "\n".join(lines) + "\n"


def _figures(rows: list[dict], out: Path) -> None:
    windows = sorted({r["propulsion_window_s"] for r in rows})
    lats = sorted({r["latency_s"] for r in rows})
    lat_mid, w_mid = lats[len(lats) // 2], windows[len(windows) // 2]
    _plot(rows, out / "tracking_vs_duty.png", "duty_cycle", 1.0, "propulsion duty cycle (-)",
          lambda r: r["latency_s"] == lat_mid, f"latency {lat_mid * 1e3:g} ms")
    _plot(rows, out / "tracking_vs_latency.png", "latency_s", 1e3, "reconstruction + localisation latency (ms)",
          lambda r: r["propulsion_window_s"] == w_mid, f"propulsion window {w_mid * 1e3:g} ms")


def _plot(rows: list[dict], path: Path, xkey: str, xscale: float, xlabel: str, keep: Callable[[dict], bool], fixed: str) -> None:
    """Tracking error (mean over seeds) against ``xkey``, one panel per hardware, one line per pair."""
    # deferred: matplotlib (~0.5 s) loads only when the figures are drawn, not for `vesselbot scanner-study --help`
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: matplotlib (see above)

    hw = sorted({r["hardware"] for r in rows})
    fig, axes = plt.subplots(1, len(hw), figsize=(4.5 * len(hw), 3.6), squeeze=False, sharey=True)
    for ax, h in zip(axes[0], hw, strict=True):
        for pair in sorted({r["pair"] for r in rows}):
            pts = sorted((r[xkey] * xscale, r["tracking_max_mean_m"] * 1e6) for r in rows
                         if r["hardware"] == h and r["pair"] == pair and r["status"] == "ok" and keep(r))
            if pts:
                ax.plot(*zip(*pts, strict=True), marker="o", label=pair)
        ax.set_title(f"{h} ({fixed})")
        ax.set_xlabel(xlabel)
        ax.set_yscale("log")
        ax.axhline(150, color="grey", ls="--", lw=0.8)  # the paper's 150 um claim
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("tracking error max after 0.6 s, mean over seeds (um)")
    axes[0][-1].legend(title="observer / controller")
    fig.tight_layout()
    save_figure(fig, path, dpi=120)
    plt.close(fig)
