"""The ``mr_images`` imager: the loop's measurements from synthesised MR frames and the default tracker."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.imaging.imager_stage import DipoleFitTracker, MrImager, MrImagerParams, TrackerParams
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.scanner.sequence import SequenceParams
from vesselbot_ros.sim.closed_loop import build_stages, run_closed_loop
from vesselbot_ros.sim.kinds import find
from vesselbot_ros.sim.scenario import load_scenario

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"


def test_the_kind_is_registered_and_names_its_bad_values():
    assert find("imager", "mr_images").params is MrImagerParams
    with pytest.raises(ConfigError, match="imager.preset"):
        MrImagerParams(preset="gre_7t")
    with pytest.raises(ConfigError, match="imager.frame_rate_Hz"):
        MrImagerParams(frame_rate_Hz=0.0)
    with pytest.raises(ConfigError, match="fov_centre_m"):
        MrImagerParams(fov_centre_m=(0.0, float("nan"), 0.0))


def test_continuous_frames_track_the_bead_and_a_frame_without_it_is_rejected_not_nan():
    imager = MrImager(MrImagerParams(frame_rate_Hz=100.0, latency_s=0.02), PhysicsParams(), SequenceParams(),
                      np.random.default_rng(3), dims=2)
    tracker = DipoleFitTracker(TrackerParams(), imager.imaging, PhysicsParams().robot, dims=2)
    p = np.array([1.0e-3, 0.5e-3])
    got = [imager.frame(k * 1e-3, p) for k in range(61)]
    delivered = [f for f in got if f is not None]
    assert imager.frames == 7 and len(delivered) == 5  # acquired at 0, 10, ..., 60 ms; delivered 20 ms later
    assert [f.index for f in delivered] == [0, 1, 2, 3, 4] and imager.superseded == 0
    frames = [tracker.track(k * 1e-3, f) for k, f in enumerate(got) if f is not None]
    assert all(m is not None for m in frames)
    assert [round(m.t_acq_s, 6) for m in frames] == [0.0, 0.01, 0.02, 0.03, 0.04]
    err = np.array([m.p - p for m in frames])
    assert np.all(np.isfinite(err)) and np.abs(err).max() < 50e-6  # MS-SET's bound is a few micrometres
    far = MrImager(MrImagerParams(), PhysicsParams(), SequenceParams(), np.random.default_rng(0), dims=2)
    frame = far.frame(0.0, np.array([0.5, 0.0]))  # 0.5 m from the field of view: nothing excited in it
    assert frame is not None and far.frames == 1
    far_tracker = DipoleFitTracker(TrackerParams(), far.imaging, PhysicsParams().robot, dims=2)
    assert far_tracker.track(0.0, frame) is None and sum(far_tracker.rejected.values()) == 1


def test_the_tracker_kind_is_registered_and_needs_frames():
    assert find("tracker", "dipole_fit").params is TrackerParams
    with pytest.raises(ConfigError, match="tracker.min_chi2"):
        TrackerParams(min_chi2=0.0)
    sc = load_scenario("config/plans/clinical_3t.yaml", sets=["sim.duration_s=0.1"])
    assert build_stages(sc).tracker is None  # the mri imager delivers positions: nothing to track


def test_the_clinical_plan_flies_on_tracked_ms_set_frames_in_its_tracking_windows():
    sc = load_scenario("config/plans/clinical_3t.yaml",
                       sets=["imager.kind=mr_images", "imager.fov_centre_m=[4.0e-3, 0.0, 0.0]", "sim.duration_s=0.4"])
    r = run_closed_loop(sc, 0)
    assert r.path == "per_tick" and r.metrics["status"] == "ok"
    ts = r.timeseries
    got = np.isfinite(ts["meas_p"][:, 0])
    period = sc.sequence.period_s
    assert got.sum() >= int(0.4 / period) - 1  # one frame per sequence period
    k = np.flatnonzero(got)
    truth = ts["p_true"][np.searchsorted(ts["t_s"], ts["meas_t_acq_s"][k])]
    assert np.abs(ts["meas_p"][k] - truth).max() < 1e-3  # the tracked bead, moving through its window


def test_frames_the_tracker_drops_are_counted_in_the_runs_metrics_and_its_headline():
    from vesselbot_ros.sim.metrics import headline

    # the field of view 0.2 m away from the vessel: every frame holds no bead
    sc = load_scenario("config/plans/clinical_3t.yaml",
                       sets=["imager.kind=mr_images", "imager.fov_centre_m=[0.2, 0.0, 0.0]", "sim.duration_s=0.2"])
    r = run_closed_loop(sc, 0)
    m = r.metrics
    assert m["imager_frames"] >= 3 and m["imager_frames_rejected"] == m["imager_frames"]
    assert not np.isfinite(r.timeseries["meas_p"][:, 0]).any()
    assert f"frames rejected {m['imager_frames']} of {m['imager_frames']} (no_bead" in headline(m)


def test_a_users_tracker_runs_by_module_and_class_with_its_own_validated_parameters(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLES))
    sets = ["imager.kind=mr_images", "imager.fov_centre_m=[4.0e-3, 0.0, 0.0]", "sim.duration_s=0.4",
            "tracker.kind=plugin_tracker:CentroidTracker"]
    sc = load_scenario("config/plans/clinical_3t.yaml", sets=sets)
    assert type(sc.tracker).__name__ == "CentroidParams" and sc.tracker.threshold_sigma == 5.0
    r = run_closed_loop(sc, 0)
    ts = r.timeseries
    k = np.flatnonzero(np.isfinite(ts["meas_p"][:, 0]))
    assert len(k) >= 5 and r.metrics["imager_frames"] == len(k)  # every frame tracked, none rejected
    truth = ts["p_true"][np.searchsorted(ts["t_s"], ts["meas_t_acq_s"][k])]
    assert np.abs(ts["meas_p"][k] - truth).max() < 0.5e-3  # a centroid, not a fit: within half a millimetre
    with pytest.raises(ConfigError, match="tracker.threshold_sigma"):
        load_scenario("config/plans/clinical_3t.yaml", sets=[*sets, "tracker.threshold_sigma=0"])
    with pytest.raises(ConfigError, match="tracker.kind: unknown tracker kind 'hough'"):
        load_scenario("config/plans/clinical_3t.yaml", sets=[*sets[:-1], "tracker.kind=hough"])


@pytest.mark.parametrize(("sets", "needle"), [
    (["imager.preset=gre_3t"], "imager.preset 'gre_3t' takes 0.768 s per frame (slice, 128 x 0.006 s TR): longer than "
                               "sequence.tracking_window_s (0.02 s)"),
    (["sequence.mode=continuous", "imager.preset=gre_1p5t", "imager.frame_rate_Hz=2"],
     "imager.preset 'gre_1p5t' takes 1.024 s per frame (slice, 128 x 0.008 s TR): longer than the frame period "
     "1 / imager.frame_rate_Hz (0.5 s)"),
])
def test_an_acquisition_that_does_not_fit_its_time_is_one_line_naming_the_keys(sets, needle):
    with pytest.raises(ConfigError) as exc:
        load_scenario("config/plans/clinical_3t.yaml", sets=["imager.kind=mr_images", *sets])
    assert needle in str(exc.value) and "\n" not in str(exc.value)


def test_a_runs_bag_estimate_counts_its_mr_frames():
    from vesselbot_ros.sim.scenario import EMPTY_FRAME_BAG_BYTES, estimate_resources

    plain = load_scenario("config/plans/clinical_3t.yaml")
    frames = load_scenario("config/plans/clinical_3t.yaml", sets=["imager.kind=mr_images"])
    extra = estimate_resources(frames).bag_bytes - estimate_resources(plain).bag_bytes
    n_frames = frames.sim.duration_s / frames.sequence.period_s
    # an empty frame per tick, and each frame's 3 x 256 complex samples (16 bytes) and magnitudes (4)
    assert extra >= frames.sim.n_ticks * EMPTY_FRAME_BAG_BYTES + int(n_frames) * 20 * 3 * 256
