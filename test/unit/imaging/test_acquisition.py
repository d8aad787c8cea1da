"""The MR acquisition model: parameters, the phantom's proton density, the readout shift, noise, moving beads."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.imaging.acquisition import (
    PRESETS,
    MrImagingParams,
    acquire_projections,
    acquire_slice,
    check_field_of_view,
    noise_sigma,
    projection_data,
    slice_image,
)
from vesselbot_ros.physics.params import RobotParams

SMALL = MrImagingParams(matrix=32, pixel_m=1e-3, echo_time_s=3e-3, repetition_time_s=6e-3)
ROBOT = RobotParams()


@pytest.mark.parametrize(("changes", "words"), [
    ({"echo_time_s": 0.0}, "echo_time_s must be > 0, got 0.0"),
    ({"echo_time_s": -1e-3}, "echo_time_s must be > 0, got -0.001"),
    ({"pixel_m": 0.0}, "pixel_m must be > 0, got 0.0"),
    ({"pixel_m": -1e-3}, "pixel_m must be > 0, got -0.001"),
    ({"matrix": 33}, "matrix must be even, got 33"),
    ({"matrix": 4}, "matrix must be in [8, 1024], got 4"),
    ({"oversample": 0}, "oversample must be in [1, 8], got 0"),
    ({"matrix": 512, "oversample": 5}, "oversample must keep matrix x oversample <= 2048 (matrix = 512), got 5"),
    ({"snr": 0.0}, "snr must be > 0, got 0.0"),
    ({"bandwidth_Hz_per_pixel": 100.0, "echo_time_s": 3e-3}, "echo_time_s must be >= half the readout"),
    ({"readout_axis": "y"}, "readout_axis must be one of ['x', 'z'], got 'y'"),
    ({"excitation_offset_Hz": 100.0}, "excitation_offset_Hz must lie more than 0.6 excitation_bandwidth_Hz (1000.0) "
                                      "from b0_offset_Hz (0.0), so the background is not excited, got 100.0"),
    ({"b0_offset_Hz": 1200.0}, "from b0_offset_Hz (1200.0)"),
    ({"b0_offset_Hz": float("nan")}, "b0_offset_Hz must be finite, got nan"),
])
def test_bad_parameters_name_the_key_and_the_value(changes: dict[str, object], words: str) -> None:
    with pytest.raises(ConfigError) as err:
        dataclasses.replace(MrImagingParams(), **changes)
    assert words in str(err.value)


def test_a_field_of_view_smaller_than_the_vessel_is_refused() -> None:
    p = MrImagingParams(matrix=8, pixel_m=0.25e-3, echo_time_s=3e-3)
    with pytest.raises(ConfigError, match=r"fov_m \(matrix x pixel_m\) must be >= the vessel's diameter \(0.003 m\), "
                                          r"got 0.002"):
        check_field_of_view(p, 3e-3)
    check_field_of_view(PRESETS["gre_3t"], 3e-3)


def test_the_presets_are_valid_and_name_their_acquisition() -> None:
    assert PRESETS["gre_1p5t"].b0_T == 1.5 and PRESETS["gre_3t"].b0_T == 3.0
    assert PRESETS["msset_1p5t"].acquisition == "projections"
    assert PRESETS["gre_3t"].fov_m == pytest.approx(0.128)


def test_a_phantom_without_bead_reconstructs_to_its_proton_density() -> None:
    img = slice_image(SMALL, ROBOT, None, (0.0, 0.0, 0.0))
    expected = SMALL.tissue_proton_density * np.exp(-SMALL.echo_time_s / SMALL.t2star_s)
    assert np.abs(img - expected).max() < 1e-12 * expected
    # with the vessel (3 mm along x): far from it, the tissue; along it, uniform in x; the image's mean is the
    # object's mean (the k-space centre is the sum)
    img = slice_image(SMALL, ROBOT, None, (0.0, 0.0, 0.0), vessel_diameter_m=3e-3)
    z = (np.arange(32) - 16) * 1e-3
    far = np.abs(z) > 6e-3
    assert np.abs(img[far] - expected).max() < 0.01 * expected
    assert np.abs(img - img[:, :1]).max() < 1e-12
    assert img.imag.max() < 1e-12 and abs(img.imag.min()) < 1e-12
    centre_row = img[16, 0].real
    assert expected < centre_row  # blood: more protons and a longer T2*, partial volume in the 5 mm slice


@pytest.mark.parametrize("bandwidth", [500.0, 1000.0])
def test_the_readout_shifts_by_df_over_the_bandwidth_per_pixel_towards_plus_readout(bandwidth: float) -> None:
    """MS-SET excites a narrow band (1500 +- 100 Hz): the y projection, symmetric about the bead, moves by
    1500 / bandwidth pixels along +y (the convention every acquisition shares)."""
    p = MrImagingParams(acquisition="projections", matrix=128, pixel_m=0.5e-3, echo_time_s=2e-3,
                        bandwidth_Hz_per_pixel=bandwidth, excitation_offset_Hz=1500.0, excitation_bandwidth_Hz=200.0)
    data = projection_data(p, ROBOT, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    w = np.abs(data[1]) ** 2
    centroid_px = float((w * (np.arange(128) - 64)).sum() / w.sum())
    assert centroid_px == pytest.approx(1500.0 / bandwidth, abs=0.1)
    # along x the lobes are symmetric about the bead too: the same shift
    wx = np.abs(data[0]) ** 2
    assert float((wx * (np.arange(128) - 64)).sum() / wx.sum()) == pytest.approx(1500.0 / bandwidth, abs=0.15)


@pytest.mark.parametrize("pixels", [2, -3])
def test_a_slice_shifts_along_its_readout_by_df_over_the_bandwidth_per_pixel(pixels: int) -> None:
    """A uniform off-resonance df = pixels x bandwidth moves the vessel (the image of its spins alone: the vessel
    phantom minus the uniform one, so the FOV's edges cancel) by exactly ``pixels`` along +readout (z: the vessel
    runs along x, so only a readout across it shows the shift; x shares the code path), with the phase
    -2 pi df TE.  A very wide slice pulse makes the slab's own shift negligible."""
    p = dataclasses.replace(SMALL, readout_axis="z", rf_bandwidth_Hz=1e12)
    df = pixels * p.bandwidth_Hz_per_pixel
    q = dataclasses.replace(p, b0_offset_Hz=df)

    def vessel_only(params: MrImagingParams) -> np.ndarray:
        return slice_image(params, ROBOT, None, (0.0, 0.0, 0.0), 3e-3) - slice_image(params, ROBOT, None,
                                                                                      (0.0, 0.0, 0.0))

    base, moved = vessel_only(p), vessel_only(q)
    expected = np.roll(base, pixels, axis=1) * np.exp(-2j * np.pi * df * p.echo_time_s)  # columns: readout
    assert np.abs(moved - expected).max() < 1e-12 * np.abs(base).max()
    assert np.abs(base - expected).max() > 0.1 * np.abs(base).max()  # it did move


