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


# -- the numbers docs/reproduction.md quotes (issue 14) -----------------------------------------------------------


def _summary(tmp_path, capsys, *sets):
    import csv

    argv = ["design-map", "--out", str(tmp_path), "--no-png"]
    for s in sets:
        argv += ["--set", s]
    assert main(argv) == 0
    capsys.readouterr()
    with (tmp_path / "design_map_summary.csv").open() as fh:
        return {(r["vessel"], r["design"]): float(r["max_ratio"]) for r in csv.DictReader(fh)}


def test_design_map_numbers_quoted_in_the_docs(tmp_path, capsys):
    import pytest

    base = _summary(tmp_path / "a", capsys)
    # EF with Z(3.4) = 1.257e-3 (docs/reproduction.md table); EF < 1 everywhere, largest in the arteriole
    ef = {v: base[(v, "EF")] for v in ("artery", "small_artery", "arteriole", "capillary")}
    assert ef == pytest.approx({"artery": 0.032, "small_artery": 0.021, "arteriole": 0.036, "capillary": 0.013},
                               abs=6e-4)
    assert max(ef, key=ef.get) == "arteriole" and max(ef.values()) < 1
    # "Δ limit": 1 µm changes every maximum by < 1 %; 10 µm lowers the artery BP maximum by 6.4 %
    one = _summary(tmp_path / "b", capsys, "design_study.grid.min_gap_m=1e-6")
    assert all(abs(one[k] / base[k] - 1) < 0.01 for k in base)
    ten = _summary(tmp_path / "c", capsys, "design_study.grid.min_gap_m=1e-5")
    assert ten[("artery", "BP")] / base[("artery", "BP")] - 1 == pytest.approx(-0.064, abs=0.002)


def test_force_balance_rows_are_evaluated_at_the_gap_they_name(tmp_path, capsys):
    import pytest

    assert main(["force-balance", "--out", str(tmp_path)]) == 0
    rows = {ln[:24].strip(): ln[24:].split() for ln in capsys.readouterr().out.splitlines()
            if ln.startswith(("upper gap", "lower gap"))}
    for label, cols in rows.items():
        assert float(cols[0]) == pytest.approx(float(label.split()[2]), rel=1e-9), label
    assert float(rows["upper gap 1e-06 m"][5]) == pytest.approx(1.66e-11, rel=0.01)  # van der Waals at 1 um


def test_design_map_figure_explains_its_contour_and_star():
    from vesselbot_ros.analysis.design_map import DesignStudy, all_design_maps
    from vesselbot_ros.analysis.design_map_cli import maps_figure
    from vesselbot_ros.config import apply_overrides, load_dataclass, load_yaml
    from vesselbot_ros.physics.params import PhysicsParams

    root = __import__("pathlib").Path(__file__).resolve().parents[3] / "config"
    params = load_dataclass(PhysicsParams, load_yaml(root / "physics_default.yaml")["physics"], "physics")
    study = DesignStudy.from_mapping(apply_overrides(load_yaml(root / "design_study.yaml")["design_study"],
                                                     {"grid.n_lambda": 20, "grid.n_delta": 10}))
    fig = maps_figure(all_design_maps(params, study))
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any(t.startswith("white line: F_m/F_tot = 1") for t in texts)
    assert any(t.startswith("red star: maximum of F_m/F_tot") for t in texts)


import pytest  # noqa: E402


@pytest.mark.parametrize(("argv", "match"), [
    (["design-map", "--no-png", "--set", "design_study.grid.n_lambda=1e9"], "must be <= 1000000 points per map"),
    (["force-balance", "--min-gap", "nan"], "--min-gap must be in (0, "),
    (["force-balance", "--min-gap", "-1"], "--min-gap must be in (0, "),
    (["force-balance", "--min-gap", "1"], "--min-gap must be in (0, "),
    (["force-balance", "--time", "nan"], "--time must be a finite time"),
])
def test_bad_analysis_arguments_are_one_line_before_any_work(tmp_path, capsys, argv, match):
    assert main([*argv, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0]
