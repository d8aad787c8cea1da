"""The lockstep input join: ticks served with a lag, stale / future / off-grid inputs rejected, nothing moved."""

from __future__ import annotations

from typing import Any

from vesselbot_ros.graph_spec import ns_of_time
from vesselbot_ros.nodes.tick_join import TickJoin

DT = 1e-3


class FakeNode:
    """What the join needs of its node: the control period and the rejection sink."""

    dt = DT

    def __init__(self) -> None:
        self.rejected: list[tuple[str, str]] = []

    def reject(self, key: str, reason: str, detail: str = "") -> None:
        self.rejected.append((key, reason))


def _join(**kw: Any) -> tuple[TickJoin, FakeNode]:
    node = FakeNode()
    return TickJoin(node, {"measurement": 0, "coil_applied": 1}, **kw), node  # type: ignore[arg-type]


def test_a_tick_is_ready_once_every_input_it_needs_is_in_and_lagged_inputs_serve_the_next_tick() -> None:
    join, node = _join()
    assert join.put("measurement", 0, "m0")
    assert join.pop_ready() == {"measurement": "m0", "coil_applied": None}  # tick 0 needs no lagged input
    assert join.put("measurement", 1, "m1")
    assert join.pop_ready() is None  # coil_applied 0 serves tick 1 and is not in yet
    assert join.put("coil_applied", 0, "c0")
    assert join.pop_ready() == {"measurement": "m1", "coil_applied": "c0"}
    assert join.k == 2 and node.rejected == []


def test_stale_duplicate_and_too_far_ahead_inputs_are_rejected_and_move_nothing() -> None:
    join, node = _join(window=2)
    join.put("measurement", 0, "m0")
    assert not join.put("measurement", 0, "again")  # a second input for a waiting tick
    join.pop_ready()
    assert not join.put("measurement", 0, "late")  # a tick already handled
    assert not join.put("measurement", 4, "early")  # more than window ticks ahead of tick 1
    assert node.rejected == [("measurement", "stale_tick")] * 2 + [("measurement", "future_tick")]
    assert join.k == 1 and join.pop_ready() is None


def test_an_unbounded_window_takes_inputs_keyed_by_arrival_order() -> None:
    join, node = _join(windows={"measurement": None})
    assert join.put("measurement", 1000, "far")
    assert node.rejected == []


def test_tick_of_accepts_only_stamps_on_the_grid_that_match_the_tick_field() -> None:
    join, node = _join()
    assert join.tick_of("measurement", ns_of_time(7 * DT)) == 7
    assert join.tick_of("measurement", ns_of_time(7 * DT), 7) == 7
    assert join.tick_of("measurement", ns_of_time(7 * DT), 6) is None
    assert join.tick_of("measurement", ns_of_time(7.5 * DT)) is None
    assert node.rejected == [("measurement", "off_tick_stamp")] * 2


def test_expect_takes_only_the_current_tick_while_running() -> None:
    join, node = _join()
    assert join.expect("clock", 0)
    assert not join.expect("clock", 1)
    assert not join.expect("clock", 0, running=False)
    assert node.rejected == [("clock", "future_tick"), ("clock", "stale_tick")]