def test_the_slice_artefact_follows_the_bead_and_voids_the_signal_near_it() -> None:
    p = dataclasses.replace(SMALL, matrix=48)
    a = np.abs(slice_image(p, ROBOT, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)))
    b = np.abs(slice_image(p, ROBOT, (0.0, 0.0, 4e-3), (0.0, 0.0, 0.0)))  # 4 pixels along z: rows
    expected = p.tissue_proton_density * np.exp(-p.echo_time_s / p.t2star_s)
    assert a[24, 24] < 0.2 * expected  # the void at the bead
    # a shift along the phase axis shifts the image (but for the field's tails at the FOV's edges: < 1 %)
    assert np.abs(b[8:40, :] - a[4:36, :]).max() < 0.01 * expected
    assert b[28, 24] < 0.2 * expected


def test_noise_is_seeded_and_has_the_documented_sigma() -> None:
    p = dataclasses.replace(SMALL, matrix=64, snr=5.0)
    f1 = acquire_slice(p, ROBOT, None, np.random.default_rng(7))
    f2 = acquire_slice(p, ROBOT, None, np.random.default_rng(7))
    assert np.array_equal(f1.image, f2.image)
    resid = f1.image - slice_image(p, ROBOT, None, (0.0, 0.0, 0.0))
    assert f1.sigma == noise_sigma(p) == pytest.approx(0.2)
    assert np.std(resid.real) == pytest.approx(0.2, rel=0.05)
    assert np.std(resid.imag) == pytest.approx(0.2, rel=0.05)
    pr = acquire_projections(PRESETS["msset_1p5t"], ROBOT, None, np.random.default_rng(1))
    assert np.std(pr.data.real) == pytest.approx(noise_sigma(PRESETS["msset_1p5t"]), rel=0.1)  # nothing excited


def test_a_moving_bead_fills_k_space_lines_in_order() -> None:
    p = SMALL
    one = slice_image(p, ROBOT, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert np.array_equal(slice_image(p, ROBOT, [(0.0, 0.0), (0.0, 0.0)], (0.0, 0.0, 0.0)), one)
    two = slice_image(p, ROBOT, [(0.0, 0.0), (2e-3, 0.0)], (0.0, 0.0, 0.0))
    other = slice_image(p, ROBOT, (2e-3, 0.0), (0.0, 0.0, 0.0))

    def k(im: np.ndarray) -> np.ndarray:
        return np.fft.fftshift(np.fft.fft2(np.fft.ifftshift(im)))

    assert np.allclose(k(two)[:16], k(one)[:16], atol=1e-9) and np.allclose(k(two)[16:], k(other)[16:], atol=1e-9)


def test_a_moving_bead_gives_each_projection_its_own_position() -> None:
    p = dataclasses.replace(PRESETS["msset_1p5t"], matrix=64)
    path = [(0.0, 0.0, 0.0), (1e-3, 0.0, 0.0), (0.0, 0.0, 1e-3)]
    moving = projection_data(p, ROBOT, path, (0.0, 0.0, 0.0))
    for axis, pos in enumerate(path):
        assert np.array_equal(moving[axis], projection_data(p, ROBOT, pos, (0.0, 0.0, 0.0))[axis])
