"""A multiplexed scanner in the pure loop: what the bag-level integration test will check on the graph."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.scanner.sequence import PHASE_CODES, SequenceParams, phase_at
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario, scenario_from_mapping, shipped_scenarios

SEQ = {"mode": "multiplexed", "tracking_window_s": 0.02, "dead_time_s": 0.002, "propulsion_window_s": 0.03,
       "latency_s": 0.02}


def _multiplexed(**over: object) -> dict:
    m = copy.deepcopy(load_scenario(shipped_scenarios()["sound_small_artery_ekf"]).to_mapping())
    m["sequence"] = dict(SEQ, **over)
    m["controller"]["gains"].update(k1=5.0, k2=10.0)
    m["controller"]["duty_compensation"] = "sequence"
    m["sim"]["duration_s"] = 0.6
    return m


def test_multiplexed_loop_respects_the_sequence() -> None:
    sc = scenario_from_mapping(_multiplexed())
    ts = run_closed_loop(sc, 0).timeseries
    t, phase, g = ts["t_s"], ts["sequence_phase"], ts["g_applied"]
    seq = sc.sequence
    assert all(phase[k] == PHASE_CODES[phase_at(seq, float(t[k]))] for k in range(t.size))
    # no propulsion gradient outside propulsion windows: the hold [t_k, t_k + dt] included
    dt = sc.sim.dt_control_s
    outside = np.array([phase_at(seq, float(tk)) != "propulsion" or phase_at(seq, float(tk) + dt - 1e-9) != "propulsion"
                        for tk in t])
    assert np.all(g[outside] == 0.0)
    assert np.any(g[~outside] != 0.0)
    # limits at every tick
    assert np.all(np.hypot(g[:, 0], g[:, 1]) <= sc.coil.saturation_T_per_m * (1 + 1e-12))
    step = np.abs(np.diff(np.vstack([np.zeros((1, 2)), g]), axis=0))
    assert np.all(step <= sc.coil.slew_rate_T_per_m_per_s * dt * (1 + 1e-9))
    # every frame acquired in a tracking window (at its middle), delivered at window end + latency
    delivered = np.isfinite(ts["meas_t_acq_s"])
    assert delivered.sum() == pytest.approx(0.6 / seq.period_s, abs=1.5)
    for k in np.flatnonzero(delivered):
        t_acq = float(ts["meas_t_acq_s"][k])
        assert phase_at(seq, t_acq) == "tracking"
        start = t_acq - 0.5 * seq.tracking_window_s
        assert float(t[k]) == pytest.approx(start + seq.tracking_window_s + seq.latency_s, abs=1e-9)


def test_continuous_sequence_is_todays_loop() -> None:
    """The paper preset (continuous) gives the same bits as a scenario without a sequence section."""
    m = copy.deepcopy(load_scenario(shipped_scenarios()["sound_small_artery"]).to_mapping())
    m["sim"]["duration_s"] = 0.3
    a = run_closed_loop(scenario_from_mapping(m), 0)
    m["sequence"] = {"mode": "continuous"}
    b = run_closed_loop(scenario_from_mapping(m), 0)
    for key, col in a.timeseries.items():
        np.testing.assert_array_equal(col, b.timeseries[key], err_msg=key)


def test_multiplexed_needs_the_sequence_latency() -> None:
    m = _multiplexed()
    m["imager"]["latency_s"] = 0.01
    with pytest.raises(ConfigError, match="imager.latency_s must be 0 with sequence.mode 'multiplexed'"):
        scenario_from_mapping(m)
    with pytest.raises(ConfigError, match="sequence.tracking_window_s must be >= one control tick"):
        scenario_from_mapping(_multiplexed(tracking_window_s=0.0005))
    assert SequenceParams().mode == "continuous"


@pytest.mark.parametrize(("key", "value", "match"), [
    ("tracking_window_s", 0.021, "tracking_window_s must be an even number of control ticks"),
    ("dead_time_s", 0.0015, "dead_time_s must be whole control ticks"),
    ("propulsion_window_s", 0.0305, "propulsion_window_s must be whole control ticks"),
    ("start_s", 0.0001, "start_s must be whole control ticks"),
])
def test_windows_off_the_tick_grid_are_refused(key, value, match):
    """A frame stamp off the tick grid would be refused by the graph's observer while the runner used it."""
    with pytest.raises(ConfigError, match=f"sequence.{match}"):
        scenario_from_mapping(_multiplexed(**{key: value}))
    scenario_from_mapping(_multiplexed(tracking_window_s=0.022, dead_time_s=0.003, propulsion_window_s=0.031))


