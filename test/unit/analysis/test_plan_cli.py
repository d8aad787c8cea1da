"""``vesselbot plan`` end to end: the plan a scenario can fly, written and flown; an infeasible path is one line."""

from __future__ import annotations

import csv
import subprocess
import sys

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


def _plan_subprocess(tmp_path, *sets: str, timeout_s: float) -> subprocess.CompletedProcess[str]:
    """``vesselbot plan`` in a process of its own, stopped at ``timeout_s`` (a generous bound: a hang, not speed)."""
    args = [sys.executable, "-m", "vesselbot_ros.cli", "plan", "--out", str(tmp_path / "plan")]
    for s in sets:
        args += ["--set", s]
    try:
        return subprocess.run(args, capture_output=True, text=True, timeout=timeout_s, check=False)
    except subprocess.TimeoutExpired:
        pytest.fail(f"vesselbot plan {' '.join(sets)} still running after {timeout_s:g} s (it hung for > 300 s)")


def test_a_tracking_window_longer_than_the_run_is_one_line_and_exit_2_not_a_hang(tmp_path):
    """``sequence.tracking_window_s=5`` ran for over 300 s with no output (in the coast check); now the scenario
    loader refuses it, naming the key, the value and the run's duration."""
    proc = _plan_subprocess(tmp_path, "sequence.tracking_window_s=5", timeout_s=60.0)
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(err) == 1 and err[0].startswith("vesselbot plan: error: sequence.tracking_window_s must be < "
                                               "sim.duration_s (2.0 s)") and err[0].endswith("got 5.0")
    assert not (tmp_path / "plan").exists()


def test_a_valid_but_long_tracking_window_plans_in_bounded_time(tmp_path):
    """A 1 s window (it fits the 2 s run) ran for over 60 s, then hours: each 10 ms of the path started a coast of
    1 s.  Now the coast check's work is bounded (at most 4 coasts per coast length): the planner ends, here with its
    one line (a 3 % duty cycle cannot carry the bead), within a generous bound."""
    proc = _plan_subprocess(tmp_path, "sequence.tracking_window_s=1", timeout_s=300.0)
    err = proc.stderr.strip().splitlines()
    assert proc.returncode in (0, 2), proc.stderr
    if proc.returncode == 2:
        assert len(err) == 1 and err[0].startswith("vesselbot plan: error: infeasible: segment "), err


@pytest.mark.parametrize("fill_after", ["", "vesselbot_ros.analysis.plan_cli:make_plan"],
                         ids=["full-before-planning", "full-after-planning"])
def test_a_full_disk_leaves_the_earlier_plan_and_no_empty_file(tmp_path, fill_after):
    from vesselbot_ros.testing import cli_on_a_full_disk

    out = tmp_path / "plan"
    out.mkdir()
    old = {"plan.yaml": "name: an earlier plan\n", "segments.csv": "segment\n1\n"}
    for name, text in old.items():
        (out / name).write_text(text)
    child = cli_on_a_full_disk(["plan", "--hardware", "clinical_3t_mfde", "--height", "wall", "--out", str(out)],
                               fill_after=fill_after)
    err = child.stderr.strip().splitlines()
    assert child.returncode == 2, child.stderr
    assert len(err) == 1 and err[0].startswith("vesselbot plan: error: ") and "File too large" in err[0]
    assert (f"--out {out} is not writable" in err[0] if not fill_after
            else f"cannot write {out / 'plan.yaml'} " in err[0] and "plan.yaml is unchanged" in err[0])
    assert {p.name: p.read_text() for p in out.iterdir()} == old  # no 0-byte plan.yaml, no temporary file


def test_a_plan_on_another_preset_is_labelled_with_it_everywhere_it_names_the_run(tmp_path, capsys, monkeypatch):
    """``--hardware propulsion_insert`` replaces the scenario's coil and sequence: the output does not call the
    result by the base scenario's name alone (issue 39)."""
    from vesselbot_ros.analysis import plan_cli

    titles = []
    real_save = plan_cli.save_figure
    monkeypatch.setattr(plan_cli, "save_figure",
                        lambda fig, path, **kw: (titles.append(fig.axes[0].get_title()), real_save(fig, path, **kw)))
    assert main(["plan", "--hardware", "propulsion_insert", "--out", str(tmp_path)]) == 0
    label = "clinical_3t_small_artery with --hardware propulsion_insert"
    named = [ln for ln in capsys.readouterr().out.splitlines() if "clinical_3t_small_artery" in ln]
    assert named and all(ln.startswith(f"{label}: ") for ln in named), named
    assert any(ln.startswith(f"{label}: the path takes ") for ln in named)
    text = (tmp_path / "plan.yaml").read_text()
    assert text.splitlines()[0].startswith(f"# written by vesselbot plan: {label}, ")
    assert load_scenario(tmp_path / "plan.yaml").name == "clinical_3t_small_artery_propulsion_insert_plan"
    assert titles == [f"{label}: the planned path (walls at the nominal diameter)"]
