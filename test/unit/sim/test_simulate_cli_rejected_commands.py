"""``vesselbot simulate`` with a hostile controller or observer (issue 38, section 2): never a coil frozen on a stale
gradient, never a traceback, never "ok".

A rejected command ramps the coil to zero at the slew limit from its tick on (the watchdog's ramp), the run counts
the rejected ticks in ``metrics.json`` (``rejected_commands``, ``first_rejected_command_s``), ends with one warning
line on stderr and exits 1; a plug-in that cannot be built is one line and exit 2.  The plug-ins are in
``test/plugins/vesselbot_hostile_plugin.py``.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from vesselbot_ros.cli import main as cli_main
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
PLUGINS = ROOT / "test" / "plugins"
#: A slow coil, so that the ramp to zero takes several ticks: 5 T/m/s is 5 mT/m per 1 ms tick.
SLEW = 5.0
COIL = ["--set", "coil.slew_rate=custom", "--set", f"coil.custom_slew_rate_T_per_m_per_s={SLEW}"]
DURATION_S = 1.0
START_S = 0.5


@pytest.fixture(autouse=True)
def _plugins_on_path(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.syspath_prepend(str(PLUGINS))


def _simulate(tmp_path: Path, capsys: pytest.CaptureFixture[str], *sets: str) -> tuple[int, str, Path]:
    out = tmp_path / "out"
    args = ["simulate", "--config", "sound_small_artery", "--out", str(out), "--duration", str(DURATION_S), *COIL]
    for s in sets:
        args += ["--set", s]
    rc = cli_main(args)
    return rc, capsys.readouterr().err, out


def _warning_lines(err: str) -> list[str]:
    return [ln for ln in err.splitlines() if ln.startswith("vesselbot: warning:")]


def test_a_nan_controller_ramps_the_coil_to_zero_at_the_slew_limit_counts_warns_and_exits_1(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """NaN from t = 0.5 s: the coil is at zero within |G_last| / slew (+2 ticks), no step exceeds S dt on the way,
    the rejected ticks are exactly those from 0.5 s, one warning line, exit 1 (today: held at 36 mT/m, exit 0)."""
    rc, err, out = _simulate(tmp_path, capsys, "controller.kind=vesselbot_hostile_plugin:NaNFrom")
    assert rc == 1
    assert "Traceback" not in err
    lines = _warning_lines(err)
    assert len(lines) == 1, err
    assert re.fullmatch(r"vesselbot: warning: 500 of 1000 controller commands rejected \(non-finite\) from "
                        r"t = 0\.500 s; the coil ramped to zero", lines[0]), lines[0]
    m = json.loads((out / "metrics.json").read_text())
    assert m["rejected_commands"] == 500 and m["first_rejected_command_s"] == START_S
    ts = np.load(out / "timeseries.npz")
    t, g, g_cmd = ts["t_s"], ts["g_applied"], ts["g_cmd"]
    k0 = int(np.argmax(t >= START_S - 1e-12))
    np.testing.assert_array_equal(ts["cmd_rejected"] != 0, t >= START_S - 1e-12)
    assert np.all(np.isnan(g_cmd[k0:])) and np.all(np.isfinite(g_cmd[:k0]))  # as commanded, not 0
    g_last = np.abs(g[k0 - 1]).max()
    assert g_last > 2 * SLEW * 1e-3  # the coil was really driven: the ramp takes several ticks
    dt = 1e-3
    ticks = math.ceil(g_last / (SLEW * dt)) + 2
    assert np.all(g[k0 + ticks:] == 0.0), "the coil must be at zero, and stay there"
    steps = np.abs(np.diff(g[k0 - 1:], axis=0))
    assert np.all(steps <= SLEW * dt * (1 + 1e-9))  # slew respected through the ramp
    assert np.all(ts["cmd_status"][k0:] == 2)  # the controller's status says nonfinite, not ok


def test_the_nan_controller_gives_the_same_bits_in_the_compiled_and_the_per_tick_loop() -> None:
    """The plug-in has a compiled form: simulate runs it compiled; its Python form per tick gives every column and
    metric bit for bit (the rejection codes, the ramp and the counts included)."""
    sc = load_scenario("sound_small_artery", duration=DURATION_S, sets=[
        "controller.kind=vesselbot_hostile_plugin:NaNFrom", "coil.slew_rate=custom",
        f"coil.custom_slew_rate_T_per_m_per_s={SLEW}"])
    for value in ("nan", "inf"):
        s = load_scenario("sound_small_artery", duration=DURATION_S, sets=[
            f"controller={{kind: 'vesselbot_hostile_plugin:NaNFrom', value: {value}}}", "coil.slew_rate=custom",
            f"coil.custom_slew_rate_T_per_m_per_s={SLEW}"]) if value == "inf" else sc
        a, b = run_closed_loop(s), run_closed_loop(s, path="per_tick")
        assert (a.path, b.path) == ("compiled", "per_tick")
        assert sorted(a.timeseries) == sorted(b.timeseries)
        for key, col in a.timeseries.items():
            np.testing.assert_array_equal(col, b.timeseries[key], err_msg=key)
            assert col.dtype == b.timeseries[key].dtype, key
        assert {k: repr(v) for k, v in a.metrics.items()} == {k: repr(v) for k, v in b.metrics.items()}
        assert a.metrics["rejected_commands"] == 500


def test_a_controller_whose_constructor_raises_is_one_line_naming_the_kind_exit_2(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc, err, _ = _simulate(tmp_path, capsys, "controller.kind=vesselbot_hostile_plugin:BrokenConstructor")
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0] == ("vesselbot simulate: error: controller.kind: the controller kind "
                        "'vesselbot_hostile_plugin:BrokenConstructor' could not be built: its constructor raised "
                        "RuntimeError: no calibration file for this coil")


def test_a_bare_ndarray_of_the_right_shape_is_a_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The same PD law returning its gradient as a bare (2,) array flies the run the ControlCommand form flies
    (its u is unknown: NaN), nothing rejected, exit 0 (today: an AttributeError traceback)."""
    rc, err, out = _simulate(tmp_path, capsys, "controller={kind: 'vesselbot_hostile_plugin:Hostile', mode: bare_array}")
    assert rc == 0, err
    assert not _warning_lines(err)
    m = json.loads((out / "metrics.json").read_text())
    assert m["rejected_commands"] == 0 and "first_rejected_command_s" not in m
    bare = np.load(out / "timeseries.npz")
    same = run_closed_loop(load_scenario("sound_small_artery", duration=DURATION_S, sets=[
        "controller={kind: 'vesselbot_hostile_plugin:NaNFrom', start_s: 100.0}", *COIL[1::2]]))
    np.testing.assert_array_equal(bare["g_applied"], same.timeseries["g_applied"])
    np.testing.assert_array_equal(bare["p_true"], same.timeseries["p_true"])
    assert np.all(np.isnan(bare["u_cmd"]))


