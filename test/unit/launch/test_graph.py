"""The launcher's pure parts: real-time figures from diagnostics, the held factor, the count comparison."""

from __future__ import annotations

import pytest

pytest.importorskip("rclpy")

from vesselbot_ros.launch.graph import (  # noqa: E402
    RealtimeStats,
    check_recorded_counts,
    held_real_time_factor,
    realtime_report,
)


def test_realtime_report_counts_the_periods_a_node_never_reached():
    diag = {
        "vesselbot_observer": {"missed_periods": "3", "period_tick": "989", "input_age_max_s": "0.004",
                               "input_age_mean_s": "0.001", "lateness_mean_s": "0.0002"},
        "vesselbot_controller": {"missed_periods": "0", "period_tick": "999"},
    }
    obs, ctl, plant = realtime_report(diag, ["observer", "controller", "plant"], 1000)
    assert (obs.missed, obs.periods) == (3 + 10, 1000)  # ticks 990..999 never handled
    assert obs.fraction == pytest.approx(0.013, abs=1e-12)
    assert (ctl.missed, ctl.fraction) == (0, 0.0)
    assert plant.missed == 1000  # no diagnostics at all: every period missed


def test_held_factor_is_the_asked_one_when_no_node_misses():
    ok = [RealtimeStats("observer", 5, 1000, 0.0, 0.0, 0.0004)]  # 0.5 %: within the 1 % allowed
    assert held_real_time_factor(ok, asked=1.0, achieved=1.02, dt=1e-3) == 1.0


def test_held_factor_follows_the_latest_node():
    late = [RealtimeStats("observer", 900, 1000, 0.0, 0.0, 0.004),
            RealtimeStats("controller", 950, 1000, 0.0, 0.0, 0.010)]
    # the controller ends its periods 10 ms late on average: a 1 ms tick fits in its period at factor 0.1
    assert held_real_time_factor(late, asked=1.0, achieved=0.9, dt=1e-3) == pytest.approx(0.1, abs=1e-12)


def test_count_comparison_names_every_difference():
    assert check_recorded_counts({"/a": 3, "/b": 2}, {"/a": 3, "/b": 2, "/extra": 5}) == []
    assert check_recorded_counts({"/a": 2000}, {"/a": 1999}) == ["/a: published 2000, recorded 1999"]
    assert check_recorded_counts({"/a": 1}, {}) == ["/a: published 1, recorded 0"]
