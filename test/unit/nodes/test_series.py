"""The run series a node keeps of what it published, and the GetSeries answer the launcher reads."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("vesselbot_msgs")

from geometry_msgs.msg import PointStamped
from nav_msgs.msg import Odometry
from vesselbot_msgs.msg import CoilState, PlantState, ReferenceSample
from vesselbot_msgs.srv import GetSeries

from vesselbot_ros.graph_spec import TOPICS, ns_of_time, role, series_service_key, service
from vesselbot_ros.nodes.conversions import codec
from vesselbot_ros.nodes.series import (
    _HAS_TICK,
    READERS,
    SERIES_COLUMNS,
    SeriesLog,
    columns_of,
    empty_series,
    series_from_response,
)

DT = 1e-3
TYPES = {"truth": PlantState, "estimate": Odometry, "reference": ReferenceSample, "coil_state": CoilState}


def _flat(msg):
    """A message's flat form (what a node publishes, and so what its log reads)."""
    return codec(type(msg)).flatten(msg)


def _stamp(msg, k):
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns_of_time(k * DT), 1_000_000_000)


def _truth(k, x):
    m = PlantState(tick=k)
    _stamp(m, k)
    m.position.x, m.position.z, m.velocity.x, m.velocity.z, m.in_contact = x, -x / 3, 2 * x, 0.1 + x, k % 2 == 1
    return _flat(m)


def _estimate(k, x, off_grid_ns=0):
    m = Odometry()
    _stamp(m, k)
    m.pose.pose.position.x, m.pose.pose.position.z = x, x / 7
    m.twist.twist.linear.x, m.twist.twist.linear.z = -x, x * 1e-3
    m.header.stamp.nanosec += off_grid_ns
    return _flat(m)


def test_every_topic_with_series_has_a_reader_of_its_width_and_a_serving_role():
    with_series = [t for t in TOPICS if t.series]
    assert {t.key for t in with_series} == set(READERS) == set(TYPES)
    for t in with_series:
        assert len(READERS[t.key](_flat(TYPES[t.key]()))) == len(columns_of(t.key))
        assert _HAS_TICK[t.key] == hasattr(TYPES[t.key](), "tick")
        assert series_service_key(t.publisher) in role(t.publisher).services
        assert service(series_service_key(t.publisher)).srvtype == "vesselbot_msgs/srv/GetSeries"
    # each series comes from exactly one topic
    names = [n for t in with_series for n in t.series]
    assert sorted(names) == sorted(SERIES_COLUMNS)


def test_a_log_answers_exactly_the_floats_it_was_given_row_by_tick():
    log = SeriesLog(role("plant").outputs, 5, DT)
    assert log.keys == ("truth",)
    xs = {0: 0.1, 3: 1 / 3, 4: np.nextafter(2.0, 3.0)}
    for k, x in xs.items():
        log.add("truth", _truth(k, x))
        log.add("clock", object())  # topics without series are ignored
    got = series_from_response(log.fill(GetSeries.Response()))
    for k, x in xs.items():
        assert got["p_true"][k, 0] == x and got["p_true"][k, 1] == -x / 3
        assert got["v_true"][k, 1] == 0.1 + x
        assert got["in_contact"][k] == (k % 2 == 1)
    assert np.isnan(got["p_true"][[1, 2]]).all()
    assert got["in_contact"].dtype == bool and got["p_true"].shape == (5, 2)


def test_the_estimate_row_comes_from_its_stamp_and_off_grid_or_out_of_run_stamps_are_dropped():
    log = SeriesLog(("estimate",), 4, DT)
    log.add("estimate", _estimate(2, 0.5))
    log.add("estimate", _estimate(1, 9.0, off_grid_ns=400_000))  # 0.4 of a tick off the grid
    log.add("estimate", _estimate(7, 9.0))  # beyond the run
    d = log.as_dict()
    assert d["x_hat"][2].tolist() == [0.5, 0.5 / 7] and d["z_hat"][2].tolist() == [-0.5, 0.5e-3]
    assert np.isnan(d["x_hat"][[0, 1, 3]]).all()


def test_reset_forgets_every_row():
    log = SeriesLog(("reference",), 3, DT)
    log.add("reference", _flat(ReferenceSample(tick=1)))
    assert not np.isnan(log.values[1]).any()
    log.reset()
    assert np.isnan(log.values).all()


