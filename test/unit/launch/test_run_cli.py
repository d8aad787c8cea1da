"""`vesselbot run` checks every argument before it creates anything or starts anything: one line, exit 2."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from vesselbot_ros import cli

REPO = Path(__file__).resolve().parents[3]
PAPER = REPO / "config" / "paper_small_artery.yaml"

# (extra arguments, substrings of the one-line error)
BAD = [
    (["--domain-id", "232"], ["--domain-id", "232"]),
    (["--domain-id", "-1"], ["--domain-id", "-1"]),
    (["--real-time-factor", "nan"], ["--real-time-factor", "nan"]),
    (["--real-time-factor", "inf"], ["--real-time-factor", "inf"]),
    (["--real-time-factor", "0"], ["--real-time-factor", "0"]),
    (["--stall-timeout", "-1"], ["--stall-timeout", "-1"]),
    (["--stall-timeout", "nan"], ["--stall-timeout", "nan"]),
    (["--wait-timeout", "0"], ["--wait-timeout", "0"]),
    (["--run-timeout", "-5"], ["--run-timeout", "-5"]),
    (["--duration", "nan"], ["--duration", "nan"]),
    (["--duration", "-1"], ["--duration", "-1"]),
    (["--without", "plant", "--without", "plant"], ["--without plant", "more than once"]),
    (["--namespace", "1robot"], ["--namespace", "1robot"]),
    (["--namespace", "a b"], ["--namespace", "a b"]),
    (["--report", "--no-record"], ["--report", "--no-record"]),
    (["--metrics-json", "/nonexistent_dir_vb/m.json"], ["--metrics-json", "nonexistent_dir_vb"]),
    (["--live-port", "70000"], ["--live-port", "70000"]),
    (["--live-port", "-1"], ["--live-port", "-1"]),
    (["--live", "--live-rate", "-5"], ["--live-rate", "-5"]),
    (["--live", "--live-rate", "nan"], ["--live-rate", "nan"]),
    (["--compression", "zstd_small", "--no-record"], ["--compression zstd_small", "--no-record"]),
    (["--hardware", "mri9000"], ["--hardware: unknown scanner preset 'mri9000'; known presets: clinical_3t, "]),
    # the tracker joins the graph only with an imager of MR frames
    (["--without", "tracker"], ["--without tracker", "no tracker", "imager.kind 'mri'", "mr_images"]),
]


@pytest.mark.parametrize(("extra", "needles"), BAD, ids=[" ".join(b[0]) for b in BAD])
def test_bad_argument_exits_2_with_one_line_and_creates_nothing(tmp_path, capsys, monkeypatch, extra, needles):
    monkeypatch.chdir(tmp_path)
    code = cli.main(["run", "--config", str(PAPER), "--record-dir", str(tmp_path / "bag"), "--quiet", *extra])
    out, err = capsys.readouterr()
    assert code == 2, out + err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vesselbot run: error:"), err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    assert os.listdir(tmp_path) == []  # no bag, no runs/, no log directory
    assert "Traceback" not in err


def test_busy_domain_is_a_bad_argument_too(tmp_path, capsys, monkeypatch):
    from vesselbot_ros.ros_env import allocate_domain

    monkeypatch.chdir(tmp_path)
    with allocate_domain() as lease:
        code = cli.main(["run", "--config", str(PAPER), "--domain-id", str(lease.domain_id), "--record-dir",
                         str(tmp_path / "bag"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert f"--domain-id: ROS domain id {lease.domain_id} is in use" in err
    assert os.listdir(tmp_path) == []


def test_without_choices_come_from_the_graph_spec(capsys):
    from vesselbot_ros.graph_spec import LOOP_ROLES

    with pytest.raises(SystemExit):
        cli.main(["run", "--without", "nonsense"])
    err = capsys.readouterr().err
    for r in LOOP_ROLES:
        assert r in err



def test_a_run_that_does_not_fit_is_refused_before_any_directory(tmp_path, capsys, monkeypatch):
    """``vesselbot run`` calls the scenario layer's resource check before it makes the run directory."""
    huge = tmp_path / "cfg" / "huge.yaml"
    huge.parent.mkdir()
    huge.write_text(PAPER.read_text().replace("control_rate_Hz: 1000.0", "control_rate_Hz: 1.0e+9"))
    assert "1.0e+9" in huge.read_text()
    monkeypatch.chdir(tmp_path)
    code = cli.main(["run", "--config", str(huge), "--record-dir", str(tmp_path / "bag"), "--quiet"])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert "sim.control_rate_Hz" in lines[0] and "sim.duration_s" in lines[0], err
    assert os.listdir(tmp_path) == ["cfg"]  # no bag, no runs/, no log directory


