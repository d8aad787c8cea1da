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
    import conftest
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.serialization import serialize_message

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


# -- a control engineer is never misled by a figure (issue 14) ----------------------------------------------------


@pytest.fixture(scope="module")
def series(synthetic_bag):
    from vesselbot_ros.bag.reader import read_timeseries
    from vesselbot_ros.bag.report import metrics_timeseries

    m = metrics_timeseries(read_timeseries(synthetic_bag[0]), dt_s=1e-3)
    return m["t_s"], m


def _labels(ax):
    return [t.get_text() for t in ax.get_legend().get_texts()]


def test_fig9a_draws_the_vessel_at_a_stated_time_over_the_whole_path_with_time_marks(series):
    import matplotlib

    matplotlib.use("Agg")
    from vesselbot_ros.bag.report import fig9a_trajectory

    t, m = series
    m = dict(m, diameter_m=2.5e-3 * (1 + 0.1 * np.sin(2 * np.pi * t)))  # pulsating, as in the paper
    m["p_true"] = m["p_true"].copy()
    m["p_true"][500:, 0] = m["p_true"][500:, 0][::-1]  # the robot moves backwards for a while
    fig = fig9a_trajectory(t, m)
    ax = fig.axes[0]
    labels = _labels(ax)
    assert any(lb.startswith("walls at t = 0.75 s (narrowest)") for lb in labels)  # min of 1 + 0.1 sin(2 pi t)
    assert any(lb.startswith("wall motion over the run (D = 2.25 to 2.75 mm)") for lb in labels)
    assert "every 0.25 s" in labels
    # the walls are straight (a tube whose diameter pulsates in time) and span reference and trajectory
    walls = [ln for ln in ax.get_lines() if ln.get_label().startswith("walls at") or ln.get_label() == "_child2"]
    x_lo, x_hi = ax.get_xlim()
    ref_x = m["p_ref"][:, 0] * 1e3
    assert x_lo <= ref_x.min() and ref_x.max() <= x_hi
    for ln in walls:
        y = ln.get_ydata()
        assert y[0] == y[-1] and ln.get_xdata()[0] == x_lo and ln.get_xdata()[-1] == x_hi
    marks = sorted(a.get_text() for a in ax.texts)
    assert marks == sorted(f"{v:g} s" for v in np.arange(0, 1.0, 0.25))


def test_fig9b_axis_is_in_um_spans_the_errors_and_labels_the_window(series):
    from vesselbot_ros.bag.report import fig9b_errors

    t, m = series
    fig = fig9b_errors(t, m, {"saturated": [], "slew limited": [], "fault": []}, after_s=0.6)
    ax = fig.axes[0]
    assert ax.get_ylabel() == "error (um)"
    lo, hi = ax.get_ylim()
    assert 0.1 <= lo <= 1.0 and hi >= 300.0  # not down to the 1e-12 of t = 0
    labels = _labels(ax)
    assert "metrics window starts (0.6 s)" in labels
    assert "150 um bound (paper, tracking)" in labels and "10 um bound (paper, estimation)" in labels
    bound = next(ln for ln in ax.get_lines() if ln.get_label().startswith("150 um"))
    assert bound.get_ydata()[0] == pytest.approx(150.0)


def test_fig10a_shows_the_norm_against_u_sat_and_the_rate_against_the_slew_limit(series):
    from vesselbot_ros.bag.report import fig10a_gradients

    t, m = series
    spans = {"saturated": [(0.2, 0.3)], "slew limited": [(0.0, 1.0)], "fault": []}
    fig = fig10a_gradients(t, m, spans, slew_limit_T_per_m_per_s=100.0)
    top, bottom = fig.axes
    assert top.get_ylabel() == "|U| (mT/m)" and "U_sat (limit on |U|)" in _labels(top)
    applied = next(ln for ln in top.get_lines() if ln.get_label() == "|U| applied")
    np.testing.assert_allclose(applied.get_ydata(), np.linalg.norm(m["g_applied"], axis=1) * 1e3, rtol=1e-12)
    assert bottom.get_ylabel() == "|dU/dt| (mT/m/s)"
    assert "slew limit (100 T/m/s per axis)" in _labels(bottom)
    # slew limiting over the whole run does not hide the saturation shading: it is a strip at the bottom
    patches = {p.get_label(): p for p in top.patches if not p.get_label().startswith("_")}
    sat, slew = patches["saturated"], patches["slew limited"]
    assert slew.get_path().get_extents(slew.get_transform()).height < 0.1 * top.bbox.height
    assert sat.get_path().get_extents(sat.get_transform()).height > 0.9 * top.bbox.height


