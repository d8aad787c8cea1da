"""Tests of the campaign summary statistics and figures."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from vesselbot_ros.campaign.summary import format_markdown, summarize, write_report


def _rows() -> list[dict]:
    rng = np.random.default_rng(1)
    rows = []
    for i in range(40):
        law = "none" if i < 20 else "midpoint"
        rows.append({"index": i, "seed": i % 20, "status": "ok", "controller.sample_hold": law,
                     "eps": float(45 + i), "tracking_error_max_m": float(1e-3 + 1e-4 * rng.standard_normal()),
                     "tracking_error_rms_m": 5e-4, "estimation_error_max_m": 9e-5, "estimation_error_rms_m": 4e-5,
                     "saturation_time_s": 0.0, "contact_time_s": 0.0, "after_s": 0.6})
    rows.append({"index": 40, "seed": 0, "status": "error", "error": "ConfigError: x", "controller.sample_hold": "none"})
    rows[3]["tracking_error_max_m"] = float("nan")  # a metric that had no window is left out
    return rows


def test_statistics_per_group() -> None:
    rows = _rows()
    summ = {(s.group, s.metric): s for s in summarize(rows, ["controller.sample_hold"])}
    s = summ[("controller.sample_hold=none", "tracking_error_max_m")]
    v = np.array([r["tracking_error_max_m"] for r in rows[:20] if math.isfinite(r["tracking_error_max_m"])])
    assert (s.n, s.n_failed) == (19, 1)
    assert s.mean == pytest.approx(np.mean(v), rel=1e-12)
    half = stats.t.ppf(0.975, 18) * np.std(v, ddof=1) / math.sqrt(19)
    assert s.ci_low == pytest.approx(np.mean(v) - half, rel=1e-12)
    assert s.ci_high == pytest.approx(np.mean(v) + half, rel=1e-12)
    assert s.ci_low < s.mean < s.ci_high
    assert s.worst == np.max(v)
    assert s.p5 <= s.p50 <= s.p95 <= s.worst
    assert s.p50 == pytest.approx(np.median(v), rel=1e-12)
    m = summ[("controller.sample_hold=midpoint", "contact_time_s")]
    assert (m.n, m.n_failed, m.mean, m.worst) == (20, 0, 0.0, 0.0)
    assert m.ci_low == pytest.approx(0.0, abs=1e-15) and m.ci_high == pytest.approx(0.0, abs=1e-15)
    # no grid: one group; one run: no interval
    one = summarize(rows[:1])
    assert one[0].group == "all" and one[0].n == 1 and math.isnan(one[0].ci_low)
    table = format_markdown(summarize(rows, ["controller.sample_hold"]))
    assert "| controller.sample_hold=none | tracking error max (um) | 19 / 1 |" in table


def test_report_writes_table_and_a_figure_per_varied_key(tmp_path) -> None:
    meta = {"name": "t", "n_runs": 42, "n_seeds": 20, "grid_keys": ["controller.sample_hold"],
            "varied_keys": ["controller.sample_hold", "eps"]}
    _, text = write_report(_rows(), meta, tmp_path)
    assert text.startswith("campaign t: 41 of 42 runs finished, 40 ok, 1 failed (metrics after t = 0.6 s)")
    assert (tmp_path / "summary.md").read_text() == text
    assert (tmp_path / "summary.csv").read_text().splitlines()[0].startswith("group,metric,n,n_failed,mean,ci_low")
    pngs = sorted(p.name for p in (tmp_path / "figures").glob("*.png"))
    assert pngs == ["tracking_error_distribution.png", "tracking_error_vs_controller.sample_hold.png",
                    "tracking_error_vs_eps.png", "tracking_error_vs_seed.png"]
    assert all((tmp_path / "figures" / p).stat().st_size > 10_000 for p in pngs)


def test_reproduction_doc_tables_are_generated_from_the_stored_campaigns(repo) -> None:
    import importlib.util

    spec = importlib.util.spec_from_file_location("gen_campaign_tables", repo / "tools" / "gen_campaign_tables.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    doc = (repo / "docs" / "reproduction.md").read_text()
    assert mod.render(doc) == doc, "docs/reproduction.md is stale: run tools/gen_campaign_tables.py"
    names = {p.name for p in (repo / "docs" / "campaigns").iterdir()}
    assert names == {p.stem for p in (repo / "config" / "campaigns").glob("*.yaml")}
    for variant in ("bs24_printed_hold", "bs24_midpoint", "adaptive_bs", "ekf_flow_estimate"):
        assert f"| variant={variant} | tracking error max (um) | 100 / 0 |" in doc


def test_runs_on_rejected_commands_are_counted_in_the_header_and_left_out_of_the_statistics(tmp_path) -> None:
    rows = _rows()
    for r in rows[:3]:
        r["status"] = "rejected_commands"
        r["tracking_error_max_m"] = 0.0154  # the robot flown blind: not a result of the law
    meta = {"name": "t", "n_runs": 41, "n_seeds": 20, "grid_keys": ["controller.sample_hold"],
            "varied_keys": ["controller.sample_hold"]}
    summary, text = write_report(rows, meta, tmp_path)
    assert text.startswith("campaign t: 41 of 41 runs finished, 37 ok, 1 failed, 3 rejected_commands ")
    s = {(x.group, x.metric): x for x in summary}[("controller.sample_hold=none", "tracking_error_max_m")]
    assert s.worst < 0.0154 and s.n == 16
