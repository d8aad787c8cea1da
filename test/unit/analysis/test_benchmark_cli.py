"""``vesselbot benchmark``: the table on stdout, bad input one line and exit 2."""

from __future__ import annotations

import csv

import pytest

from vesselbot_ros.cli import main


def test_benchmark_prints_the_table_and_writes_the_csv(tmp_path, capsys) -> None:
    out_csv = tmp_path / "rows.csv"
    rc = main(["benchmark", "--tiers", "Straight,MriSequence", "--seeds", "0,1", "--set", "sim.duration_s=0.1",
               "--workers", "1", "--csv", str(out_csv)])
    assert rc == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split()[:3] == ["tier", "controller", "scenario"]
    assert [line.split()[:2] for line in out[1:6]] == [["Straight", "law24"], ["Straight", "ekf"],
                                                       ["Straight", "predictive"], ["MriSequence", "law24"],
                                                       ["MriSequence", "predictive"]]
    assert "no ekf loop" in out[6]
    rows = list(csv.DictReader(out_csv.open()))
    assert len(rows) == 5 and rows[1]["scenario"] == "sound_small_artery_ekf" and rows[0]["seeds"] == "2"


@pytest.mark.parametrize(("argv", "said"), [
    (["--tiers", "Nope"], "unknown tier 'Nope'"),
    (["--seeds", "zero"], "--seeds must be seeds >= 0"),
    (["--seeds", "5-1"], "runs backwards"),
    (["--controllers", "pid"], "--controllers: unknown controller 'pid'"),
    (["--controllers", "none"], "nothing to run"),
    (["--policy", "vb_no_such_module_43:act"], "module 'vb_no_such_module_43' does not import"),
    (["--policy", "act"], "controller.policy must be 'module:callable'"),
    (["--workers", "0"], "--workers must be >= 1"),
])
def test_bad_input_is_one_line_and_exit_2(argv, said, capsys) -> None:
    assert main(["benchmark", *argv]) == 2
    err = capsys.readouterr().err
    assert said in err and err.count("\n") == 1 and err.startswith("vesselbot benchmark: error:")