def test_sequenced_coil_hold_keeps_the_output_and_the_slew_clock() -> None:
    """The coil driver's watchdog holds a late tick: the output stays, the next command slews from the held tick."""
    from vesselbot_ros.scanner.stages import SequencedCoil
    from vesselbot_ros.sim.closed_loop import build_stages

    m = _multiplexed()
    m["coil"].update(slew_rate="custom", custom_slew_rate_T_per_m_per_s=2.0)  # 2 mT/m per tick: never saturates here
    sc = scenario_from_mapping(m)
    coil = build_stages(sc).coil
    assert isinstance(coil, SequencedCoil)
    seq, dt = sc.sequence, sc.sim.dt_control_s
    # first propulsion tick whose hold [t, t + dt] stays in the window, and two more after it
    k0 = next(k for k in range(1000) if phase_at(seq, k * dt) == "propulsion" and phase_at(seq, (k + 3) * dt) == "propulsion")
    big = np.array([1.0, 1.0])  # far beyond saturation: every tick moves by the full slew step
    out1 = coil.apply(k0 * dt, big)
    held = coil.hold((k0 + 1) * dt)
    np.testing.assert_array_equal(held.applied, out1.applied)
    assert not held.saturated and not held.rejected
    out3 = coil.apply((k0 + 2) * dt, big)
    step = sc.coil.slew_rate_T_per_m_per_s * dt
    # one tick of slew from the held tick, not two from the last command
    assert np.all(np.abs(out3.applied - held.applied) <= step * (1 + 1e-9))
    assert np.any(np.abs(out3.applied - held.applied) > 0.5 * step)
    with pytest.raises(Exception, match="back"):
        coil.hold(k0 * dt)  # time never goes back


def test_the_sequenced_coil_ramps_a_rejected_command_to_zero_within_the_window() -> None:
    """Inside a propulsion window a non-finite command (or ``reject``: not a command) moves the output towards zero
    by at most S dt per tick and flags it; it is never held (issue 38)."""
    from vesselbot_ros.scanner.stages import SequencedCoil
    from vesselbot_ros.sim.closed_loop import build_stages

    m = _multiplexed()
    m["coil"].update(slew_rate="custom", custom_slew_rate_T_per_m_per_s=2.0)
    sc = scenario_from_mapping(m)
    coil = build_stages(sc).coil
    assert isinstance(coil, SequencedCoil)
    seq, dt = sc.sequence, sc.sim.dt_control_s
    k0 = next(k for k in range(1000) if all(phase_at(seq, (k + i) * dt) == "propulsion" for i in range(6)))
    out = coil.apply(k0 * dt, np.array([1.0, 1.0]))
    out = coil.apply((k0 + 1) * dt, np.array([1.0, 1.0]))
    g1 = out.applied
    step = sc.coil.slew_rate_T_per_m_per_s * dt
    assert np.all(np.abs(g1) > 1.5 * step)
    nan = coil.apply((k0 + 2) * dt, np.array([np.nan, 0.0]))
    assert nan.rejected and np.all(np.abs(nan.applied) < np.abs(g1))
    assert np.all(np.abs(nan.applied - g1) <= step * (1 + 1e-9)) and np.any(np.abs(nan.applied - g1) > 0.5 * step)
    rej = coil.reject((k0 + 3) * dt)
    assert rej.rejected and np.all(np.abs(rej.applied) < np.abs(nan.applied))
    assert np.all(np.abs(rej.applied - nan.applied) <= step * (1 + 1e-9))


# ---- three axes (3-D vessel trees) --------------------------------------------------------------------
SEQ3D = ["sequence.mode=multiplexed", "sequence.tracking_window_s=0.002", "sequence.dead_time_s=0.001",
         "sequence.propulsion_window_s=0.004", "sequence.latency_s=0.001", "imager.frame_rate_Hz=500",
         "controller.duty_compensation=sequence", "sim.duration_s=0.1"]


def test_the_3d_sequence_gates_all_three_axes_and_images_once_per_window() -> None:
    from vesselbot_ros.scanner.sequence import phase_codes, sequence_vector
    from vesselbot_ros.scanner.stages import SequencedCoil, SequencedImager
    from vesselbot_ros.sim.closed_loop import build_stages, run_closed_loop
    from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios

    sc = load_scenario(shipped_scenarios()["paper_iiic_network_upper_3d"], sets=SEQ3D)
    st = build_stages(sc)
    assert type(st.imager) is SequencedImager and type(st.coil) is SequencedCoil and st.imager.dims == st.coil.dims == 3
    a, b = run_closed_loop(sc, 3), run_closed_loop(sc, 3, path="per_tick")
    assert a.path == "compiled"
    for k, v in b.timeseries.items():
        assert np.array_equal(a.timeseries[k], v, equal_nan=v.dtype.kind == "f"), k
    ts = a.timeseries
    phase = phase_codes(sequence_vector(sc.sequence), ts["t_s"])
    assert ts["g_applied"].shape == (100, 3)
    assert not ts["g_applied"][phase != 3].any()  # no gradient outside the propulsion windows, on any axis
    assert np.abs(ts["g_applied"][phase == 3]).max() > 0.0
    got = ~np.isnan(ts["meas_t_acq_s"])
    assert 0 < got.sum() <= int(np.ceil(0.1 / 0.008)) and np.all(np.diff(ts["meas_t_acq_s"][got]) > 0.0)
    assert np.all(np.linalg.norm(ts["g_applied"], axis=1) <= sc.coil.saturation_T_per_m * (1 + 1e-12))
