"""``vesselbot plan`` end to end: the plan a scenario can fly, written and flown; an infeasible path is one line."""

from __future__ import annotations

import csv

import pytest

from vesselbot_ros.cli import main
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario


def test_plan_writes_a_scenario_that_flies_its_reference_to_the_end(tmp_path, capsys):
    assert main(["plan", "--hardware", "clinical_3t_mfde", "--height", "wall", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "the path takes" in out and "continuous propulsion on the same coil" in out and "coast floor" in out
    rows = list(csv.DictReader((tmp_path / "segments.csv").open()))
    assert rows and all(float(r["margin_m_per_s2"]) >= 0.0 for r in rows)
    assert (tmp_path / "plan.png").stat().st_size > 10_000
    planned = load_scenario(tmp_path / "plan.yaml")
    assert planned.reference.timing == "planned" and planned.sequence.propulsion_window_s == pytest.approx(0.022)
    assert "the plan rests on the lower wall" in out  # and the loop is set to fly it there
    assert planned.controller.wall_contact == "carried" and planned.observer.ekf.wall_projection == "lumen"
    result = run_closed_loop(planned)  # the written scenario runs as it is, until its reference ends
    t = result.timeseries["t_s"]
    assert t[-1] == pytest.approx(planned.sim.duration_s, abs=2e-3)
    assert result.timeseries["p_ref"][-1, 0] == pytest.approx(9e-3, abs=1e-5)  # one tick before its end


def test_an_infeasible_path_is_one_line_naming_the_segment_and_exit_2(tmp_path, capsys):
    rc = main(["plan", "--set", "coil.saturation_T_per_m=0.01", "--height", "free", "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1
    assert err.startswith("vesselbot plan: error: infeasible: segment ") and err.endswith("m/s^2 missing")
    assert not (tmp_path / "plan.yaml").exists()


def test_nonsense_sequence_parameters_are_one_line_naming_the_key(tmp_path, capsys):
    for key, value in (("sequence.latency_s", "-0.01"), ("sequence.propulsion_window_s", "0"),
                       ("sequence.tracking_window_s", "0.003")):
        assert main(["plan", "--set", f"{key}={value}", "--out", str(tmp_path)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and key.split(".")[1] in err, err
