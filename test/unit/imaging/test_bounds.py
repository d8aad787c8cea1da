"""The Cramer-Rao bound: a textbook case, its scaling with the noise, the nuisance scale, the step it uses."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vesselbot_ros.imaging.acquisition import PRESETS
from vesselbot_ros.imaging.bounds import crb_from_jacobian, projection_crb, slice_crb
from vesselbot_ros.physics.params import RobotParams

ROBOT = RobotParams()
SLICE = dataclasses.replace(PRESETS["gre_3t"], matrix=32)
TRUE = np.array([0.37e-3, 0.0, -0.21e-3])


def test_a_shifted_gaussian_has_the_textbook_bound() -> None:
    """d_n = A g(x_n - p) + noise: var(p) >= sigma^2 / (A^2 sum g'^2) (amplitude known: one column)."""
    x = np.linspace(-5, 5, 401)
    g = np.exp(-0.5 * x ** 2)
    dg = x * g  # d/dp of g(x - p) at p = 0
    sigma = 0.1
    jac = (2.0 * dg).astype(np.complex128)[:, None]
    assert crb_from_jacobian(jac, sigma, 1)[0, 0] == pytest.approx(sigma ** 2 / (4.0 * (dg ** 2).sum()), rel=1e-12)
    # a complex amplitude as nuisance: the derivative is orthogonal to g, so the bound does not grow
    full = np.stack([2.0 * dg, g, 1j * g], axis=1).astype(np.complex128)
    assert crb_from_jacobian(full, sigma, 1)[0, 0] == pytest.approx(sigma ** 2 / (4.0 * (dg ** 2).sum()), rel=1e-9)


def test_the_slice_bound_scales_as_sigma_squared_and_is_below_a_pixel() -> None:
    a = slice_crb(SLICE, ROBOT, TRUE, (0.0, 0.0, 0.0), 3e-3)
    b = slice_crb(dataclasses.replace(SLICE, snr=SLICE.snr / 2.0), ROBOT, TRUE, (0.0, 0.0, 0.0), 3e-3)
    assert b == pytest.approx(4.0 * a, rel=1e-9)
    assert np.all(np.linalg.eigvalsh(a) > 0)
    assert np.sqrt(np.trace(a)) < 0.1 * SLICE.pixel_m  # the artefact spans tens of pixels: far below a pixel


def test_the_bound_does_not_depend_on_the_differencing_step() -> None:
    a = slice_crb(SLICE, ROBOT, TRUE, (0.0, 0.0, 0.0), 3e-3, step_m=SLICE.pixel_m / 50)
    b = slice_crb(SLICE, ROBOT, TRUE, (0.0, 0.0, 0.0), 3e-3, step_m=SLICE.pixel_m / 200)
    assert np.sqrt(np.diag(b)) == pytest.approx(np.sqrt(np.diag(a)), rel=0.02)


def test_the_projection_bound_is_3x3_and_grows_without_the_bead_in_band() -> None:
    p = dataclasses.replace(PRESETS["msset_1p5t"], matrix=128)
    crb = projection_crb(p, ROBOT, TRUE, (0.0, 0.0, 0.0), 3e-3)
    assert crb.shape == (3, 3) and np.all(np.linalg.eigvalsh(crb) > 0)
    # a weaker bead excites fewer spins in the same band: a larger bound
    weak = projection_crb(p, dataclasses.replace(ROBOT, magnetization_A_per_m=0.5e6), TRUE, (0.0, 0.0, 0.0), 3e-3)
    assert np.trace(weak) > np.trace(crb)