def test_force_plot_axis_is_not_stretched_by_negligible_terms(series):
    from vesselbot_ros.bag.report import FORCE_AXIS_DECADES, forces_figure

    t, m = series
    m = dict(m, forces=m["forces"].copy())
    m["forces"][:, 4, :] = 1e-16  # van der Waals far from the wall
    fig = forces_figure(t, m, {"saturated": [], "slew limited": [], "fault": []})
    ax = fig.axes[0]
    lo, hi = ax.get_ylim()
    assert lo >= hi / 10 ** (FORCE_AXIS_DECADES + 1)
    labels = _labels(ax)
    assert any("below the axis: van der Waals (max 1.4e-16 N)" in lb for lb in labels)
    assert "van der Waals" not in labels


def test_tracking_windows_come_from_the_phase_rows_clipped_to_the_run():
    from vesselbot_ros.bag.report import tracking_windows

    ts = {"phase.phase": np.array([1, 2, 3, 2, 1, 2]),
          "phase.window_start_s": np.array([0.0, 0.02, 0.022, 0.052, 0.054, 0.074]),
          "phase.window_end_s": np.array([0.02, 0.022, 0.052, 0.054, 0.074, 0.076])}
    assert tracking_windows(ts, 0.06) == [(0.0, 0.02), (0.054, 0.06)]
    assert tracking_windows(ts, 1.0) == [(0.0, 0.02), (0.054, 0.074)]
    assert tracking_windows({"phase.phase": np.array([0]), "phase.window_start_s": np.array([0.0]),
                             "phase.window_end_s": np.array([np.inf])}, 1.0) == []  # continuous: nothing to shade
    assert tracking_windows({}, 1.0) == []  # a bag from before the scanner


# -- a 3-D vessel tree: Fig. 9a as two projections ------------------------------------------------------------------

def _y(t):
    """The 3-D bag's robot y (m): a swing out of the plane."""
    return 1.5e-3 * np.sin(2 * np.pi * t)


def _write_3d_bag(path, n_ticks, network="carotid_bifurcation_3d", outlet="ica"):
    """The synthetic graph's ticks with y: the robot at y(t), the reference at 0.9 y(t), the estimate at y(t) + 6 um."""
    import conftest

    from vesselbot_ros.graph_spec import topic

    def with_y(k, name, msg):
        y = _y(k * 1e-3)
        if name == topic("truth").name:
            msg.position.y = y
        elif name == topic("reference").name:
            msg.position.y = 0.9 * y
        elif name == topic("estimate").name:
            msg.pose.pose.position.y = y + 6e-6

    meta = {"scenario": "synthetic_3d", "seed": 1, "mode": "lockstep",
            "config": {"sim": {"control_rate_Hz": 1000.0},
                       "physics": {"vessel": {"network": network}, "flow": {"diameter_pulsation": 0.05}},
                       "reference": {"route_outlet": outlet}}}
    conftest.write_synthetic_bag(path, n_ticks, run_metadata=meta, edit=with_y)


def _fake_navigation(monkeypatch):
    """navigation_outcome stand-in (its wall is the 3-D plant's compiled lookup: tens of seconds to build)."""
    from vesselbot_ros.bag import report

    seen = {}

    def outcome(network, outlet, t, p_true, blood=None, pulsation=None):
        seen.update(network=network, outlet=outlet, p_true=np.asarray(p_true), pulsation=pulsation)
        return {"branch_final": "cca", "reached_target": False, "route_outlet": outlet}

    monkeypatch.setattr(report, "navigation_outcome", outcome)
    return seen


