"""Tests of compute_metrics on hand-built time series."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vesselbot_ros.cli import main as cli_main
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.sim.metrics import compute_metrics, divergence_bound_m, headline, run_status, status_line

SOUND = Path(__file__).resolve().parents[3] / "config" / "sound_small_artery.yaml"


def _series(n: int = 10) -> dict[str, np.ndarray]:
    t = np.arange(n) * 0.1
    p = np.zeros((n, 2))
    ref = np.zeros((n, 2))
    ref[:, 0] = np.where(t >= 0.6 - 1e-12, 3e-6, 50e-6)  # 3 um after 0.6 s
    ref[:, 1] = np.where(t >= 0.6 - 1e-12, 4e-6, 0.0)  # -> |e| = 5 um after 0.6 s
    return {
        "t_s": t, "p_true": p, "v_true": np.zeros((n, 2)), "p_ref": ref,
        "x_hat": p + np.array([1e-6, 0.0]), "z_hat": np.zeros((n, 2)),
        "g_applied": np.tile([0.03, 0.04], (n, 1)),
        "saturated": np.array([0, 1, 1, 0, 0, 0, 0, 0, 0, 0], bool),
        "slew_limited": np.zeros((n, 2), bool),
        "in_contact": np.array([0, 1, 1, 0, 1, 0, 0, 0, 1, 1], bool),
    }


def test_hand_computed_metrics() -> None:
    m = compute_metrics(_series(), after_s=0.6)
    assert m["tracking_error_max_m"] == pytest.approx(5e-6, rel=1e-12)
    assert m["tracking_error_rms_m"] == pytest.approx(5e-6, rel=1e-12)
    assert m["tracking_error_max_all_m"] == pytest.approx(50e-6, rel=1e-12)
    assert m["estimation_error_max_m"] == pytest.approx(1e-6, rel=1e-12)
    assert m["saturation_time_s"] == pytest.approx(0.2)
    assert m["wall_contacts"] == 3
    assert m["contact_time_s"] == pytest.approx(0.5)
    assert m["max_gradient_T_per_m"] == pytest.approx(0.05)


def test_missing_key_and_bad_lengths() -> None:
    s = _series()
    del s["x_hat"]
    with pytest.raises(ModelInputError, match="lacks key"):
        compute_metrics(s)
    s = _series()
    s["p_ref"] = s["p_ref"][:5]
    with pytest.raises(ModelInputError, match=r"timeseries\['p_ref'\] has 5 rows"):
        compute_metrics(s)


def test_missing_samples_are_left_out_not_propagated():
    from vesselbot_ros.sim.metrics import compute_metrics

    n = 10
    t = np.arange(n) * 1e-3
    p = np.zeros((n, 2))
    ref = np.zeros((n, 2))
    ref[:, 1] = 1e-4  # 100 um tracking error everywhere
    g = np.zeros((n, 2))
    g[:, 0] = 0.05
    g[3] = np.nan  # a coil sample that never arrived
    ref[5] = np.nan
    ts = {"t_s": t, "p_true": p, "v_true": p, "p_ref": ref, "x_hat": p, "z_hat": p, "g_applied": g,
          "saturated": np.zeros(n, bool), "slew_limited": np.zeros(n, bool), "in_contact": np.zeros(n, bool)}
    m = compute_metrics(ts, after_s=0.0)
    assert m["max_gradient_T_per_m"] == pytest.approx(0.05)
    assert m["tracking_error_max_m"] == pytest.approx(1e-4)
    assert m["tracking_error_rms_m"] == pytest.approx(1e-4)


# ---- divergence: one rule in the core, one status every command reads ----------------------------------------------
PLUGINS = Path(__file__).resolve().parents[2] / "plugins"
WRONG_GAIN = "vesselbot_divergent_plugin:WrongGainObserver"  # its estimate: 1000 x the frame's position


def test_the_divergence_bound_is_ten_diameters_and_at_least_ten_mm() -> None:
    assert divergence_bound_m(3e-3) == pytest.approx(30e-3)
    assert divergence_bound_m(0.2e-3) == pytest.approx(10e-3)
    assert divergence_bound_m() == pytest.approx(10e-3)


def test_a_run_diverges_where_the_bead_or_its_estimate_leaves_the_bound_or_is_not_finite() -> None:
    s = _series()
    m = compute_metrics(s, after_s=0.6, vessel_diameter_m=3e-3)
    assert (m["status"], m["diverged_at_s"], m["divergence"]) == ("ok", None, None)
    far = dict(s, x_hat=s["x_hat"].copy())
    far["x_hat"][3:, 1] = 1.915  # the study's paper pair: the estimate metres away
    m = compute_metrics(far, after_s=0.6, vessel_diameter_m=3e-3)
    assert m["status"] == "diverged" and m["diverged_at_s"] == pytest.approx(0.3)
    assert m["divergence"] == "the estimate is 1915 mm from the reference (the bound is 30 mm)"
    assert m["estimation_error_rms_m"] > 1.0  # the numbers are still reported, the status says what they are
    line = status_line(m)
    assert line is not None and line.startswith("warning: the run diverged at t = 0.3 s: the estimate is 1915 mm")
    # the true position 31 mm off (beyond 10 diameters of a 3 mm vessel) at 0.5 s, before the estimate at 0.7 s
    both = dict(s, p_true=s["p_true"].copy(), x_hat=s["x_hat"].copy())
    both["p_true"][5:, 0] = 31e-3
    both["x_hat"][7:, 0] = 1.0
    m = compute_metrics(both, after_s=0.6, vessel_diameter_m=3e-3)
    assert m["diverged_at_s"] == pytest.approx(0.5) and m["divergence"].startswith("the true position is 30.95 mm")
    # within the bound: ok (29 mm)
    near = dict(s, p_true=s["p_true"] + np.array([29e-3, 0.0]))
    assert compute_metrics(near, vessel_diameter_m=3e-3)["status"] == "ok"
    # NaN: a divergence only where every tick is computed (in a real-time run it is a sample that never arrived)
    nan = dict(s, x_hat=s["x_hat"].copy())
    nan["x_hat"][4] = np.nan
    assert compute_metrics(nan)["status"] == "ok"
    m = compute_metrics(nan, nonfinite_diverges=True)
    assert m["status"] == "diverged" and m["diverged_at_s"] == pytest.approx(0.4)
    assert m["divergence"] == "the estimate is not finite (the bound is 10 mm)"
    inf = dict(s, p_true=s["p_true"].copy())
    inf["p_true"][2, 1] = -np.inf
    assert compute_metrics(inf)["divergence"] == "the true position is not finite (the bound is 10 mm)"


def test_run_status_orders_divergence_before_rejected_commands() -> None:
    assert run_status({}) == "ok"
    assert run_status({"rejected_commands": 3}) == "rejected_commands"
    assert run_status({"rejected_commands": 3, "diverged_at_s": 0.1}) == "diverged"
    assert status_line({"status": "ok"}) is None


def test_simulate_reports_a_diverged_run_in_one_line_and_exit_1(tmp_path, capsys, monkeypatch) -> None:
    """An observer with a very wrong gain: the estimate is metres from the vessel; simulate said nothing, exit 0."""
    monkeypatch.syspath_prepend(str(PLUGINS))
    code = cli_main(["simulate", "--set", f"observer.kind={WRONG_GAIN}", "--duration", "0.05",
                     "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and err[0].startswith("vesselbot: warning: the run diverged at t = 0 s: the estimate is ")
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["status"] == "diverged" and m["diverged_at_s"] == 0.0 and m["estimation_error_max_m"] > 0.5


def test_a_campaigns_table_and_summary_say_diverged(tmp_path, monkeypatch) -> None:
    from vesselbot_ros.campaign.runner import RunTask, code_version, run_chunk
    from vesselbot_ros.campaign.summary import write_report
    from vesselbot_ros.config import load_yaml

    monkeypatch.syspath_prepend(str(PLUGINS))
    ok = load_yaml(SOUND)
    ok["sim"]["duration_s"] = 0.05
    bad = {**ok, "observer": {"kind": WRONG_GAIN}}
    recs = run_chunk([RunTask(0, "ok", 0, ok, False), RunTask(1, "bad", 0, bad, False)], code_version())
    assert [r["status"] for r in recs] == ["ok", "diverged"]
    assert recs[0]["error"] is None and recs[1]["error"].startswith("the estimate is ")
    rows = [{"run_id": r["run_id"], "status": r["status"], "error": r["error"], **r["metrics"]} for r in recs]
    _, text = write_report(rows, {"name": "div", "n_runs": 2}, tmp_path)
    assert text.startswith("campaign div: 2 of 2 runs finished, 1 ok, 0 failed, 1 diverged")


def test_the_scanner_studys_table_says_diverged() -> None:
    from vesselbot_ros.analysis.scanner_study import StudyCell, cell_row
    from vesselbot_ros.sim.scenario import load_scenario

    sc = load_scenario(SOUND)
    good = {"status": "ok", "seed": 0, "tracking_error_max_m": 1e-4, "estimation_error_rms_m": 1e-5,
            "tracking_error_rms_m": 5e-5}
    bad = {**good, "seed": 1, "status": "diverged", "error": "the estimate is 1915 mm from the reference",
           "estimation_error_rms_m": 1.915}
    row = cell_row(StudyCell("paper", 0.03, 0.0, "paper"), sc, {}, [good, bad], None)
    assert row["status"] == "diverged (seed 1): the estimate is 1915 mm from the reference"
    assert "estimation_rms_mean_m" not in row  # no mean over a run that left the vessel


def test_the_headline_is_one_line_in_micrometres_with_what_applies():
    m = {"after_s": 0.6, "tracking_error_max_m": 751.24e-6, "tracking_error_rms_m": 310.0e-6,
         "estimation_error_max_m": 402.04e-6, "saturation_time_s": 0.12, "wall_contacts": 0,
         "rejected_commands": 0, "diverged_at_s": None}
    line = headline(m)
    assert line == ("tracking error after 0.6 s max 751.2 um rms 310.0 um; estimation error max 402.0 um; "
                    "saturated 0.120 s; contacts 0")
    bad = dict(m, rejected_commands=1500, diverged_at_s=0.8123, tracking_error_max_m=float("nan"))
    assert headline(bad) == ("tracking error after 0.6 s max - rms 310.0 um; estimation error max 402.0 um; "
                             "saturated 0.120 s; contacts 0; rejected commands 1500; diverged at t = 0.8123 s")


def test_simulate_prints_the_headline_and_where_the_wall_time_went(tmp_path, capsys):
    cfg = tmp_path / "s.yaml"
    cfg.write_text("base: sound_small_artery\nname: s\nsim: {duration_s: 0.05}\nreference: {duration_s: 0.05}\n")
    assert cli_main(["simulate", "--config", str(cfg), "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert f"s: {headline(m)}; wall time {m['wall_time_s']:.2f} s (set-up {m['setup_wall_time_s']:.2f} s" in out
    assert 0.0 <= m["setup_wall_time_s"] <= m["wall_time_s"]
