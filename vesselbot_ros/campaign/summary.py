"""What people look at after a campaign: a summary table and figures.

:func:`summarize` computes, per group of grid values (one group when nothing
is gridded) and per metric of :data:`SUMMARY_METRICS`, over the runs that
finished without error (status ``ok``; ``error`` and ``timeout`` runs count as
failed, and runs that completed on rejected commands (``rejected_commands``) or
diverged are counted by status in the header, not in the statistics): the number of runs, the mean with its 95 % confidence
interval (Student t, ``mean +/- t(0.975, n-1) s / sqrt(n)``), the standard
deviation, the 5th, 50th and 95th percentiles and the worst run (the largest
value: every metric here is better smaller).

:func:`write_report` writes ``summary.md``, ``summary.csv`` and the figures
``figures/tracking_error_distribution.png`` (histograms of the tracking error)
and ``figures/tracking_error_vs_<key>.png`` (tracking error against each
varied key); ``vesselbot campaign report DIR`` calls it again on a folder.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vesselbot_ros.atomic_io import atomic_open, save_figure, write_text

__all__ = ["SUMMARY_METRICS", "SummaryRow", "summarize", "format_markdown", "draw_figures", "write_report"]

# metric column -> (label, display unit, factor from SI)
SUMMARY_METRICS: dict[str, tuple[str, str, float]] = {
    "tracking_error_max_m": ("tracking error max", "um", 1e6),
    "tracking_error_rms_m": ("tracking error rms", "um", 1e6),
    "estimation_error_max_m": ("estimation error max", "um", 1e6),
    "estimation_error_rms_m": ("estimation error rms", "um", 1e6),
    "saturation_time_s": ("time saturated", "s", 1.0),
    "contact_time_s": ("time in wall contact", "s", 1.0),
}


@dataclasses.dataclass(frozen=True)
class SummaryRow:
    """Statistics of one metric over one group of runs (SI units, see :data:`SUMMARY_METRICS`).

    ``ci_low``/``ci_high`` bound the 95 % confidence interval of the mean
    (NaN with fewer than two runs); ``worst`` is the largest value.
    """

    group: str
    metric: str
    n: int
    n_failed: int
    mean: float
    ci_low: float
    ci_high: float
    std: float
    p5: float
    p50: float
    p95: float
    worst: float


def _t975(dof: int) -> float:
    # scipy.stats.t.ppf is this function; importing scipy.stats costs 0.4 s, scipy.special a tenth of it
    # deferred: scipy.special, paid only when a confidence interval is computed
    from scipy.special import stdtrit

    return float(stdtrit(dof, 0.975))


def _group_label(row: dict[str, Any], group_keys: Sequence[str]) -> str:
    if not group_keys:
        return "all"
    return ", ".join(f"{k}={row.get(k)}" for k in group_keys)


def _groups(rows: Sequence[dict[str, Any]], group_keys: Sequence[str]) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = {}
    for r in sorted(rows, key=lambda r: r.get("index", 0)):
        out.setdefault(_group_label(r, group_keys), []).append(r)
    return out


def summarize(rows: Sequence[dict[str, Any]], group_keys: Sequence[str] = ()) -> list[SummaryRow]:
    """Summary statistics per group and metric (see the module docstring).

    Args:
        rows: Results-table rows (dicts with ``status`` and the metric columns).
        group_keys: Keys whose values split the runs into groups (the grid keys).
    """
    out = []
    for label, members in _groups(rows, group_keys).items():
        ok = [r for r in members if r.get("status") == "ok"]
        for metric in SUMMARY_METRICS:
            v = np.array([r.get(metric) for r in ok if r.get(metric) is not None], dtype=np.float64)
            v = v[np.isfinite(v)]
            n = int(v.size)
            if n == 0:
                nan = float("nan")
                out.append(SummaryRow(label, metric, 0, len(members) - len(ok), nan, nan, nan, nan, nan, nan, nan, nan))
                continue
            mean = float(np.mean(v))
            std = float(np.std(v, ddof=1)) if n > 1 else float("nan")
            half = _t975(n - 1) * std / math.sqrt(n) if n > 1 else float("nan")
            p5, p50, p95 = (float(x) for x in np.percentile(v, [5, 50, 95]))
            out.append(SummaryRow(label, metric, n, len(members) - len(ok), mean, mean - half, mean + half,
                                  std, p5, p50, p95, float(np.max(v))))
    return out


def _fmt(x: float, unit: str) -> str:
    if not math.isfinite(x):
        return "-"
    return f"{x:.0f}" if unit == "um" else f"{x:.3g}"


def format_markdown(summary: Sequence[SummaryRow]) -> str:
    """The summary as a Markdown table (display units: um and s)."""
    lines = ["| group | metric | runs ok / failed | mean | 95 % CI of mean | p5 | median | p95 | worst |",
             "|---|---|---|---|---|---|---|---|---|"]
    for s in summary:
        label, unit, f = SUMMARY_METRICS[s.metric]
        ci = f"[{_fmt(s.ci_low * f, unit)}, {_fmt(s.ci_high * f, unit)}]" if math.isfinite(s.ci_low) else "-"
        lines.append(
            f"| {s.group} | {label} ({unit}) | {s.n} / {s.n_failed} | {_fmt(s.mean * f, unit)} | {ci} | "
            f"{_fmt(s.p5 * f, unit)} | {_fmt(s.p50 * f, unit)} | {_fmt(s.p95 * f, unit)} | {_fmt(s.worst * f, unit)} |"
        )
    return "\n".join(lines) + "\n"


def _finite(r: dict[str, Any], metric: str) -> bool:
    v = r.get(metric)
    return v is not None and math.isfinite(float(v))


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def draw_figures(rows: Sequence[dict[str, Any]], varied_keys: Sequence[str], group_keys: Sequence[str],
                 out_dir: Path, title: str = "") -> list[Path]:
    """Draw the tracking-error distribution and tracking error against each varied key.

    Args:
        rows: Results-table rows.
        varied_keys: Keys to plot against (grid keys, sampled keys, ``seed``).
        group_keys: Keys that split the runs into coloured groups.
        out_dir: Folder for the PNG files (created).
        title: Figure title prefix (the campaign name).

    Returns:
        The written files.
    """
    import matplotlib  # deferred: matplotlib (~0.5 s) loads only when figures are drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: matplotlib (see above)

    out_dir.mkdir(parents=True, exist_ok=True)
    groups = {k: [r for r in v if r.get("status") == "ok"] for k, v in _groups(rows, group_keys).items()}
    written = []
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, metric in zip(axes, ("tracking_error_max_m", "tracking_error_rms_m")):
        label, unit, f = SUMMARY_METRICS[metric]
        allv = [float(r[metric]) * f for g in groups.values() for r in g if _finite(r, metric)]
        bins = np.histogram_bin_edges(allv, bins=min(30, max(5, len(allv) // 3))) if allv else 10
        for name, g in groups.items():
            v = [float(r[metric]) * f for r in g if _finite(r, metric)]
            if v:
                ax.hist(v, bins=bins, histtype="step", linewidth=1.5, label=f"{name} (n={len(v)})")
        ax.set_xlabel(f"{label} after t = metrics_after_s ({unit})")
        ax.set_ylabel("runs")
        ax.grid(alpha=0.3)
    if axes[0].get_legend_handles_labels()[0]:  # no finished run, no histogram to name (matplotlib warns)
        axes[0].legend(fontsize=8)
    else:
        axes[0].text(0.5, 0.5, "no run finished ok", ha="center", va="center", transform=axes[0].transAxes)
    fig.suptitle(f"{title}: distribution of the tracking error".strip(": "))
    fig.tight_layout()
    path = out_dir / "tracking_error_distribution.png"
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    written.append(path)

    for key in varied_keys:
        fig, ax = plt.subplots(figsize=(6.5, 4.5))
        values = [r.get(key) for g in groups.values() for r in g]
        numeric = bool(values) and all(_is_number(v) for v in values)
        cats = sorted({str(v) for v in values}) if not numeric else []
        for name, g in groups.items():
            pts = [(r.get(key), float(r["tracking_error_max_m"]) * 1e6) for r in g
                   if _finite(r, "tracking_error_max_m")]
            if not pts:
                continue
            xs = [float(x) if numeric else cats.index(str(x)) for x, _ in pts]  # type: ignore[arg-type]  # numeric: no None
            ax.plot(xs, [y for _, y in pts], "o", ms=4, alpha=0.7, label=name)
        if not numeric:
            ax.set_xticks(range(len(cats)), cats)
        ax.set_xlabel(key)
        ax.set_ylabel("tracking error max (um)")
        ax.grid(alpha=0.3)
        if len(groups) > 1:
            ax.legend(fontsize=8)
        ax.set_title(f"{title}: tracking error vs {key}".strip(": "), fontsize=10)
        fig.tight_layout()
        path = out_dir / f"tracking_error_vs_{key.replace('/', '_')}.png"
        save_figure(fig, path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written


def write_report(rows: Sequence[dict[str, Any]], meta: dict[str, Any], root: Path) -> tuple[list[SummaryRow], str]:
    """Write ``summary.md``, ``summary.csv`` and the figures of a campaign folder.

    Args:
        rows: Results-table rows.
        meta: ``campaign.json`` (``name``, ``grid_keys``, ``varied_keys``, ``n_runs``, ``n_seeds``).
        root: The campaign folder.

    Returns:
        The summary and its Markdown text (with a header line).
    """
    group_keys = list(meta.get("grid_keys", ()))
    varied = list(meta.get("varied_keys", ()))
    if meta.get("n_seeds", 1) > 1:
        varied.append("seed")
    summary = summarize(rows, group_keys)
    n_ok = sum(1 for r in rows if r.get("status") == "ok")
    n_failed = sum(1 for r in rows if r.get("status") == "error")
    n_timeout = sum(1 for r in rows if r.get("status") == "timeout")
    budget = meta.get("run_timeout_s")
    over = (f", {n_timeout} over the run budget" + (f" of {budget:g} s" if budget else "")) if n_timeout else ""
    # runs that completed but cannot be trusted (rejected_commands, diverged): counted by status, left out of the
    # statistics as the failed ones are
    untrusted: dict[str, int] = {}
    for r in rows:
        st = r.get("status")
        if st not in ("ok", "error", "timeout", None):
            untrusted[str(st)] = untrusted.get(str(st), 0) + 1
    other = "".join(f", {n} {st}" for st, n in sorted(untrusted.items()))
    head = (f"campaign {meta.get('name')}: {len(rows)} of {meta.get('n_runs', len(rows))} runs finished, "
            f"{n_ok} ok, {n_failed} failed{over}{other} (metrics after t = {_after(rows)} s)\n\n")
    text = head + format_markdown(summary)
    write_text(root / "summary.md", text)
    with atomic_open(root / "summary.csv", newline="") as fh:
        w = csv.writer(fh)
        fields = [f.name for f in dataclasses.fields(SummaryRow)]
        w.writerow(fields)
        for s in summary:
            w.writerow([getattr(s, f) for f in fields])
    draw_figures(rows, varied, group_keys, root / "figures", str(meta.get("name", "")))
    return summary, text


def _after(rows: Sequence[dict[str, Any]]) -> str:
    vals = {float(r["after_s"]) for r in rows if r.get("after_s") is not None}
    return "/".join(f"{v:g}" for v in sorted(vals)) or "-"