@pytest.mark.parametrize(("mode", "reason"), [
    ("raise", r"the controller raised; first: ZeroDivisionError: the hostile controller divided by zero"),
    ("none", r"not a command; first: returned NoneType, not a command"),
    ("wrong_length", r"not a command; first: gradient of shape \(3,\), expected \(2,\)"),
    ("bad_status", r"not a command; first: status 'fine', not one of \['ok', 'stale', 'nonfinite'\]"),
])
def test_every_other_bad_answer_of_a_controller_is_rejected_counted_and_warned(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], mode: str, reason: str) -> None:
    """A controller that raises in its step, returns None, a gradient of the wrong length or an unknown status from
    0.5 s: the same containment as NaN (the coil at zero, counted, one warning line naming the first, exit 1)."""
    rc, err, out = _simulate(tmp_path, capsys, f"controller={{kind: 'vesselbot_hostile_plugin:Hostile', mode: {mode}}}")
    assert rc == 1 and "Traceback" not in err
    lines = _warning_lines(err)
    assert len(lines) == 1, err
    assert re.fullmatch(rf"vesselbot: warning: 500 of 1000 controller commands rejected \({reason}\) from "
                        r"t = 0\.500 s; the coil ramped to zero", lines[0]), lines[0]
    m = json.loads((out / "metrics.json").read_text())
    assert m["rejected_commands"] == 500 and m["first_rejected_command_s"] == START_S
    ts = np.load(out / "timeseries.npz")
    assert np.all(ts["g_applied"][-400:] == 0.0)


def test_an_observer_that_returns_nan_estimates_is_contained(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """NaN estimates from 0.5 s: the controller is not called on them, the command is rejected (the coil at zero),
    counted and warned, exit 1 (today: a ModelInputError from the law at the first NaN tick, nothing written)."""
    rc, err, out = _simulate(tmp_path, capsys, "observer.kind=vesselbot_hostile_plugin:NaNObserver")
    assert rc == 1 and "Traceback" not in err
    assert any("500 of 1000 controller commands rejected (non-finite estimate) from t = 0.500 s" in ln
               for ln in _warning_lines(err)), err
    m = json.loads((out / "metrics.json").read_text())
    assert m["rejected_commands"] == 500
    ts = np.load(out / "timeseries.npz")
    assert np.all(ts["g_applied"][-400:] == 0.0) and np.all(ts["cmd_rejected"][500:] == 2)
