"""The coil driver node on rejected commands: from the rejected tick on the coil ramps to zero at the slew limit
(the core coil stage's rule, the runner's), stays there, and follows the next valid command; it never holds a stale
gradient (it used to hold the last good one for as long as the commands stayed bad)."""

from __future__ import annotations

import math

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

DT_S = 1e-3
SLEW = 2.0  # T/m/s: 2 mT/m per tick, so the ramp spans many ticks
G0 = 0.04  # T/m


@pytest.fixture()
def driver():
    from rclpy.parameter import Parameter

    from vesselbot_ros.nodes.coil_driver_node import CoilDriverNode

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = CoilDriverNode(context=ctx, parameter_overrides=[
        Parameter("coil.slew_rate", value="custom"), Parameter("coil.custom_slew_rate_T_per_m_per_s", value=SLEW)])
    states: list = []
    publish = node.publish

    def spy(key, msg):
        if key == "coil_state":
            states.append(msg)
        publish(key, msg)

    node.publish = spy  # type: ignore[method-assign]
    try:
        yield node, states
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)


def _command(node, k: int, gx: float, frame: bytes = b"vessel\0") -> None:
    from vesselbot_ros.nodes import conversions as cv

    msg = cv.gradient_flat(k * DT_S, np.array([gx, 0.0]), 2)
    node._on_command(msg._replace(header_frame_id_cdr=frame, header_frame_id_size=len(frame)))


@pytest.mark.parametrize("bad", ["nan", "inf", "wrong_frame"])
def test_a_rejected_command_ramps_the_coil_to_zero_at_the_slew_limit_and_a_valid_one_resumes(driver, bad):
    node, states = driver
    for k in range(40):  # reaches G0 at tick 19
        _command(node, k, G0)
    for k in range(40, 80):
        if bad == "wrong_frame":
            _command(node, k, G0, b"map\0")
        else:
            _command(node, k, math.nan if bad == "nan" else math.inf)
    for k in range(80, 90):
        _command(node, k, G0)
    g = np.array([s.applied_x for s in states])
    rejected = np.array([s.command_rejected for s in states])
    assert len(g) == 90 and g[39] == pytest.approx(G0, abs=1e-15)
    np.testing.assert_array_equal(rejected, [False] * 40 + [True] * 40 + [False] * 10)
    step = SLEW * DT_S
    # from the first rejected tick on: down by the slew step each tick, zero after |G| / slew = 20 ticks, then zero
    np.testing.assert_allclose(g[40:60], G0 - step * np.arange(1, 21), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(g[60:80], 0.0)
    assert np.all(np.abs(np.diff(g)) <= step * (1 + 1e-9))  # the slew limit holds through the ramp
    np.testing.assert_allclose(g[80:90], step * np.arange(1, 11), rtol=0, atol=1e-12)  # and the valid command resumes
    assert node.diagnostic_values()["rejected_commands"] == "40"
    assert all(s.commanded_x == 0.0 for s in states[40:80])  # nothing non-finite is published


def test_a_stall_request_waits_for_a_live_but_late_controller_and_is_answered_at_once_for_a_silent_one(driver):
    """Lockstep: once the watchdog answered a tick the plant asks after 20 ms; a controller that is alive but slower
    than that (a command of any tick within the last stall timeout) gets a full stall timeout for the tick asked for,
    and its command is taken; a silent one is answered by the watchdog at once (it used to be answered at once
    always, so a slow controller, once late, stayed locked out for the rest of the run)."""
    import time

    from vesselbot_ros.nodes import conversions as cv

    node, states = driver
    assert node.lockstep
    for k in range(10):
        _command(node, k, G0)
    node._on_stall(cv.header(10 * DT_S))  # the first request (the plant waited a full stall timeout): answered at once
    assert len(states) == 11 and states[10].watchdog_active is False and states[10].commanded_x == 0.0
    _command(node, 10, G0)  # tick 10's command comes late: stale, rejected, but the controller is alive
    assert len(states) == 11 and node.rejected_commands == 0
    node._on_stall(cv.header(11 * DT_S))  # deferred: no answer yet
    assert len(states) == 11 and node.deferred_stalls == 1 and not node._defer_timer.is_canceled()
    node._on_stall(cv.header(11 * DT_S))  # a repeated request for the deferred tick moves nothing
    assert len(states) == 11 and node.deferred_stalls == 1
    _command(node, 11, G0)  # in time for the deferred tick: taken
    assert len(states) == 12 and states[11].commanded_x == G0 and node._defer_timer.is_canceled()
    node._deferred_answer()  # a timer firing after the answer moves nothing
    assert len(states) == 12
    node._on_stall(cv.header(12 * DT_S))  # deferred again (a command just came) ...
    assert len(states) == 12 and node.deferred_stalls == 2
    node._deferred_answer()  # ... and its stall timeout passed without a command: the watchdog answers
    assert len(states) == 13 and states[12].commanded_x == 0.0 and node.diagnostic_values()["deferred_stalls"] == "2"
    assert node.watchdog_ticks == 2
    node._last_command_wall = time.monotonic() - 2 * node.graph.stall_timeout_s  # the controller went silent
    node._on_stall(cv.header(13 * DT_S))  # answered at once, as a dead controller's ticks are
    assert len(states) == 14 and node.watchdog_ticks == 3 and node.deferred_stalls == 2
