"""`vesselbot run` through a 3-D vessel tree: the pure runner's numbers bit for bit, y on the wire and in the bag.

paper_iiic_network_upper_3d.yaml (the III-C artery written as a 3-D tree; the imager is noisy in y, so y is real
everywhere downstream of it) over 0.6 s (the outlier burst at 0.5 s included), lockstep, seed 0: once with one
process per node (the default) and once composed in one process (with ``--report``).  Each run's metrics equal
the ROS-free loop's bit for bit, and its bag holds every per-tick vector on three axes, each equal to the pure
runner's column: truth, measurement, estimate, reference, coil state (slew flags of all three axes), forces; the
report computed from the bag alone has the same metrics (errors in space).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from vesselbot_ros.bag.reader import open_bag, read_timeseries
from vesselbot_ros.graph_spec import topic
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario

REPO = Path(__file__).resolve().parents[2]
CONFIG = "config/paper_iiic_network_upper_3d.yaml"
DURATION_S = 0.6


@pytest.fixture(scope="module")
def pure():  # type: ignore[no-untyped-def]
    scenario = load_scenario(REPO / CONFIG, duration=DURATION_S, changes={"sim.record_forces": True})
    assert scenario.dims == 3
    return scenario, run_closed_loop(scenario, 0)


@pytest.fixture(scope="module", params=["processes", "single_process"])
def run(request, tmp_path_factory):  # type: ignore[no-untyped-def]
    tmp = tmp_path_factory.mktemp(f"tree_run_{request.param}")
    bag, metrics = tmp / "bag", tmp / "metrics.json"
    cmd = [sys.executable, "-m", "vesselbot_ros.cli", "run", "--config", CONFIG, "--seed", "0", "--quiet",
           "--duration", str(DURATION_S), "--record-dir", str(bag), "--metrics-json", str(metrics),
           "--wait-timeout", "120", "--run-timeout", "240"]
    if request.param == "single_process":
        cmd += ["--single-process", "--report"]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=420)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return bag, json.loads(metrics.read_text())["metrics"]


def test_lockstep_metrics_equal_the_pure_runner_bit_for_bit(run, pure) -> None:  # type: ignore[no-untyped-def]
    _bag, m = run
    _scenario, res = pure
    for k, v in res.metrics.items():
        assert m[k] == v, k  # every metric the pure runner has, errors in space included: bit for bit


def test_the_bag_holds_every_vector_on_three_axes_as_the_pure_runner_has_it(run, pure) -> None:  # type: ignore[no-untyped-def]
    bag, _m = run
    scenario, res = pure
    info = open_bag(bag)
    assert info.consistent and info.run_metadata["dims"] == 3
    n = scenario.sim.n_ticks
    for key in ("truth", "measurement", "estimate", "reference", "gradient_command", "coil_state", "coil_applied"):
        assert info.topic(topic(key).name).count == n, key  # nothing published is missing
    ts = read_timeseries(info)
    want = res.timeseries
    for got, col in (("truth.p_WR", "p_true"), ("truth.v_WR", "v_true"), ("estimate.p_hat", "x_hat"),
                     ("estimate.v_hat", "z_hat"), ("reference.p_ref", "p_ref"), ("reference.v_ref", "v_ref"),
                     ("reference.a_ref", "a_ref"), ("command.u_cmd", "g_cmd"), ("coil.applied", "g_applied"),
                     ("truth.applied_gradient", None)):
        arr = ts[got]
        assert arr.shape == (n, 3), got
        if col is not None:
            assert arr.tobytes() == want[col].tobytes(), got  # the doubles themselves, y included
    # the plant's input of tick k is the coil's output of tick k - 1 (zero before the first)
    assert ts["truth.applied_gradient"][1:].tobytes() == want["g_applied"][:-1].tobytes()
    slew = np.stack([ts[f"coil.slew_limited_{a}"] for a in "xyz"], axis=1)
    assert np.array_equal(slew, want["slew_limited"])
    frames = ~np.isnan(want["meas_p"][:, 0])  # the ticks a frame was delivered at (the imager repeats it between)
    assert ts["measurement.p_meas"][ts["measurement.fresh"]].tobytes() == want["meas_p"][frames].tobytes()
    forces = np.stack([ts[f"truth.F_{t}"] for t in ("magnetic", "drag", "apparent_weight", "contact", "van_der_waals",
                                                     "electrostatic", "steric", "total")], axis=1)
    assert forces.tobytes() == want["forces"].tobytes()
    # y is real: the imager's noise in y reaches the estimate, the command and the robot
    for got in ("measurement.p_meas", "estimate.p_hat", "coil.applied", "truth.p_WR"):
        assert np.abs(ts[got][:, 1]).max() > 0.0, got


@pytest.mark.parametrize("run", ["single_process"], indirect=True)  # the run that wrote the report
def test_the_report_from_the_bag_alone_has_the_same_metrics(run, pure) -> None:  # type: ignore[no-untyped-def]
    bag, m = run
    rep = json.loads((bag.with_name(f"{bag.name}.report") / "metrics.json").read_text())  # beside the bag
    _scenario, res = pure
    for k in ("tracking_error_max_m", "tracking_error_rms_m", "estimation_error_max_m", "estimation_error_rms_m",
              "velocity_estimation_error_max_m_per_s", "saturation_time_s", "slew_limited_time_s", "contact_time_s",
              "max_gradient_T_per_m", "n_ticks"):
        assert rep[k] == m[k] == res.metrics[k], k


@pytest.mark.parametrize("role", ["observer", "controller"])
def test_replay_into_a_role_reproduces_the_3d_run_bit_for_bit(run, role, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """`vesselbot replay --into` a fresh observer or controller of the tree's run: every output on three axes
    as recorded (no tolerance)."""
    bag, _m = run
    if "single_process" not in str(bag):
        pytest.skip("replayed from the single-process run's bag (the other bag holds the same messages)")
    out = tmp_path / role
    proc = subprocess.run([sys.executable, "-m", "vesselbot_ros.cli", "replay", str(bag), "--into", role, "--out", str(out),
                           "--tolerance", "0"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    n = int(round(DURATION_S * 1000))
    assert f"{n} bit-identical" in proc.stdout, proc.stdout
    summary = json.loads((out / "comparison.json").read_text())
    diffs = summary["max_abs_difference"]
    assert set(diffs.values()) == {0.0} and any(k.endswith("_y_m") or "_y_" in k for k in diffs), diffs


@pytest.mark.parametrize("sets", [("observer.kind=ekf", "controller.flow_compensation=estimate"),
                                  ("controller.kind=predictive",)], ids=["ekf", "predictive"])
def test_the_filter_and_the_predictive_controller_run_in_the_tree_over_the_nodes(sets, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Issue 40: every kind in every geometry, in the nodes too.  The extended Kalman filter (its blood-velocity
    scale fed to law (24)) and the predictive controller fly the tree over ROS, lockstep, with the pure runner's
    metrics bit for bit."""
    duration = 0.3
    scenario = load_scenario(REPO / CONFIG, duration=duration, sets=list(sets))
    assert scenario.dims == 3
    want = run_closed_loop(scenario, 0).metrics
    metrics = tmp_path / "metrics.json"
    cmd = [sys.executable, "-m", "vesselbot_ros.cli", "run", "--config", CONFIG, "--seed", "0", "--quiet",
           "--duration", str(duration), "--record-dir", str(tmp_path / "bag"), "--metrics-json", str(metrics),
           "--single-process", "--wait-timeout", "120", "--run-timeout", "240"]
    for s in sets:
        cmd += ["--set", s]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=420)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    got = json.loads(metrics.read_text())["metrics"]
    for k, v in want.items():
        assert got[k] == v, k
