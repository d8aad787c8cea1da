"""Law (24) (vesselbot_ros.control.backstepping) on three axes: the planar rule, axis by axis, in one class."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vesselbot_ros.control.backstepping import BacksteppingController, BacksteppingGains, ControllerParams, backstepping_u
from vesselbot_ros.control.bspline_reference import RefSample
from vesselbot_ros.control.estimate import Estimate
from vesselbot_ros.errors import ModelInputError


class _FreeModel:
    """F = 0: the bead coasts (dims 2 or 3), B = b I."""

    def __init__(self, dims: int, b: float = 2.0) -> None:
        self.input_gain = b
        self.input_matrix = b * np.eye(dims)
        self.stats = np.zeros(4, dtype=np.int64)

    def new_contact_state(self) -> np.ndarray:
        return np.zeros(4)

    def propagate(self, t0, t1, y, u, contact):  # type: ignore[no-untyped-def]
        d = len(u)
        h = t1 - t0
        y[:d] = y[:d] + h * y[d:] + 0.5 * h * h * u
        y[d:] = y[d:] + h * u

    def F(self, t, x, z, flow_scale=1.0):  # type: ignore[no-untyped-def]
        return -0.5 * np.asarray(z) * flow_scale


def test_law_24_per_axis() -> None:
    prm = ControllerParams(gains=BacksteppingGains(k1=5.0, k2=10.0))
    m = _FreeModel(3, b=4.0)
    c = BacksteppingController(prm, m.F, m.input_matrix)
    x, z = np.array([1e-3, 2e-4, -3e-4]), np.array([1e-3, 0.0, -2e-3])
    ref = RefSample(np.array([2e-3, 0.0, 0.0]), np.array([4e-3, 1e-4, 0.0]), np.array([0.0, 0.0, 1e-2]))
    cmd = c.command(0.0, Estimate(0.0, x, z, 0.0, np.zeros(3), True, False), ref)
    u_ref = backstepping_u(5.0, 10.0, x, z, m.F(0.0, x, z), ref.p, ref.v, ref.a)
    assert cmd.status == "ok" and np.allclose(cmd.u_m_per_s2, u_ref, rtol=1e-14, atol=0)
    assert np.allclose(cmd.gradient_T_per_m, u_ref / 4.0, rtol=1e-14)
    stale = c.command(0.0, Estimate(0.0, x, z, 1.0, np.zeros(3), False, False), ref)
    assert stale.status == "stale" and not stale.gradient_T_per_m.any()
    with pytest.raises(ModelInputError, match="non-finite estimate"):
        c.command(0.0, Estimate(0.0, np.array([math.nan, 0, 0]), z, 0.0, np.zeros(3), True, False), ref)


def test_law_midpoint_and_flow_compensation_use_the_model() -> None:
    prm = ControllerParams(sample_hold="midpoint", flow_compensation="estimate")
    m = _FreeModel(3)
    c = BacksteppingController(prm, m.F, m.input_matrix, hold_period_s=1e-3)
    x, z = np.zeros(3), np.array([1e-3, 0.0, 0.0])
    ref = RefSample(np.zeros(3), np.zeros(3), np.zeros(3))
    cmd = c.command(0.0, Estimate(0.0, x, z, 0.0, np.zeros(3), True, False, 2.0), ref)
    s, cc, h = 15.0, 51.0, 0.5e-3
    a = -s * z
    f = m.F(h, x + h * z + 0.5 * h * h * a, z + h * a, 2.0)
    assert np.allclose(cmd.u_m_per_s2, a - f, rtol=1e-14) and cc == 51.0
    with pytest.raises(ModelInputError, match="flow scale"):
        c.command(0.0, Estimate(0.0, x, z, 0.0, np.zeros(3), True, False, 0.0), ref)
