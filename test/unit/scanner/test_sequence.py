"""MRI sequence: phases partition time, the propulsion limit keeps tracking windows free of propulsion."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vesselbot_ros.config import ConfigError
from vesselbot_ros.scanner.actuator_limits import CoilLimiter, CoilLimits
from vesselbot_ros.scanner.hardware import PRESETS, dbdt_slew_limit, iec_normal_mode_dbdt
from vesselbot_ros.scanner.sequence import (
    SequenceParams,
    duty_cycle,
    phase_at,
    propulsion_limit,
    propulsion_target,
    tracking_window_of,
)

SEQ = SequenceParams(mode="multiplexed", tracking_window_s=0.02, dead_time_s=0.002, propulsion_window_s=0.03,
                     latency_s=0.02)


def test_phases_of_one_period() -> None:
    assert SEQ.period_s == pytest.approx(0.054, abs=1e-15)
    expect = {0.0: "tracking", 0.0199: "tracking", 0.0205: "dead", 0.022: "propulsion", 0.0519: "propulsion",
              0.0525: "dead", 0.054: "tracking", 0.054 * 7 + 0.03: "propulsion"}
    for t, ph in expect.items():
        assert phase_at(SEQ, t) == ph, t
    assert phase_at(SequenceParams(), 0.123) == "continuous"
    assert duty_cycle(SEQ) == pytest.approx(0.03 / 0.054, rel=1e-12)
    assert duty_cycle(SequenceParams()) == 1.0


def test_tracking_window_stamps_and_delivery() -> None:
    w = tracking_window_of(SEQ, 0.054 * 3 + 0.005)
    assert w is not None and w.index == 3
    assert w.start_s == pytest.approx(0.162, abs=1e-12) and w.end_s == pytest.approx(0.182, abs=1e-12)
    assert w.t_acq_s == pytest.approx(0.172, abs=1e-12) and w.t_deliver_s == pytest.approx(0.202, abs=1e-12)
    assert tracking_window_of(SEQ, 0.03) is None


def test_bad_timing_is_refused() -> None:
    with pytest.raises(ConfigError, match="tracking_window_s must be > 0"):
        SequenceParams(tracking_window_s=0.0)
    with pytest.raises(ConfigError, match="mode must be one of"):
        SequenceParams(mode="interleaved")  # type: ignore[arg-type]


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(["random", "constant", "alternating"]),
       st.sampled_from([0.0005, 0.001]), st.sampled_from([20.0, 100.0, 200.0]))
def test_coil_never_propels_outside_propulsion_windows(seed: int, kind: str, dt: float, slew: float) -> None:
    """Any command sequence through propulsion_target + the coil limiter: zero outside propulsion windows."""
    rng = np.random.default_rng(seed)
    if kind == "random":
        cmds = rng.uniform(-0.2, 0.2, size=(300, 2))
    elif kind == "constant":
        cmds = np.tile(rng.uniform(-0.2, 0.2, size=2), (300, 1))
    else:
        cmds = np.outer((-1.0) ** np.arange(300), rng.uniform(-0.2, 0.2, size=2))
    limits = CoilLimits(saturation_T_per_m=0.08, slew_rate="custom", custom_slew_rate_T_per_m_per_s=slew)
    coil = CoilLimiter(limits, -dt)
    prev = (0.0, 0.0)
    for k, c in enumerate(cmds):
        t = k * dt
        lim = propulsion_limit(SEQ, t, dt, slew, 0.08)
        target = propulsion_target(prev, (float(c[0]), float(c[1])), lim, slew * dt)
        out = coil.apply(t, np.array(target))
        g = out.applied
        assert math.hypot(g[0], g[1]) <= lim + 1e-15, (t, g, lim)
        for tau in (t, t + 0.5 * dt, t + dt - 1e-9):  # the whole hold
            if phase_at(SEQ, tau) != "propulsion":
                assert g[0] == 0.0 and g[1] == 0.0, (t, tau, g)
        prev = (float(g[0]), float(g[1]))


def test_continuous_mode_is_the_saturation() -> None:
    assert propulsion_limit(SequenceParams(), 0.3, 1e-3, 100.0, 0.08) == 0.08
    assert propulsion_target((0.0, 0.0), (0.05, 0.0), 0.08, 0.1) == (0.05, 0.0)


def test_presets_and_dbdt() -> None:
    assert set(PRESETS) == {"paper", "clinical_3t", "clinical_3t_mfde", "propulsion_insert"}
    mfde = PRESETS["clinical_3t_mfde"].sequence  # Zhai 2026: TR 30 ms, at most 77 % driving, on whole ticks
    assert mfde.period_s == pytest.approx(0.030) and 0.70 < duty_cycle(mfde) <= 0.77
    assert PRESETS["paper"].sequence.mode == "continuous" and PRESETS["paper"].saturation_T_per_m == 0.08
    assert PRESETS["propulsion_insert"].saturation_T_per_m > 5 * PRESETS["clinical_3t"].saturation_T_per_m
    assert iec_normal_mode_dbdt(0.36) == pytest.approx(32.0, rel=1e-12)  # 0.8 * 20 * (1 + 1)
    assert dbdt_slew_limit(32.0, 0.2) == pytest.approx(160.0, rel=1e-12)
    with pytest.raises(ConfigError, match="radius_m"):
        dbdt_slew_limit(32.0, 0.0)


@given(st.floats(-0.01, 1.0))
@settings(max_examples=300, deadline=None)
def test_window_at_agrees_with_phase_at_and_contains_the_time(t: float) -> None:
    from vesselbot_ros.scanner.sequence import window_at

    w = window_at(SEQ, t)
    assert w.phase == phase_at(SEQ, t)
    assert w.start_s - 1e-9 <= t < w.end_s - 1e-9 or (w.start_s == -math.inf and t < w.end_s)
    if w.phase == "tracking":
        tw = tracking_window_of(SEQ, t)
        assert (tw.start_s, tw.end_s, tw.index) == pytest.approx((w.start_s, w.end_s, w.index), abs=1e-15)
    # the window's end is where the next window starts
    nxt = window_at(SEQ, w.end_s)
    assert nxt.start_s == pytest.approx(w.end_s, abs=1e-12) and nxt.phase != w.phase


def test_window_at_by_hand() -> None:
    from vesselbot_ros.scanner.sequence import window_at

    assert tuple(window_at(SEQ, 0.03)) == ("propulsion", 0, 0.022, pytest.approx(0.052))
    assert tuple(window_at(SEQ, 0.0525)) == ("dead", 0, pytest.approx(0.052), pytest.approx(0.054))
    assert window_at(SEQ, 0.054)[:2] == ("tracking", 1)
    assert tuple(window_at(SequenceParams(), 5.0)) == ("continuous", -1, 0.0, math.inf)
    late = SequenceParams(mode="multiplexed", start_s=0.1)
    assert tuple(window_at(late, 0.05)) == ("dead", -1, -math.inf, 0.1)