def test_a_3d_tree_run_gets_xz_and_xy_projections_of_its_tubes_and_paths(tmp_path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    from vesselbot_ros.bag.reader import read_timeseries
    from vesselbot_ros.bag.report import metrics_timeseries, positions_3d, tree_trajectory

    seen = _fake_navigation(monkeypatch)
    _write_3d_bag(tmp_path / "b", 400)
    metrics = write_report(tmp_path / "b", tmp_path / "rep")
    assert (tmp_path / "rep" / FIGURES[0]).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    ts = read_timeseries(tmp_path / "b")
    # the branch reached and the time outside the lumen from the 3-D positions (the 3-D plant's wall)
    assert seen["network"] == "carotid_bifurcation_3d" and np.array_equal(seen["p_true"], positions_3d(ts)["p_true"])
    # the lumen is judged against the run's own pulsating wall (its flow section, defaults for what it leaves out)
    assert seen["pulsation"] == pytest.approx((0.05, 2.0 * np.pi, 0.5 * np.pi))
    assert metrics["branch_final"] == "cca"
    m, p = metrics_timeseries(ts, dt_s=1e-3), positions_3d(ts)
    # the same ticks; (x, z) as the metrics take them, y besides
    assert np.array_equal(p["p_true"][:, [0, 2]], m["p_true"]) and np.array_equal(p["p_ref"][:, [0, 2]], m["p_ref"])
    assert np.array_equal(p["p_true"][:, 1], _y(m["t_s"])) and np.array_equal(p["x_hat"][:, 1], _y(m["t_s"]) + 6e-6)
    fig = tree_trajectory(m["t_s"], p, "carotid_bifurcation_3d", metrics)
    xz, xy = fig.axes
    assert (xz.get_ylabel(), xy.get_ylabel()) == ("z (mm)", "y (mm)")
    assert "projected on XZ; branch reached: cca (target ica: NOT reached)" in xz.get_title() and "XY" in xy.get_title()
    for ax, col in ((xz, 2), (xy, 1)):
        lines = {ln.get_label(): ln for ln in ax.get_lines()}
        assert set(lines) >= {"robot", "reference", "estimate", "every 0.25 s"}
        assert np.array_equal(lines["robot"].get_xdata(), p["p_true"][:, 0] * 1e3)
        assert np.array_equal(lines["robot"].get_ydata(), p["p_true"][:, col] * 1e3)
        assert np.array_equal(lines["reference"].get_ydata(), p["p_ref"][:, col] * 1e3)
        assert {a.get_text() for a in ax.texts} == {"cca", "ica", "eca"}  # every branch's tube, named
        x_lo, x_hi = ax.get_xlim()
        assert x_lo < -40.0 and x_hi > 30.0  # the whole tree: the CCA from x = -40 mm, the ICA to 29 mm
    # the XY panel shows the tree leaving the plane: the ICA's and ECA's tubes reach y = -3.5 mm - 2.8 mm
    assert xy.dataLim.y0 < -6.0


def test_a_rejected_command_is_drawn_as_a_gap_and_counted(tmp_path, monkeypatch, capsys):
    """The coil driver rejected the commands from tick 500 (and recorded commanded = 0): the report's commanded
    gradient is NaN there (a gap in Fig. 10a, not a line at 0), metrics.json counts them and `vesselbot report`
    prints the count (issue 38)."""
    import conftest

    from vesselbot_ros.bag.reader import read_timeseries
    from vesselbot_ros.bag.report import metrics_timeseries
    from vesselbot_ros.cli import main as cli_main
    from vesselbot_ros.graph_spec import topic

    def reject_from_500(k, name, msg):
        if name == topic("coil_state").name and k >= 500:
            msg.command_rejected = True
            msg.commanded.x = msg.commanded.z = 0.0

    meta = dict(conftest.RUN_METADATA, config={"sim": {"control_rate_Hz": 1000.0}})
    monkeypatch.setattr(conftest, "RUN_METADATA", meta)
    conftest.write_synthetic_bag(tmp_path / "b", 1000, edit=reject_from_500)
    m = metrics_timeseries(read_timeseries(tmp_path / "b"), dt_s=1e-3)
    assert np.all(np.isnan(m["g_cmd"][500:])) and np.all(np.isfinite(m["g_cmd"][:500]))
    np.testing.assert_array_equal(m["cmd_rejected"], np.arange(1000) >= 500)
    assert cli_main(["report", str(tmp_path / "b"), "--out", str(tmp_path / "rep")]) == 0
    out = capsys.readouterr().out
    assert "rejected commands 500 (the first at t = 0.500 s; the coil ramped to zero)" in out
    on_disk = json.loads((tmp_path / "rep" / "metrics.json").read_text())
    assert on_disk["rejected_commands"] == 500 and on_disk["first_rejected_command_s"] == pytest.approx(0.5)
    assert on_disk["rejected_command_intervals_s"] == [[pytest.approx(0.5), pytest.approx(1.0)]]
