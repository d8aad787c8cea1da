"""``vesselbot simulate`` on a full disk: each output whole or not at all, one line naming the path, exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vesselbot_ros.cli import main as cli_main
from vesselbot_ros.scanner.hardware import preset_changes
from vesselbot_ros.testing import cli_on_a_full_disk

ROOT = Path(__file__).resolve().parents[3]
SOUND = ROOT / "config" / "sound_small_artery.yaml"
OLD = {"metrics.json": '{"old": 1}\n', "timeseries.npz": "old series", "scenario.yaml": "name: old\n"}


@pytest.mark.parametrize("fill_after", ["", "vesselbot_ros.sim.simulate_cli:run_closed_loop"],
                         ids=["full-before-the-run", "full-after-the-run"])
def test_a_full_disk_leaves_the_earlier_outputs_and_no_empty_or_probe_file(tmp_path: Path, fill_after: str) -> None:
    out = tmp_path / "o"
    out.mkdir()
    for name, text in OLD.items():
        (out / name).write_text(text)
    child = cli_on_a_full_disk(["simulate", "--config", str(SOUND), "--out", str(out), "--duration", "0.05",
                                "--set", "reference.duration_s=0.05"], fill_after=fill_after)
    err = child.stderr.strip().splitlines()
    assert child.returncode == 2, child.stderr
    assert len(err) == 1 and err[0].startswith("vesselbot simulate: error: ")
    assert "File too large: the disk is full or a file size limit was reached" in err[0]
    # the message names the path: the folder refused before the run, or the file that could not be written after it
    assert (f"--out {out} is not writable" in err[0] if not fill_after
            else f"cannot write {out / 'metrics.json'} " in err[0] and "metrics.json is unchanged" in err[0])
    assert {p.name: p.read_text() for p in out.iterdir()} == OLD  # no 0-byte file, no temporary or probe file


def test_hardware_flies_the_same_run_as_the_presets_keys_given_with_set(tmp_path: Path, capsys) -> None:
    common = ["simulate", "--config", "clinical_3t_small_artery", "--duration", "0.05"]
    assert cli_main([*common, "--hardware", "propulsion_insert", "--out", str(tmp_path / "hw")]) == 0
    sets = [a for k, v in preset_changes("propulsion_insert").items() for a in ("--set", f"{k}={v}")]
    assert cli_main([*common, *sets, "--out", str(tmp_path / "set")]) == 0
    assert (tmp_path / "hw" / "scenario.yaml").read_text() == (tmp_path / "set" / "scenario.yaml").read_text()
    m_hw, m_set = (json.loads((tmp_path / d / "metrics.json").read_text()) for d in ("hw", "set"))
    for m in (m_hw, m_set):
        m.pop("wall_time_s", None)
        m.pop("setup_wall_time_s", None)
    assert m_hw == m_set
    assert "saturation_T_per_m: 0.4" in (tmp_path / "hw" / "scenario.yaml").read_text()  # the insert's 400 mT/m
    # --set applies after --hardware
    capsys.readouterr()
    assert cli_main([*common, "--hardware", "propulsion_insert", "--set", "coil.saturation_T_per_m=0.3",
                     "--out", str(tmp_path / "both")]) == 0
    assert "saturation_T_per_m: 0.3" in (tmp_path / "both" / "scenario.yaml").read_text()


def test_an_unknown_hardware_preset_is_one_line_listing_the_known_ones(tmp_path: Path, capsys) -> None:
    assert cli_main(["simulate", "--hardware", "mri9000", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["vesselbot simulate: error: --hardware: unknown scanner preset 'mri9000'; known presets: "
                   "clinical_3t, clinical_3t_mfde, paper, propulsion_insert"]
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("kind", ["observer.kind=ekf", "controller.kind=predictive"])
def test_a_3d_tree_takes_the_filter_and_the_predictive_controller_to_the_outlet_in_both_loops(tmp_path: Path,
                                                                                             kind: str) -> None:
    """Issue 40: every kind in every geometry.  The carotid bifurcation (a 3-D tree) with the extended Kalman filter,
    and with the predictive controller, reaches its outlet compiled and per tick, with the same bits."""
    runs = {}
    for path in ("compiled", "per_tick"):
        out = tmp_path / path
        assert cli_main(["simulate", "--config", "carotid_bifurcation_3d_eca", "--set", kind, "--path", path,
                         "--out", str(out)]) == 0
        m = json.loads((out / "metrics.json").read_text())
        assert m.pop("loop_path") == path
        assert m["status"] == "ok" and m["reached_target"] == 1, m
        for key in ("wall_time_s", "setup_wall_time_s"):
            m.pop(key)
        with np.load(out / "timeseries.npz") as z:
            runs[path] = (json.dumps(m, sort_keys=True), {k: z[k] for k in z.files})
    assert runs["compiled"][0] == runs["per_tick"][0]
    series = runs["compiled"][1]
    assert series["p_true"].shape[1] == 3
    for col, values in series.items():
        assert np.array_equal(values, runs["per_tick"][1][col], equal_nan=True), col
