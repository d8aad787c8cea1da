"""Tests of the gradient-coil saturation + slew limiter."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vesselbot_ros.config import ConfigError, load_dataclass
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.scanner.actuator_limits import (
    CLINICAL_SLEW_RATE_T_PER_M_PER_S,
    COIL_OUT_SIZE,
    PAPER_PRINTED_SLEW_RATE_T_PER_M_PER_S,
    CoilLimiter,
    CoilLimits,
    coil_apply,
    coil_out_size,
    coil_params,
    new_coil_state,
)


def test_slew_presets() -> None:
    assert CoilLimits().slew_rate_T_per_m_per_s == CLINICAL_SLEW_RATE_T_PER_M_PER_S == 100.0
    assert CoilLimits(slew_rate="paper_printed").slew_rate_T_per_m_per_s == PAPER_PRINTED_SLEW_RATE_T_PER_M_PER_S == 0.1
    assert CoilLimits(slew_rate="custom", custom_slew_rate_T_per_m_per_s=7.0).slew_rate_T_per_m_per_s == 7.0


def test_saturation_keeps_direction_paper_formula() -> None:
    lim = CoilLimiter(CoilLimits(slew_rate="custom", custom_slew_rate_T_per_m_per_s=1e9))
    cmd = np.array([0.3, -0.4])  # |cmd| = 0.5 T/m
    out = lim.apply(0.001, cmd)
    k = 0.5 / 0.08  # paper: k = max(1, |U|/U_sat)
    assert out.k_scale == pytest.approx(k, rel=1e-12)
    np.testing.assert_allclose(out.applied, cmd / k, rtol=1e-12, atol=1e-12)
    assert out.saturated and not out.rejected


def test_per_axis_saturation() -> None:
    lim = CoilLimiter(CoilLimits(saturation_norm="per_axis", slew_rate="custom", custom_slew_rate_T_per_m_per_s=1e9))
    out = lim.apply(0.001, [0.16, 0.05])
    np.testing.assert_allclose(out.applied, [0.08, 0.05], rtol=1e-12, atol=1e-12)
    assert out.k_scale == pytest.approx(2.0)


def test_slew_from_zero_and_first_tick() -> None:
    lim = CoilLimiter(CoilLimits(slew_rate="paper_printed"))
    out0 = lim.apply(0.0, [0.08, 0.0])  # dt = 0 at t0: nothing can move
    np.testing.assert_array_equal(out0.applied, [0.0, 0.0])
    out1 = lim.apply(0.5, [0.08, 0.0])  # 0.1 T/m/s * 0.5 s = 0.05 T/m
    np.testing.assert_allclose(out1.applied, [0.05, 0.0], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(out1.slew_limited, [True, False])


def test_a_held_tick_is_an_output_so_the_next_command_slews_from_it() -> None:
    """The coil driver holds the output when a command is late (within the command timeout): that tick
    counts, so the next command may move S * dt from it, not S * 2 dt (a stall at the first tick of a run
    let the next command jump two ticks' worth of slew)."""
    lim = CoilLimiter(CoilLimits(slew_rate="custom", custom_slew_rate_T_per_m_per_s=2.0, command_timeout_s=0.02), -1e-3)
    out0 = lim.hold(0.0)  # tick 0 answered without a command
    np.testing.assert_array_equal(out0.applied, [0.0, 0.0])
    assert not out0.saturated and out0.k_scale == 1.0
    out1 = lim.apply(1e-3, [0.08, 0.0])
    np.testing.assert_allclose(out1.applied, [2e-3, 0.0], rtol=1e-12, atol=0)
    with pytest.raises(ModelInputError, match="went backwards"):
        lim.hold(0.0)


def test_a_rejected_command_never_freezes_the_coil_it_ramps_to_zero_at_the_slew_limit() -> None:
    """Default limits (issue 38): from the first non-finite command on, the output moves towards zero by S dt per
    tick on the larger axis (the watchdog's ramp), stays at zero while the commands stay bad, and follows the next
    valid command within the slew limit; ``reject`` (not a command: a wrong frame) is the same."""
    lim = CoilLimiter(CoilLimits(slew_rate="custom", custom_slew_rate_T_per_m_per_s=5.0), 0.0)
    for k in range(1, 21):
        lim.apply(k * 1e-3, [0.036, -0.018])  # 5 T/m/s * 1 ms = 5 mT/m per tick: there by tick 8
    np.testing.assert_allclose(lim.applied, [0.036, -0.018], rtol=1e-12)
    applied = []
    for k in range(21, 41):
        out = lim.apply(k * 1e-3, [math.nan, 0.0] if k % 2 else [0.0, math.inf])
        assert out.rejected and not out.saturated and out.k_scale == 1.0
        applied.append(out.applied)
    a = np.array(applied)
    steps = np.abs(np.diff(np.vstack([[0.036, -0.018], a]), axis=0))
    assert np.all(steps <= 5e-3 * (1 + 1e-9))
    np.testing.assert_allclose(a[0], [0.031, -0.0155], rtol=1e-9)  # the step scaled uniformly: same direction
    # |G| / S = 36 mT/m / 5 T/m/s = 7.2 ms: zero from the 8th rejected tick on, exactly
    assert np.all(a[7:] == 0.0) and np.all(np.abs(a[6]) > 0.0)
    out = lim.apply(41e-3, [0.02, 0.0])
    assert not out.rejected
    np.testing.assert_allclose(out.applied, [0.005, 0.0], rtol=1e-9)
    out = lim.reject(42e-3)
    assert out.rejected
    np.testing.assert_allclose(out.applied, [0.0, 0.0], atol=1e-18)


def test_on_reject_hold_is_refused_in_one_line() -> None:
    with pytest.raises(ConfigError, match=r"on_reject: 'hold' is refused: it froze the coil on the last good gradient"):
        CoilLimits(on_reject="hold")  # type: ignore[arg-type]
    assert CoilLimits().on_reject == "ramp_to_zero"


def test_watchdog_ramps_to_zero_after_timeout() -> None:
    lim = CoilLimiter(CoilLimits(command_timeout_s=0.05, slew_rate="custom", custom_slew_rate_T_per_m_per_s=1.0))
    lim.apply(0.1, [0.08, 0.0])
    assert lim.watchdog(0.12) is None  # within the timeout: nothing
    # held until 0.1 + 0.05 = 0.15 s; the ramp runs from there: 1 T/m/s * (0.16 - 0.15) s
    out = lim.watchdog(0.16)
    assert out is not None
    np.testing.assert_allclose(out.applied, [0.08 - 0.01, 0.0], rtol=1e-9, atol=1e-12)
    out = lim.watchdog(0.17)  # one more 10 ms step
    np.testing.assert_allclose(out.applied, [0.08 - 0.02, 0.0], rtol=1e-9, atol=1e-12)
    out = lim.watchdog(1.0)
    np.testing.assert_array_equal(out.applied, [0.0, 0.0])


def test_watchdog_polled_while_commands_flow_never_blocks_a_later_command() -> None:
    # a real-time driver polls the watchdog every tick; commands arrive stamped slightly in the past
    lim = CoilLimiter(CoilLimits(command_timeout_s=0.05))
    lim.apply(0.010, [0.01, 0.0])
    for t in (0.011, 0.012, 0.013):
        assert lim.watchdog(t) is None
    out = lim.apply(0.011, [0.02, 0.0])  # the limiter's clock was not advanced by the polls
    np.testing.assert_allclose(out.applied, [0.02, 0.0], rtol=1e-12, atol=1e-12)


def test_time_going_backwards_raises() -> None:
    lim = CoilLimiter(CoilLimits())
    lim.apply(0.01, [0.0, 0.0])
    with pytest.raises(ModelInputError, match="backwards"):
        lim.apply(0.005, [0.0, 0.0])
    with pytest.raises(ModelInputError, match=r"shape \(2,\)"):
        lim.apply(0.02, [0.0, 0.0, 0.0])


def test_config_errors_name_field_and_value() -> None:
    with pytest.raises(ConfigError, match=r"coil.saturation_T_per_m must be > 0, got -0.04"):
        load_dataclass(CoilLimits, {"saturation_T_per_m": -0.04}, "coil")
    with pytest.raises(ConfigError, match=r"coil.slew_rate must be one of"):
        load_dataclass(CoilLimits, {"slew_rate": "fast"}, "coil")


commands = st.lists(
    st.tuples(
        st.floats(-1.0, 1.0, allow_nan=False),
        st.floats(-1.0, 1.0, allow_nan=False),
        st.floats(1e-5, 5e-3),
        st.booleans(),
    ),
    min_size=1,
    max_size=60,
)


@settings(max_examples=150, deadline=None)
@given(commands, st.sampled_from(["euclidean", "per_axis"]), st.floats(0.1, 200.0))
def test_property_limits_never_exceeded(seq, norm, slew) -> None:  # type: ignore[no-untyped-def]
    limits = CoilLimits(saturation_norm=norm, slew_rate="custom", custom_slew_rate_T_per_m_per_s=slew)
    lim = CoilLimiter(limits)
    t = 0.0
    prev = np.zeros(2)
    for gx, gz, dt, poison in seq:
        t += dt
        cmd = [math.nan, gz] if poison else [gx, gz]
        out = lim.apply(t, cmd)
        a = out.applied
        assert np.all(np.isfinite(a))
        if norm == "euclidean":
            assert math.hypot(a[0], a[1]) <= 0.08 * (1 + 1e-12)
        else:
            assert np.all(np.abs(a) <= 0.08 * (1 + 1e-12))
        assert np.all(np.abs(a - prev) <= slew * dt * (1 + 1e-9) + 1e-15)
        prev = a


# ---- three axes --------------------------------------------------------------------------------------------------
def _coil_runs(limits: CoilLimits, commands: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The one coil on (x, z) and on (x, y, z) over the same command sequence: their outputs."""
    prm = coil_params(limits)
    s2, s3 = new_coil_state(2, 0.0), new_coil_state(3, 0.0)
    o2, o3 = np.zeros(COIL_OUT_SIZE), np.zeros(coil_out_size(3))
    out2, out3 = [], []
    for i, (gx, gy, gz) in enumerate(commands):
        coil_apply(prm, s2, (i + 1) * dt, np.array([gx, gz]), o2)
        coil_apply(prm, s3, (i + 1) * dt, np.array([gx, gy, gz]), o3)
        out2.append(o2.copy())
        out3.append(o3.copy())
    return np.array(out2), np.array(out3)


@pytest.mark.parametrize("norm", ["euclidean", "per_axis"])
@pytest.mark.parametrize("reject", ["ramp_to_zero"])
def test_the_3d_coil_in_the_plane_is_the_planar_coil(norm: str, reject: str) -> None:
    """Every y command 0: the three-axis coil applies the planar coil's doubles on x and z, 0 on y, with the same
    saturation factor and flags (saturating, slewing and non-finite commands included)."""
    rng = np.random.default_rng(3)
    cmd = rng.normal(0.0, 0.08, (400, 3))
    cmd[:, 1] = 0.0
    cmd[rng.integers(0, 400, 20), 2] = np.nan
    cmd[rng.integers(0, 400, 10), 0] = np.inf
    limits = CoilLimits(saturation_norm=norm, on_reject=reject, slew_rate="custom", custom_slew_rate_T_per_m_per_s=20.0)
    o2, o3 = _coil_runs(limits, cmd, 1e-3)
    np.testing.assert_array_equal(o3[:, [0, 2]], o2[:, [0, 1]])
    assert np.all(o3[:, 1] == 0.0) and np.all(o3[:, 6] == 0.0)
    np.testing.assert_array_equal(o3[:, [3, 4, 5, 7, 8]], o2[:, [2, 3, 4, 5, 6]])


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(["euclidean", "per_axis"]), st.floats(1.0, 200.0))
def test_the_3d_coil_keeps_saturation_and_slew_on_every_axis(seed: int, norm: str, slew: float) -> None:
    """Any finite command sequence: the applied gradient stays in the saturation set (norm or box) and no axis moves
    more than S dt per call."""
    rng = np.random.default_rng(seed)
    cmd = rng.normal(0.0, 0.2, (200, 3))
    limits = CoilLimits(saturation_norm=norm, slew_rate="custom", custom_slew_rate_T_per_m_per_s=slew)
    _o2, o3 = _coil_runs(limits, cmd, 1e-3)
    applied = o3[:, :3]
    sat = limits.saturation_T_per_m
    if norm == "euclidean":
        assert np.all(np.linalg.norm(applied, axis=1) <= sat * (1 + 1e-12))
    else:
        assert np.all(np.abs(applied) <= sat * (1 + 1e-12))
    steps = np.abs(np.diff(np.vstack([np.zeros(3), applied]), axis=0))
    assert np.all(steps <= slew * 1e-3 * (1 + 1e-12))


# ---- three axes ---------------------------------------------------------------------------------------
def test_the_coil_on_three_axes_in_the_plane_is_the_coil_on_two() -> None:
    lim = CoilLimits(slew_rate="clinical")
    c2, c3 = CoilLimiter(lim, -1e-3), CoilLimiter(lim, -1e-3, dims=3)
    rng = np.random.default_rng(0)
    for k in range(200):
        g = rng.normal(0.0, 0.1, 2)
        o2 = c2.apply(k * 1e-3, g)
        o3 = c3.apply(k * 1e-3, np.array([g[0], 0.0, g[1]]))
        assert o3.applied[0] == o2.applied[0] and o3.applied[2] == o2.applied[1] and o3.applied[1] == 0.0
        assert o3.k_scale == o2.k_scale and o3.saturated == o2.saturated
        assert list(o3.slew_limited[[0, 2]]) == list(o2.slew_limited)


def test_the_coil_on_three_axes_saturates_the_norm_over_them_and_ramps_down() -> None:
    lim = CoilLimits(slew_rate="custom", custom_slew_rate_T_per_m_per_s=1e6, command_timeout_s=0.01)
    c = CoilLimiter(lim, 0.0, dims=3)
    out = c.apply(1e-3, np.array([0.1, 0.1, 0.1]))
    assert np.linalg.norm(out.applied) == pytest.approx(lim.saturation_T_per_m, rel=1e-12)
    assert out.saturated and out.k_scale == pytest.approx(np.sqrt(0.03) / lim.saturation_T_per_m)
    assert c.watchdog(5e-3) is None
    ramp = c.watchdog(0.5)
    assert ramp is not None and not ramp.applied.any()
    rej = c.apply(0.6, np.array([np.nan, 0.0, 0.0]))
    assert rej.rejected
    with pytest.raises(ModelInputError, match=r"\(3,\)"):
        c.apply(0.7, np.zeros(2))


def test_a_coil_has_two_or_three_axes_and_its_command_goes_in_place() -> None:
    """One coil class serves the plane and space; a command may sit in the output's own slots (no scratch)."""
    with pytest.raises(ModelInputError, match="2 or 3 axes"):
        CoilLimiter(CoilLimits(), 0.0, dims=4)
    prm = coil_params(CoilLimits(slew_rate="custom", custom_slew_rate_T_per_m_per_s=20.0))
    rng = np.random.default_rng(5)
    for d in (2, 3):
        sa, sb = new_coil_state(d, 0.0), new_coil_state(d, 0.0)
        oa, ob = np.zeros(coil_out_size(d)), np.zeros(coil_out_size(d))
        for i in range(100):
            g = rng.normal(0.0, 0.1, d)
            if i % 17 == 0:
                g[0] = np.nan
            coil_apply(prm, sa, (i + 1) * 1e-3, g, oa)
            ob[:d] = g
            coil_apply(prm, sb, (i + 1) * 1e-3, ob[:d], ob)
            np.testing.assert_array_equal(oa, ob)
            np.testing.assert_array_equal(sa, sb)
