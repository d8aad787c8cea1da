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