def test_no_config_means_the_scenario_make_run_runs(tmp_path, capsys, monkeypatch):
    """`vesselbot run` and `make run` (empty CONFIG: run's default) run sound_small_artery, from any directory."""
    from vesselbot_ros.launch.run_cli import DEFAULT_CONFIG
    from vesselbot_ros.sim.scenario import DEFAULT_SCENARIO, load_scenario

    assert DEFAULT_CONFIG == DEFAULT_SCENARIO == "sound_small_artery"
    assert "\nCONFIG ?=\n" in (REPO / "Makefile").read_text()
    monkeypatch.chdir(tmp_path)
    assert load_scenario(DEFAULT_CONFIG).name == "sound_small_artery"
    with pytest.raises(SystemExit) as exc:
        cli.main(["run", "--compression", "gzip"])
    assert exc.value.code == 2 and "invalid choice: 'gzip'" in capsys.readouterr().err


def test_hardware_is_the_presets_keys_with_set_applied_after_it_as_simulate_and_plan(tmp_path, capsys, monkeypatch):
    from vesselbot_ros.config import ConfigError
    from vesselbot_ros.scanner.hardware import preset_changes
    from vesselbot_ros.sim import scenario as sc

    seen = []

    def stop(scenario, *args, **kwargs):  # the scenario the graph would run, before anything is made
        seen.append(scenario)
        raise ConfigError("stopped here")

    monkeypatch.setattr(sc, "check_resources", stop)
    monkeypatch.chdir(tmp_path)
    code = cli.main(["run", "--config", "clinical_3t_small_artery", "--hardware", "propulsion_insert",
                     "--set", "coil.saturation_T_per_m=0.3", "--quiet"])
    assert code == 2 and "stopped here" in capsys.readouterr().err
    by_set = sc.load_scenario("clinical_3t_small_artery", sets=[
        *(f"{k}={v}" for k, v in preset_changes("propulsion_insert").items()), "coil.saturation_T_per_m=0.3"])
    assert seen == [by_set]
    assert (by_set.coil.saturation_T_per_m, by_set.sequence.propulsion_window_s) == (0.3, 0.06)


PLUGINS = REPO / "test" / "plugins"


def test_a_plugin_whose_constructor_raises_is_one_line_before_any_node_starts(tmp_path, capsys, monkeypatch):
    """The plug-in controller is built once in the launcher: its constructor's exception is one line naming the
    kind and the exception, exit 2, no run directory, and the graph is never started (it used to start the whole
    graph, then the controller node died)."""
    from vesselbot_ros.launch import graph

    monkeypatch.syspath_prepend(str(PLUGINS))
    monkeypatch.chdir(tmp_path)
    started = []
    monkeypatch.setattr(graph, "run_graph", lambda *a, **k: started.append(a))
    code = cli.main(["run", "--config", str(PAPER), "--set", "controller.kind=vesselbot_graph_fault_plugin:RaisingCtor",
                     "--record-dir", str(tmp_path / "bag"), "--quiet"])
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, out + err
    assert "vesselbot_graph_fault_plugin:RaisingCtor" in lines[0] and "RuntimeError: no licence for this coil" in lines[0]
    assert "Traceback" not in err and not started
    assert os.listdir(tmp_path) == []  # no bag, no runs/, no log directory


def test_without_the_controller_its_kind_is_not_built(tmp_path, monkeypatch):
    """--without controller: the user's node takes the slot, so the scenario's kind is never built (nor refused)."""
    from vesselbot_ros.launch.run_cli import check_plugin_stages
    from vesselbot_ros.sim.scenario import load_scenario

    monkeypatch.syspath_prepend(str(PLUGINS))
    s = load_scenario(str(PAPER), sets=["controller.kind=vesselbot_graph_fault_plugin:RaisingCtor"])
    check_plugin_stages(s, ["controller"])
    from vesselbot_ros.config import ConfigError

    with pytest.raises(ConfigError, match="controller.kind"):
        check_plugin_stages(s, [])


