"""The imager (vesselbot_ros.scanner.imager_model) on three axes: the plane's timing, a noise per axis, outliers in
space; one class for both (the axis count is the imager's dims)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.scanner.imager_model import Dropout, ImagerModel, ImagerParams, OutlierBurst, VariateBuffer


def _frames(imager, n: int = 200, dt: float = 1e-3, p=(1e-3, 2e-3, -1e-3)):  # type: ignore[no-untyped-def]
    out = []
    for k in range(n):
        out.append(imager.frame(k * dt, np.array(p)))
    return out


def test_timing_is_the_planar_imagers() -> None:
    prm = ImagerParams(noise_sigma_m=0.0, frame_rate_Hz=50.0, latency_s=0.013)
    f3 = _frames(ImagerModel(prm, np.random.default_rng(0), dims=3), 300)
    f2 = _frames(ImagerModel(prm, np.random.default_rng(0)), 300, p=(1e-3, -1e-3))
    assert [m is None for m in f3] == [m is None for m in f2]
    assert [m.t_acq_s for m in f3 if m] == [m.t_acq_s for m in f2 if m]
    assert all(np.array_equal(m.p, [1e-3, 2e-3, -1e-3]) for m in f3 if m)


def test_noise_per_axis_and_the_draw_order() -> None:
    prm = ImagerParams(noise_sigma_m=1e-4, frame_rate_Hz=1000.0)
    ms = [m for m in _frames(ImagerModel(prm, np.random.default_rng(3), dims=3), 4000) if m]
    err = np.array([m.p for m in ms]) - np.array([1e-3, 2e-3, -1e-3])
    assert np.allclose(err.std(axis=0), 1e-4, rtol=0.05) and np.allclose(err.mean(axis=0), 0.0, atol=1e-5)
    rng = np.random.default_rng(3)  # three normals, then three uniforms, per frame
    first = rng.standard_normal(3)
    assert np.allclose(ms[0].p, np.array([1e-3, 2e-3, -1e-3]) + 1e-4 * first, rtol=0, atol=0)
    rng.random(3)
    assert np.allclose(ms[1].p, np.array([1e-3, 2e-3, -1e-3]) + 1e-4 * rng.standard_normal(3), rtol=0, atol=0)
    assert VariateBuffer(np.random.default_rng(0), 3)._per == 6


def test_outliers_fixed_in_the_xz_plane_and_random_on_the_sphere() -> None:
    fixed = ImagerParams(noise_sigma_m=0.0, frame_rate_Hz=1000.0, outliers=(
        OutlierBurst(start_s=0.01, duration_s=0.01, magnitude_m=1e-3, direction="fixed", angle_rad=math.pi / 2),))
    ms = _frames(ImagerModel(fixed, np.random.default_rng(0), dims=3), 30)
    hit = [m for m in ms if m and m.outlier]
    assert len(hit) == 10 and all(np.allclose(m.p - [1e-3, 2e-3, -1e-3], [0, 0, 1e-3], atol=1e-18) for m in hit)
    rnd = ImagerParams(noise_sigma_m=0.0, frame_rate_Hz=1000.0, outliers=(
        OutlierBurst(start_s=0.0, duration_s=1.0, magnitude_m=1e-3, direction="random_per_frame"),))
    off = np.array([m.p for m in _frames(ImagerModel(rnd, np.random.default_rng(1), dims=3), 990) if m]) - [1e-3, 2e-3, -1e-3]
    assert np.allclose(np.linalg.norm(off, axis=1), 1e-3, rtol=1e-12)
    assert np.allclose(off.mean(axis=0), 0.0, atol=0.05e-3) and np.allclose((off ** 2).mean(axis=0), 1e-6 / 3, rtol=0.1)


def test_dropouts_and_bad_input() -> None:
    prm = ImagerParams(noise_sigma_m=0.0, frame_rate_Hz=1000.0, dropouts=(Dropout(start_s=0.005, duration_s=0.005),))
    im = ImagerModel(prm, np.random.default_rng(0), dims=3)
    got = [m is not None for m in _frames(im, 20)]
    assert got == [True] * 5 + [False] * 5 + [True] * 10
    with pytest.raises(ModelInputError, match="finite"):
        im.frame(1.0, np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ModelInputError, match=r"\(3,\)"):
        im.frame(1.0, np.array([0.0, 0.0]))
    im.frame(1.0, np.zeros(3))
    with pytest.raises(ModelInputError, match="non-decreasing"):
        im.frame(0.5, np.zeros(3))


def test_imager_rate_latency_and_noise_sigma() -> None:
    frames = _frames_of(ImagerParams(frame_rate_Hz=50.0, latency_s=0.005), 0)
    got = [(k, f) for k, f in enumerate(frames) if f is not None]
    assert [k for k, _ in got] == [5, 25, 45, 65, 85, 105, 125, 145, 165, 185]
    assert [f.t_acq_s for _, f in got] == pytest.approx([0.0, 0.02, 0.04, 0.06, 0.08, 0.1, 0.12, 0.14, 0.16, 0.18])
    im = ImagerModel(ImagerParams(frame_rate_Hz=1000.0), np.random.default_rng(1))
    z = np.array([im.frame(k * 1e-3, np.zeros(2)).p for k in range(4000)])
    assert np.std(z) == pytest.approx(100e-6, rel=0.05)  # sigma, not a bound
    assert abs(np.mean(z)) < 5e-6


def test_imager_outliers_dropouts_and_draw_order() -> None:
    base = ImagerParams(frame_rate_Hz=1000.0)
    clean = _frames_of(base, 7)
    burst = _frames_of(ImagerParams(frame_rate_Hz=1000.0, outliers=(OutlierBurst(0.05, 0.01, 1e-3),)), 7)
    for k, (a, b) in enumerate(zip(clean, burst)):
        if 50 <= k < 60:
            assert b.outlier
            assert np.linalg.norm(b.p - a.p) == pytest.approx(1e-3, rel=1e-9)
        else:  # outliers do not shift the noise of other frames
            np.testing.assert_array_equal(a.p, b.p)
    im = ImagerModel(base, np.random.default_rng(7))
    im.inject_dropout(0.05, 0.01)
    im.inject_outliers(0.1, 0.005, 2e-3)
    out = [im.frame(k * 1e-3, np.array([0.0, 1e-3])) for k in range(200)]
    assert all(out[k] is None for k in range(50, 60))
    assert all(out[k].outlier for k in range(100, 105))
    np.testing.assert_array_equal(out[150].p, clean[150].p)
    with pytest.raises(ModelInputError, match="true position must be a finite"):
        im.frame(0.3, np.array([math.nan, 0.0]))


def test_outlier_direction_is_an_option_fixed_offset_or_random_per_frame() -> None:
    fixed, clean = _burst_offsets(OutlierBurst(0.01, 0.02, 1e-3, direction="fixed", angle_rad=math.pi / 2))
    assert fixed.shape == (20, 2)
    np.testing.assert_allclose(fixed, np.tile([0.0, 1e-3], (20, 1)), rtol=0, atol=1e-15)  # the same offset, +z
    assert all(np.array_equal(c, [0.0, 0.0]) for c in clean)  # the noise stream is not shifted
    rnd, _ = _burst_offsets(OutlierBurst(0.01, 0.02, 1e-3, direction="random_per_frame"))
    np.testing.assert_allclose(np.linalg.norm(rnd, axis=1), 1e-3, rtol=1e-12)
    assert len({round(math.atan2(z, x), 6) for x, z in rnd}) == 20  # a new direction every frame
    with pytest.raises(Exception, match="direction must be one of"):
        OutlierBurst(direction="sideways")  # type: ignore[arg-type]


def test_paper_scenarios_default_to_a_fixed_outlier_offset() -> None:
    from pathlib import Path

    from vesselbot_ros.sim.scenario import load_scenario

    for name in ("paper_small_artery", "sound_small_artery"):
        sc = load_scenario(Path(__file__).resolve().parents[3] / "config" / f"{name}.yaml")
        assert [(o.direction, o.angle_rad) for o in sc.imager.outliers] == [("fixed", 0.0)], name


def test_variate_buffer_draws_the_generators_stream_and_gives_it_back_where_it_was_used_up_to():
    from vesselbot_ros.scanner.imager_model import VariateBuffer, fill_variates

    direct = np.random.default_rng(7)
    expected = np.zeros(1 + 4 * 300)
    fill_variates(direct, expected, 2)  # 300 acquisitions straight from the generator
    buffered = VariateBuffer(np.random.default_rng(7))
    got = []
    for _ in range(300):  # more than one block
        b = buffered.ready()
        i = int(b[0])
        got.extend(b[i + 1:i + 5])
        b[0] = i + 4  # what the compiled next_normal / next_uniform do, four times
    assert np.array_equal(np.array(got), expected[1:])
    # the generator comes back exactly where 300 acquisitions left it, whatever was drawn ahead
    assert buffered.generator().random() == direct.random()


def test_the_imager_per_tick_and_its_generator_handed_on_continue_one_stream():
    from vesselbot_ros.scanner.imager_model import fill_variates

    params = ImagerParams(frame_rate_Hz=1000.0, noise_sigma_m=1e-4, latency_s=0.0)
    a = ImagerModel(params, np.random.default_rng(3))
    b = ImagerModel(params, np.random.default_rng(3))
    p = np.array([1e-3, 2e-4])
    for k in range(10):
        assert a.frame(k * 1e-3, p).p.tolist() == b.frame(k * 1e-3, p).p.tolist()
    a_next = a.rng.standard_normal()
    b.frame(10e-3, p)  # b draws one more acquisition: two normals first
    ref = np.random.default_rng(3)
    fill_variates(ref, np.zeros(1 + 4 * 10), 2)
    assert a_next == ref.standard_normal()


def _frames_of(prm: ImagerParams, seed: int, n: int = 200, dt: float = 1e-3) -> list:
    im = ImagerModel(prm, np.random.default_rng(seed))
    return [im.frame(k * dt, np.array([0.0, 1e-3])) for k in range(n)]


def _burst_offsets(burst: OutlierBurst, seed: int = 3) -> tuple[np.ndarray, list[np.ndarray]]:
    im = ImagerModel(ImagerParams(noise_sigma_m=1e-5, frame_rate_Hz=1000.0, outliers=(burst,)), np.random.default_rng(seed))
    ref = ImagerModel(ImagerParams(noise_sigma_m=1e-5, frame_rate_Hz=1000.0), np.random.default_rng(seed))
    offsets, clean = [], []
    for k in range(40):
        t = k * 1e-3
        a, b = im.frame(t, [0.0, 0.0]), ref.frame(t, [0.0, 0.0])
        (offsets if a.outlier else clean).append(a.p - b.p)
    return np.array(offsets), clean
