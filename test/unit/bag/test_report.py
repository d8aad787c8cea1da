"""write_report: figures and metrics from the bag alone, equal to hand-computed values."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from vesselbot_ros.bag.report import FIGURES, bool_intervals, write_report
from vesselbot_ros.bag.synthetic import PARAMS
from vesselbot_ros.errors import BagError


def test_bool_intervals_by_hand():
    t = np.arange(10) * 0.1
    f = np.array([0, 1, 1, 0, 0, 1, 0, 0, 1, 1], bool)
    got = bool_intervals(t, f)
    assert [(round(a, 9), round(b, 9)) for a, b in got] == [(0.1, 0.3), (0.5, 0.6), (0.8, 1.0)]
    assert bool_intervals(t, np.zeros(10, bool)) == []


def test_report_writes_every_figure_and_metrics_equal_to_the_closed_form(synthetic_bag, tmp_path):
    path, _ = synthetic_bag
    out = tmp_path / "rep"
    metrics = write_report(path, out)
    for name in FIGURES:
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, name
    on_disk = json.loads((out / "metrics.json").read_text())
    P = PARAMS
    # tracking error e(t) = sqrt((e0 exp(-t/tau))^2 + e_z^2) decreases: its max after 0.6 s is at t = 0.6
    e06 = math.hypot(P["e0"] * math.exp(-0.6 / P["tau"]), P["e_z"])
    assert on_disk["tracking_error_max_m"] == pytest.approx(e06, rel=1e-9)
    t = np.arange(600, 1000) * 1e-3
    e = np.hypot(P["e0"] * np.exp(-t / P["tau"]), P["e_z"])
    assert on_disk["tracking_error_rms_m"] == pytest.approx(float(np.sqrt(np.mean(e**2))), rel=1e-9)
    assert on_disk["estimation_error_max_m"] == pytest.approx(P["est_dx"], rel=1e-9)
    assert on_disk["velocity_estimation_error_max_m_per_s"] == pytest.approx(P["est_dvx"], rel=1e-9)
    tt = np.arange(1000) * 1e-3
    n_sat = int(np.sum(np.abs(0.1 * np.sin(2 * np.pi * tt)) > P["u_sat"]))
    assert on_disk["saturation_time_s"] == pytest.approx(n_sat * 1e-3, rel=1e-9)
    assert len(on_disk["saturated_intervals_s"]) == 2  # the two lobes of |sin| above 0.8
    # applied gradient norm: hypot(0.08, 0.05) while saturated
    assert on_disk["max_gradient_T_per_m"] == pytest.approx(math.hypot(0.08, 0.05), rel=1e-12)
    assert on_disk["outlier_frames_detected"] == 20  # 1 mm offsets on the 20 ticks of [0.5, 0.52)
    kinds = {(f["kind"], f["source"]) for f in on_disk["faults"]}
    assert kinds == {("outlier_burst", "config"), ("outlier_frames", "detected")}
    det = next(f for f in on_disk["faults"] if f["source"] == "detected")
    assert det["start_s"] == pytest.approx(0.5, abs=1e-9) and det["end_s"] == pytest.approx(0.52, abs=1e-9)
    assert on_disk["seed"] == 7 and on_disk["message_counts"]["/vesselbot/truth"] == 1000
    assert metrics["n_ticks"] == 1000


def test_report_needs_the_graph_topics(tmp_path):
    from rclpy.serialization import serialize_message
    from std_msgs.msg import String

    from vesselbot_ros.bag.writer import BagWriter

    with BagWriter(tmp_path / "b") as bag:
        c = bag.add_topic("/chatter", "std_msgs/msg/String")
        bag.write(c, serialize_message(String(data="x")), 1)
    with pytest.raises(BagError, match="no messages for 'truth'"):
        write_report(tmp_path / "b")


def test_metrics_timeseries_rebuilds_tick_times_as_k_times_dt(synthetic_bag):
    from vesselbot_ros.bag.reader import read_timeseries
    from vesselbot_ros.bag.report import metrics_timeseries

    ts = read_timeseries(synthetic_bag[0])
    dt = 1e-3
    m = metrics_timeseries(ts, dt_s=dt)
    # exactly the launcher's np.arange(n) * dt, never float(stamp)
    assert np.array_equal(m["t_s"], np.arange(1000) * dt)
    raw = metrics_timeseries(ts)
    assert np.allclose(raw["t_s"], m["t_s"], rtol=0, atol=1e-12)


def test_report_takes_the_window_from_the_run_config_and_counters_from_final_diagnostics(tmp_path, monkeypatch):
    from vesselbot_ros.bag.report import DIAGNOSTIC_COUNTERS
    from vesselbot_ros.nodes.plant_node import PLANT_STAT_NAMES

    assert DIAGNOSTIC_COUNTERS["plant"] == PLANT_STAT_NAMES
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.serialization import serialize_message

    import conftest

    meta = dict(conftest.RUN_METADATA, config={"sim": {"metrics_after_s": 0.25, "control_rate_Hz": 1000.0}})
    monkeypatch.setattr(conftest, "RUN_METADATA", meta)
    bag, _ = conftest.write_synthetic_bag(tmp_path / "b", 400, finish=False)
    conn = bag.connections["/diagnostics"]
    for steps in (10, 12345):  # the last status of a node wins
        st = DiagnosticStatus(name="vesselbot_plant", values=[KeyValue(key="plant_steps", value=str(steps)),
                                                              KeyValue(key="finished", value="true")])
        bag.write(conn, serialize_message(DiagnosticArray(status=[st])), 1_800_000_000_000_000_000 + steps)
    st = DiagnosticStatus(name="vesselbot_observer", values=[KeyValue(key="measurements_used", value="399")])
    bag.write(conn, serialize_message(DiagnosticArray(status=[st])), 1_800_000_000_000_100_000)
    bag.finish()
    metrics = write_report(tmp_path / "b", tmp_path / "rep")
    assert metrics["after_s"] == 0.25
    assert metrics["plant_steps"] == 12345 and metrics["measurements_used"] == 399
    assert "plant_rhs_evals" not in metrics  # not reported by the bag: not invented
    assert write_report(tmp_path / "b", tmp_path / "rep2", after_s=0.3)["after_s"] == 0.3