def test_a_malformed_answer_is_an_error_not_a_silent_series():
    r = GetSeries.Response(rows=3, columns=["p_true_x_m", "p_true_z_m"], values=[0.0] * 5)
    with pytest.raises(ValueError, match="5 values"):
        series_from_response(r)
    r = GetSeries.Response(rows=1, columns=["p_true_x_m", "p_true_z_m", "bogus"], values=[0.0] * 3)
    with pytest.raises(ValueError, match="bogus"):
        series_from_response(r)


def test_empty_series_cover_every_series_with_nan_or_false():
    e = empty_series(4)
    assert set(e) == set(SERIES_COLUMNS)
    assert e["slew_limited"].shape == (4, 2) and not e["slew_limited"].any()
    assert e["p_ref"].shape == (4, 2) and np.isnan(e["p_ref"]).all()


def test_a_point_message_has_no_series():
    assert SeriesLog(("measurement",), 3, DT).keys == ()
    assert columns_of("measurement") == ()
    assert PointStamped  # the imager's output carries no run series


def test_a_three_d_log_has_y_columns_and_answers_its_floats_as_three_axis_series():
    from vesselbot_ros.nodes.series import readers, series_columns

    for t in (t for t in TOPICS if t.series):  # each 3-D reader fills exactly its columns
        assert len(readers(3)[t.key](_flat(TYPES[t.key]()))) == len(columns_of(t.key, 3))
    assert series_columns(3)["p_true"] == ("p_true_x_m", "p_true_y_m", "p_true_z_m")
    assert series_columns(3)["slew_limited"] == ("slew_limited_x", "slew_limited_y", "slew_limited_z")
    assert series_columns(2)["z_hat"] == ("z_hat_x_m_per_s", "z_hat_z_m_per_s")
    log = SeriesLog(role("plant").outputs, 3, DT, dims=3)
    m = PlantState(tick=1)
    _stamp(m, 1)
    m.position.x, m.position.y, m.position.z = 1e-3, np.nextafter(-2e-4, 0.0), 3e-4
    m.velocity.y = 5e-3
    log.add("truth", _flat(m))
    got = series_from_response(log.fill(GetSeries.Response()))
    assert got["p_true"].shape == (3, 3) and got["p_true"][1].tolist() == [1e-3, np.nextafter(-2e-4, 0.0), 3e-4]
    assert got["v_true"][1, 1] == 5e-3
    c = CoilState(tick=0, slew_limited_y=True)
    coil = SeriesLog(("coil_state",), 1, DT, dims=3)
    coil.add("coil_state", _flat(c))
    got = coil.as_dict()
    assert got["slew_limited"].tolist() == [[False, True, False]] and got["g_applied"].shape == (1, 3)
    e = empty_series(2, dims=3)
    assert e["x_hat"].shape == (2, 3) and e["slew_limited"].shape == (2, 3) and e["in_contact"].shape == (2,)


def test_a_planar_log_is_unchanged_by_the_three_d_columns():
    log = SeriesLog(("coil_state",), 1, DT)
    assert log.columns == ("g_applied_x_T_per_m", "g_applied_z_T_per_m", "saturated", "slew_limited_x", "slew_limited_z",
                           "cmd_rejected")
    log.add("coil_state", _flat(CoilState(tick=0, slew_limited_y=True)))  # a planar coil never sets it; not read
    assert log.as_dict()["slew_limited"].tolist() == [[False, False]]


def test_a_y_column_without_its_x_and_z_is_malformed():
    r = GetSeries.Response(rows=1, columns=["p_true_x_m", "p_true_y_m"], values=[0.0] * 2)
    with pytest.raises(ValueError, match="p_true_z_m"):
        series_from_response(r)


@pytest.mark.parametrize("dims", [2, 3])
def test_the_coil_state_carries_the_rejected_flag_of_each_tick(dims):
    """The run's ``cmd_rejected`` series (what the metrics' rejected_commands count) is the coil's own flag."""
    log = SeriesLog(("coil_state",), 3, DT, dims=dims)
    for k in range(3):
        log.add("coil_state", _flat(CoilState(tick=k, command_rejected=k >= 1)))
    got = series_from_response(log.fill(GetSeries.Response()))
    assert got["cmd_rejected"].tolist() == [False, True, True]
    assert empty_series(2, dims)["cmd_rejected"].tolist() == [False, False]