@pytest.mark.parametrize(("metrics", "code", "needles"), [
    ({"rejected_commands": 1500, "first_rejected_command_s": 0.5, "n_ticks": 2000,
      "rejected_command_reasons": "non-finite", "status": "rejected_commands"}, 1,
     ["vesselbot: warning: 1500 of 2000 controller commands rejected (non-finite) from t = 0.500 s",
      "the coil ramped to zero"]),
    ({"rejected_commands": 0, "n_ticks": 2000, "status": "ok"}, 0, []),
    # lockstep ticks the coil driver's watchdog answered (a user's node sent nothing usable in time): not ok either
    ({"rejected_commands": 0, "n_ticks": 2000, "status": "ok", "watchdog_ticks": 37}, 1,
     ["vesselbot: warning: 37 of 2000 ticks got no valid controller command in time: the coil driver's watchdog "
      "answered them"]),
])
def test_a_run_whose_commands_were_rejected_warns_in_one_line_and_exits_1(tmp_path, capsys, monkeypatch, metrics,
                                                                          code, needles):
    """The run completed, yet the coil flew on rejected commands: one warning line, exit 1 (it used to exit 0)."""
    import numpy as np

    from vesselbot_ros.launch import graph

    monkeypatch.chdir(tmp_path)
    n = 4
    ts = {k: np.zeros((n, 2)) for k in ("p_true", "x_hat", "g_applied")}
    result = graph.GraphResult(dict(metrics), ts, 1.0, 1.0, {})
    monkeypatch.setattr(graph, "run_graph", lambda *a, **k: result)
    out_json = tmp_path / "m.json"
    got = cli.main(["run", "--config", str(PAPER), "--no-record", "--quiet", "--metrics-json", str(out_json)])
    _out, err = capsys.readouterr()
    assert got == code, err
    warnings = [line for line in err.splitlines() if "warning" in line]
    assert len(warnings) == (1 if needles else 0), err
    for needle in needles:
        assert needle in warnings[0]
    import json

    assert json.loads(out_json.read_text())["metrics"]["rejected_commands"] == metrics["rejected_commands"]


@pytest.mark.parametrize("target", ["/sys/vesselbot_metrics.json", "/sys/kernel/uevent_seqnum"],
                         ids=["new-file-in-a-read-only-folder", "read-only-file"])
def test_metrics_json_to_a_read_only_place_is_refused_before_anything_runs(tmp_path, monkeypatch, capsys, target):
    # a chmod 0o500 folder stops no one running as root (the tests do); sysfs refuses a new file and a write to a
    # read-only attribute, whoever asks
    if not Path(target).parent.is_dir() or (target.endswith("seqnum") and not Path(target).is_file()):
        pytest.skip("no sysfs here")
    import vesselbot_ros.sim.scenario as scenario_module

    def no_run(*a, **k):
        raise AssertionError("the scenario was loaded: the run went on")

    monkeypatch.setattr(scenario_module, "load_scenario", no_run)
    monkeypatch.chdir(tmp_path)
    rc = cli.main(["run", "--no-record", "--metrics-json", target])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert err[0].startswith(f"vesselbot run: error: --metrics-json {target} is not writable (Permission denied)")
    assert list(tmp_path.iterdir()) == []


def test_a_run_that_does_not_fit_on_the_disk_is_one_line_with_both_sizes_and_leaves_no_bag_folder(
        tmp_path, monkeypatch, capsys):
    """8 MB free: one line naming the bag folder, the estimate (3.9 MiB of bag), what it needs in all and what is
    free, by the one rule (no second 256 MiB minimum), and no empty bag folder."""
    import collections
    import shutil

    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10**10, 10**10, 8 * 10**6))
    bag = tmp_path / "runs" / "r1"
    rc = cli.main(["run", "--record-dir", str(bag)])  # the default: 2 s at 1 kHz
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert f"recording it to {bag} needs 19.9 MiB free (3.9 MiB of bag at 2048 B per tick, and 16.0 MiB for the " \
           f"node logs, the bag's metadata and a report), but only 7.6 MiB is free on {tmp_path}" in err[0]
    assert "256" not in err[0]
    assert list(tmp_path.iterdir()) == []
