"""The launcher's pure parts: real-time figures from diagnostics, the report and its verdict, the count comparison."""

from __future__ import annotations

import pytest

pytest.importorskip("rclpy")

from vesselbot_ros.graph_spec import REALTIME_FACTOR_LIMIT, REALTIME_MISSED_LIMIT
from vesselbot_ros.launch.graph import (
    RealtimeReport,
    RealtimeStats,
    check_recorded_counts,
    realtime_report,
)


def test_realtime_report_counts_the_periods_a_node_never_reached():
    diag = {
        "vesselbot_observer": {"missed_periods": "3", "period_tick": "989", "input_age_max_s": "0.004",
                               "input_age_mean_s": "0.001", "lateness_mean_s": "0.0002", "lateness_max_s": "0.003"},
        "vesselbot_controller": {"missed_periods": "0", "period_tick": "999"},
    }
    obs, ctl, plant = realtime_report(diag, ["observer", "controller", "plant"], 1000)
    assert (obs.missed, obs.periods) == (3 + 10, 1000)  # ticks 990..999 never handled
    assert obs.fraction == pytest.approx(0.013, abs=1e-12)
    assert obs.lateness_max_s == 0.003 and ctl.lateness_max_s == 0.0
    assert (ctl.missed, ctl.fraction) == (0, 0.0)
    assert plant.missed == 1000  # no diagnostics at all: every period missed


def _stats(role: str, missed: int, periods: int = 1000, worst_s: float = 0.004) -> RealtimeStats:
    return RealtimeStats(role, missed, periods, 0.002, 0.001, 0.0002, worst_s)


def test_average_factor_is_sim_time_advanced_over_wall_time_whatever_the_deadlines():
    # 999 ticks of 1 ms (first to last published) in 1.9983 s of wall: 0.49992, not "about 0.5"
    rt = RealtimeReport(0.5, 0.999, 1.9983, (_stats("coil_driver", 26, 1000),))
    assert rt.factor_held == pytest.approx(0.999 / 1.9983, rel=1e-15)
    assert not rt.factor_short  # 99.98 % of the asked factor
    assert "average real-time factor held 0.4999 of 0.5 asked (99.98 %" in rt.factor_text()
    assert RealtimeReport(1.0, 1.0, 0.0, ()).factor_held == 0.0  # no wall time: nothing held, no division by zero


@pytest.mark.parametrize(("missed", "sim_s", "wall_s", "failed", "reasons"), [
    (10, 0.999, 1.999, False, []),  # 1.0 % missed: at the limit, held
    (11, 0.999, 1.999, True, ["deadlines missed"]),  # 1.1 % > 1 %: jitter fails the run, though the factor held
    (0, 0.999, 2.03, True, ["average factor short"]),  # 98.4 % of the asked factor, no deadline missed
    (0, 0.999, 2.0, False, []),  # 99.9 % of the asked factor
    (50, 0.999, 2.5, True, ["deadlines missed", "average factor short"]),
])
def test_verdict_follows_from_the_figures_by_the_rule(missed, sim_s, wall_s, failed, reasons):
    rt = RealtimeReport(0.5, sim_s, wall_s, (_stats("observer", 0), _stats("coil_driver", missed)))
    assert rt.failed is failed and rt.reasons == reasons
    assert rt.failed == (any(st.fraction > REALTIME_MISSED_LIMIT for st in rt.nodes)
                         or rt.factor_held < 0.5 * (1 - REALTIME_FACTOR_LIMIT))
    line = rt.verdict_line()
    assert line.startswith("real time not held (" + " and ".join(reasons) + ")" if failed else "real time held")
    # the line states both figures apart, with the worst node's count, its fraction and its worst lateness
    assert f"node coil_driver missed {missed} of 1000 control periods ({missed / 10:.2f} %" in line or missed == 0
    assert f"average real-time factor held {sim_s / wall_s:.4f} of 0.5 asked" in line
    d = rt.as_dict()
    assert d["failed"] is failed and d["reasons"] == reasons and d["factor_held"] == rt.factor_held
    assert [n["missed"] for n in d["nodes"]] == [0, missed] and d["verdict"] == line


def test_missed_periods_within_the_limit_are_a_warning_naming_each_node():
    rt = RealtimeReport(1.0, 1.999, 2.0, (_stats("imager", 0), _stats("controller", 7, 2000, 0.0031)))
    assert not rt.failed
    assert rt.warnings == ["node controller missed 7 of 2000 control periods (0.35 %, within the 1 % allowed), "
                           "worst 3.10 ms late"]
    assert rt.worst.role == "controller"


def test_a_node_that_never_reported_fails_the_run():
    rt = RealtimeReport(1.0, 1.999, 2.0, tuple(realtime_report({}, ["plant"], 2000)))
    assert rt.failed and rt.reasons == ["deadlines missed"] and rt.nodes[0].missed == 2000


def test_count_comparison_names_every_difference():
    assert check_recorded_counts({"/a": 3, "/b": 2}, {"/a": 3, "/b": 2, "/extra": 5}) == []
    assert check_recorded_counts({"/a": 2000}, {"/a": 1999}) == ["/a: published 2000, recorded 1999"]
    assert check_recorded_counts({"/a": 1}, {}) == ["/a: published 1, recorded 0"]


def test_rejection_reasons_come_from_the_controller_node_or_else_the_coil_driver():
    """The warning line's words: the controller node's own rejections (the core's words), with the first
    exception; a user's node in the controller's slot: what the coil driver rejected."""
    from vesselbot_ros.launch.graph import rejection_reasons

    ctl = {"command_rejected:nonfinite": "3", "command_rejected:raised": "2", "command_rejected:malformed": "0",
           "rejected_command_error": "ZeroDivisionError: boom"}
    drv = {"rejected_reason:non_finite": "5", "rejected_reason:wrong_frame_id": "1"}
    got = rejection_reasons({"vesselbot_controller": ctl, "vesselbot_coil_driver": drv})
    assert got == {"rejected_command_reasons": "non-finite, the controller raised",
                   "rejected_command_error": "ZeroDivisionError: boom"}
    got = rejection_reasons({"vesselbot_coil_driver": drv})
    assert got == {"rejected_command_reasons": "non-finite, wrong frame_id"}
    assert rejection_reasons({}) == {}
