"""The controller node checks what its controller returned before it publishes it (the core's checked_command).

A plug-in controller that returns NaN, None, a wrong shape or raises in its step: every such tick is counted
(``status:nonfinite``, ``rejected_commands``, ``command_rejected:<reason>``), warned (WARN diagnostics), and its
command is still published, NaN, so the coil driver rejects it and ramps to zero and the bag holds it.  A finite bare
ndarray is a command.  Used to be: ``status:ok`` for every NaN, and an ``AttributeError`` for a bare ndarray.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

PLUGINS = Path(__file__).resolve().parents[2] / "plugins"
KIND = "vesselbot_graph_fault_plugin:FaultAfter"
DT_S = 1e-3


@pytest.fixture()
def controller_of(monkeypatch):
    """``controller_of(mode)``: a controller node running the fault plug-in (bad from tick 3), in its own context."""
    from rclpy.parameter import Parameter

    from vesselbot_ros.nodes.controller_node import ControllerNode

    monkeypatch.syspath_prepend(str(PLUGINS))
    made = []

    def make(mode: str):
        ctx = rclpy.Context()
        rclpy.init(context=ctx)
        node = ControllerNode(context=ctx, parameter_overrides=[
            Parameter("controller.kind", value=KIND), Parameter("controller.mode", value=mode),
            Parameter("controller.after_s", value=3 * DT_S)])
        sent: list[tuple[float, float, float]] = []
        monkeypatch.setattr(node, "publish", lambda key, msg: sent.append(
            (msg.vector_x, msg.vector_y, msg.vector_z)) if key == "gradient_command" else None)
        made.append((node, ctx))
        return node, sent

    yield make
    for node, ctx in made:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)


def _run(node, ticks: int, x_hat=(0.0, 0.0)) -> None:
    """Tick the node's command step as its lockstep join does, with a resting estimate and reference."""
    zero = np.zeros(2)
    for k in range(ticks):
        node._command(k, (np.asarray(x_hat, dtype=float), zero, 0.0, 1.0), (np.array([1e-3, 0.0]), zero, zero))


def _diag(node) -> dict[str, str]:
    return node.diagnostic_values()


@pytest.mark.parametrize(("mode", "reason"), [("nan_gradient", "nonfinite"), ("none", "malformed"),
                                              ("raise", "raised"), ("shape", "malformed")])
def test_a_bad_return_value_is_counted_warned_and_published_as_nan(controller_of, mode, reason):
    node, sent = controller_of(mode)
    _run(node, 10)
    d = _diag(node)
    assert d["status:ok"] == "3" and d["status:nonfinite"] == "7"  # used to say ok 10 times
    assert d["rejected_commands"] == "7" and d[f"command_rejected:{reason}"] == "7"
    assert d["first_rejected_command_tick"] == "3"
    assert len(sent) == 10  # every tick's command goes out (nothing dropped: the bag holds it)
    assert all(map(math.isfinite, (v for g in sent[:3] for v in g)))
    assert all(math.isnan(g[0]) and math.isnan(g[2]) for g in sent[3:])  # the driver rejects it and ramps to zero
    assert node._warn_pending and node._last_reason.startswith("rejected output: /vesselbot/gradient_command")
    if mode == "raise":
        assert d["rejected_command_error"].startswith("ZeroDivisionError: the law divided by zero at t = 0.003 s")
    if mode in ("none", "shape"):
        assert "rejected_command_malformed" in d


def test_a_bare_finite_ndarray_is_a_command(controller_of):
    node, sent = controller_of("array")
    _run(node, 6)
    d = _diag(node)
    assert d["status:ok"] == "6" and d["rejected_commands"] == "0"
    assert all(map(math.isfinite, (v for g in sent for v in g))) and len(sent) == 6


def test_a_non_finite_estimate_is_a_rejected_command_not_a_call(controller_of):
    """An observer that diverged: its tick is answered with a rejected (NaN) command, the controller not called,
    as the ROS-free runner does (it used to be dropped: the tick then waited for the driver's watchdog)."""
    node, sent = controller_of("nan_gradient")
    calls = node.controller.calls
    _run(node, 2, x_hat=(math.nan, 0.0))
    d = _diag(node)
    assert node.controller.calls == calls
    assert d["command_rejected:nonfinite_estimate"] == "2" and d["status:nonfinite"] == "2"
    assert len(sent) == 2 and all(math.isnan(g[0]) for g in sent)


def test_a_non_finite_estimate_message_gets_its_tick_answered(controller_of):
    """Through the node's inputs (lockstep): a NaN estimate of tick 0 is counted as a rejected input, and tick 0
    still gets its (rejected, NaN) command once the reference is in; tick 1's finite estimate is steered again."""
    from vesselbot_ros.nodes import conversions as cv

    node, sent = controller_of("array")  # good all along: only the estimate is bad
    zero = np.zeros(2)
    node._on_estimate(cv.estimate_flat(0.0, [math.nan, 0.0], zero, 0.0))
    node._on_estimate(cv.estimate_flat(0.0, [0.0, math.inf], zero, 0.0))  # a second one for tick 0: one rejection
    node._on_reference(cv.reference_flat(0, 0.0, [1e-3, 0.0], zero, zero))
    node._on_reference(cv.reference_flat(1, DT_S, [1e-3, 0.0], zero, zero))
    node._on_estimate(cv.estimate_flat(DT_S, zero, zero, 0.0))
    d = node.diagnostic_values()
    assert len(sent) == 2 and math.isnan(sent[0][0]) and math.isfinite(sent[1][0])
    assert d["command_rejected:nonfinite_estimate"] == "1" and d["status:ok"] == "1"
    assert node._rejected["/vesselbot/estimate"] == 2 and node._reject_reasons["non_finite"] == 2
    assert node._reject_reasons["stale_tick"] == 0
