"""The imager (vesselbot_ros.control.imager_model) on three axes: the plane's timing, a noise per axis, outliers in
space; one class for both (the axis count is the imager's dims)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vesselbot_ros.control.imager_model import Dropout, ImagerModel, ImagerParams, OutlierBurst, VariateBuffer
from vesselbot_ros.errors import ModelInputError


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
