"""Tests of the numpy force-balance API (eq. (1), every term separately)."""

import math

import numpy as np
import pytest

from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.force_balance import ContactState, force_terms, robot_mass, update_contact_state
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.physics.wall_contact import LOADING

P = PhysicsParams()
T_MEAN = 0.25  # sin(2 pi 0.25 + pi/2) = 0: pulse factor 1 and D(t) = D
TERMS = ("magnetic", "drag", "apparent_weight", "contact", "van_der_waals", "electrostatic", "steric")


def test_total_is_sum_and_weight_value():
    ft = force_terms(T_MEAN, [0.0, 0.3e-3], [0.01, -0.002], [0.03, 0.05], ContactState(), P)
    np.testing.assert_allclose(ft.total, sum(getattr(ft, n) for n in TERMS), rtol=1e-14, atol=1e-18)
    w = 4 / 3 * math.pi * (250e-6) ** 3 * (0.8 * 7874 + 0.2 * 1500 - 1060) * 9.81
    np.testing.assert_allclose(ft.apparent_weight, [0.0, -w], rtol=1e-12, atol=1e-18)
    assert w == pytest.approx(3.55e-6, rel=1e-2)
    np.testing.assert_allclose(ft.magnetic, 0.8 * 4 / 3 * math.pi * (250e-6) ** 3 * 1.72e6 * np.array([0.03, 0.05]), rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(ft.without_motive(), ft.total - ft.magnetic, rtol=1e-12, atol=1e-18)


def test_drag_uses_local_flow_and_vanishes_when_comoving():
    z = 0.3e-3
    vf = 0.025 * (1 - (2 * z / 3e-3) ** 2)
    ft = force_terms(T_MEAN, [0.0, z], [vf, 0.0], [0.0, 0.0], ContactState(), P)
    np.testing.assert_allclose(ft.v_fluid_W, [vf, 0.0], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(ft.drag, 0.0, atol=1e-20)
    still = force_terms(T_MEAN, [0.0, z], [0.0, 0.0], [0.0, 0.0], ContactState(), P)
    assert still.drag[0] > 0  # blood pushes a still robot downstream


def test_geometry_fields_and_signs_near_upper_wall():
    z = 1.5e-3 - 250e-6 - 50e-9  # 50 nm gap to the upper wall at D(t) = D
    ft = force_terms(T_MEAN, [0.0, z], [0.0, 0.0], [0.0, 0.0], ContactState(), P)
    assert ft.wall == 1 and ft.delta_m == pytest.approx(-50e-9, rel=1e-6)
    np.testing.assert_allclose(ft.normal_W, [0.0, 1.0], atol=1e-15)
    assert ft.diameter_m == pytest.approx(3e-3)
    assert ft.van_der_waals[1] > 0 and ft.electrostatic[1] > 0  # attraction towards the wall (+n)
    assert ft.steric[1] < 0  # repulsion
    low = force_terms(T_MEAN, [0.0, -z], [0.0, 0.0], [0.0, 0.0], ContactState(), P)
    assert low.wall == -1 and low.van_der_waals[1] < 0 and low.electrostatic[1] < 0 and low.steric[1] > 0


def test_contact_repels_and_state_update():
    z = 1.5e-3 - 250e-6 + 1e-7  # 100 nm penetration
    ft = force_terms(T_MEAN, [0.0, z], [0.0, 0.0], [0.0, 0.0], ContactState(), P)
    k = (4 * math.sqrt(250e-6) / 3) / ((1 - 0.27**2) / 1e9 + (1 - 0.2**2) / 1e9)
    assert ft.contact[1] == pytest.approx(-k * 1e-7**1.5, rel=1e-6)
    s = update_contact_state(ContactState(), ft.delta_m, P)
    assert s.phase == LOADING and s.delta_max_m == pytest.approx(1e-7, rel=1e-6)


def test_electrostatic_model_option_is_4x():
    z = 1.5e-3 - 250e-6 - 1e-9
    img = force_terms(T_MEAN, [0.0, z], [0.0, 0.0], [0.0, 0.0], ContactState(), P).electrostatic[1]
    pp = P.with_overrides({"interactions.electrostatic_model": "paper_printed"})
    printed = force_terms(T_MEAN, [0.0, z], [0.0, 0.0], [0.0, 0.0], ContactState(), pp).electrostatic[1]
    assert printed / img == pytest.approx(4.0, rel=1e-3)  # the far wall's pull scales by 4 too


def test_mass():
    assert robot_mass(P) == pytest.approx(6599.2 * 4 / 3 * math.pi * (250e-6) ** 3, rel=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"p_W": [np.nan, 0.0]}, "p_W must be finite"),
        ({"v_W": [0.0, 0.0, 0.0]}, r"v_W must have shape \(2,\)"),
        ({"gradient_T_per_m": [np.inf, 0.0]}, "gradient_T_per_m must be finite"),
        ({"t_s": float("nan")}, "t_s must be finite"),
        ({"contact": (0, 0, 0, 0)}, "contact must be a ContactState"),
    ],
)
def test_input_errors(kwargs, match):
    args = {"t_s": 0.0, "p_W": [0.0, 0.0], "v_W": [0.0, 0.0], "gradient_T_per_m": [0.0, 0.0], "contact": ContactState(), "params": P}
    args.update(kwargs)
    with pytest.raises(ModelInputError, match=match):
        force_terms(**args)
