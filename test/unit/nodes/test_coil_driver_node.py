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
