"""The analysis CLI commands run end to end and write their outputs."""

from vesselbot_ros.cli import main


def test_design_map_cli(tmp_path, capsys):
    rc = main(["design-map", "--out", str(tmp_path), "--set", "design_study.grid.n_lambda=20",
               "--set", "design_study.grid.n_delta=10", "--no-png"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "capillary" in out and "12 maps of 20x10" in out
    assert (tmp_path / "design_map_summary.csv").read_text().count("\n") == 13
    assert (tmp_path / "map_artery_BP.csv").is_file()


def test_force_balance_cli(tmp_path, capsys):
    assert main(["force-balance", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "force_balance.png").stat().st_size > 1000
    header = (tmp_path / "force_balance.csv").read_text().splitlines()[0]
    assert "electrostatic_z_N" in header and "load_x_N" in header


def test_sensitivity_cli(tmp_path, capsys):
    assert main(["sensitivity", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "M +10%" in out and "Table II eta" in out
    assert (tmp_path / "sensitivity.png").is_file()


def test_bad_override_is_one_line_error(tmp_path, capsys):
    assert main(["force-balance", "--out", str(tmp_path), "--set", "physics.robot.radius_m=-1"]) == 2
    assert "physics.robot.radius_m must be > 0" in capsys.readouterr().err
    assert main(["force-balance", "--out", str(tmp_path), "--set", "bogus"]) == 2
