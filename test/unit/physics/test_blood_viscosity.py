"""Tests of eq. (9) against values computed by hand from Pries et al. (1996)."""

import math

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.physics.blood_viscosity import blood_viscosity, hematocrit_exponent


def pries_by_hand(d_um, h, eta_pl):
    """Pries 1996 in vivo viscosity, written out independently of the module."""
    eta45 = 6 * math.exp(-0.085 * d_um) + 3.2 - 2.44 * math.exp(-0.06 * d_um**0.645)
    c = (0.8 + math.exp(-0.075 * d_um)) * (-1 + 1 / (1 + 1e-11 * d_um**12)) + 1 / (1 + 1e-11 * d_um**12)
    g = (d_um / (d_um - 1.1)) ** 2
    return eta_pl * g * (1 + (eta45 - 1) * g * ((1 - h) ** c - 1) / ((1 - 0.45) ** c - 1))


@pytest.mark.parametrize("d_m", [10e-3, 1e-3, 0.1e-3, 0.01e-3, 3e-3])
@pytest.mark.parametrize("h", [0.45, 0.3])
def test_four_vessel_sizes_match_hand_formula(d_m, h):
    got = float(blood_viscosity(d_m, h, 5e-3))
    assert got == pytest.approx(pries_by_hand(d_m * 1e6, h, 5e-3), rel=1e-12)


def test_capillary_value_at_reference_hematocrit():
    # h = 0.45 -> the hematocrit shape factor is exactly 1:
    # d = 10 um: eta45 = 6 e^-0.85 + 3.2 - 2.44 e^(-0.06 * 10^0.645) = 3.8930, g = (10/8.9)^2 = 1.26247
    g = (10 / 8.9) ** 2
    eta45 = 6 * math.exp(-0.85) + 3.2 - 2.44 * math.exp(-0.06 * 10**0.645)
    assert eta45 == pytest.approx(3.893, abs=1e-3)
    assert float(blood_viscosity(10e-6, 0.45, 5e-3)) == pytest.approx(5e-3 * g * (1 + (eta45 - 1) * g), rel=1e-12)


def test_large_vessels_tend_to_3_2_times_plasma():
    assert float(blood_viscosity(10e-3, 0.45, 5e-3)) == pytest.approx(5e-3 * 3.2, rel=2e-3)


def test_printed_form_agrees_for_large_d_and_diverges_for_small_d():
    for d in (10e-3, 1e-3, 0.1e-3):
        assert float(blood_viscosity(d, 0.3, model="paper_printed")) == pytest.approx(float(blood_viscosity(d, 0.3)), rel=1e-6)
    # d = 3 um: printed c = 1e11 / 3^12 - ... ~ 1.9e5, Pries c ~ 1
    assert float(hematocrit_exponent(3.0, 1.0)) > 1e5
    assert float(hematocrit_exponent(3.0, 0.0)) == pytest.approx(1.0, abs=0.01)
    # with that c, (1 - h)^c -> 0: the printed viscosity loses its hematocrit dependence
    a = float(blood_viscosity(3e-6, 0.2, model="paper_printed"))
    b = float(blood_viscosity(3e-6, 0.4, model="paper_printed"))
    assert a == pytest.approx(b, rel=1e-9)
    assert float(blood_viscosity(3e-6, 0.2)) < float(blood_viscosity(3e-6, 0.4))


def test_constant_model_and_array_shape():
    out = blood_viscosity(np.array([1e-3, 2e-3]), model="constant", constant_viscosity_Pa_s=0.01)
    assert out.shape == (2,)
    np.testing.assert_allclose(out, 0.01, rtol=1e-12, atol=0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"diameter_m": -1e-3}, "diameter_m must be finite and > 0"),
        ({"diameter_m": float("nan")}, "diameter_m must be finite and > 0"),
        ({"diameter_m": 1e-6}, "diameter_m must exceed 1.1e-6"),
        ({"diameter_m": 1e-3, "hematocrit": 1.0}, r"hematocrit must be in \[0, 1\)"),
        ({"diameter_m": 1e-3, "model": "x"}, "viscosity_model must be one of"),
    ],
)
def test_errors(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        blood_viscosity(**kwargs)
