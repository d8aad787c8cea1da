"""Tests of the numba kernel: consistency with the numpy API, finiteness, contact bookkeeping."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vesselbot_ros.physics import kernel
from vesselbot_ros.physics.force_balance import ContactState, force_terms, update_contact_state
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios
from vesselbot_ros.vessels import cfd

P = PhysicsParams()
PK = kernel.pack_params(P)


def test_packed_values():
    assert PK[kernel.I_MASS] == pytest.approx(P.robot.mass_kg)
    assert PK[kernel.I_HERTZ_K] == pytest.approx(1.117e7, rel=1e-3)
    assert PK[kernel.I_CHARGE] == pytest.approx(7.13e-11, rel=1e-2)
    assert PK[kernel.I_EL_FACTOR] == 0.25
    assert PK.size == kernel.N_FIXED
    bif = kernel.pack_params(P.with_overrides({"vessel.major_bifurcation.enabled": True}))
    k = int(bif[kernel.I_BIF_NKNOTS])
    assert bif.size == kernel.N_FIXED + 15 * k


def test_accel_is_total_over_mass_and_no_motive_drops_magnetic():
    c = np.zeros(4)
    state = (0.37, 0.002, 0.4e-3, 0.01, -0.003)
    ax, az = kernel.accel(*state, 0.05, -0.02, c, PK)
    ft = force_terms(state[0], state[1:3], state[3:5], [0.05, -0.02], ContactState(), P)
    np.testing.assert_allclose([ax, az], ft.total / P.robot.mass_kg, rtol=1e-13, atol=1e-12)
    fx, fz = kernel.accel_no_motive(*state, c, PK)
    np.testing.assert_allclose([fx, fz], (ft.total - ft.magnetic) / P.robot.mass_kg, rtol=1e-12, atol=1e-12)


def test_forces_into_rows_follow_term_names():
    out = np.empty((8, 2))
    kernel.forces_into(0.1, 0.0, 0.5e-3, 0.0, 0.0, 0.0, 0.08, np.zeros(4), PK, out)
    assert kernel.TERM_NAMES[0] == "magnetic" and out[0, 1] == pytest.approx(7.2e-6, rel=1e-2)
    np.testing.assert_allclose(out[7], out[:7].sum(axis=0), rtol=1e-14, atol=1e-18)


@pytest.mark.parametrize("z", [-1.0, -3e-3, -1.26e-3, 0.0, 1.2499e-3, 1.6e-3, 5e-3, 1e3])
@pytest.mark.parametrize("phase", [0.0, 1.0, 2.0])
def test_finite_everywhere_including_outside_the_vessel(z, phase):
    c = np.array([phase, 1e-6 * (phase > 0), 1e-3 * (phase > 0), 1e-7 * (phase > 1)])
    overrides = {"interactions.in_contact": "paper_heaviside", "vessel.major_bifurcation.enabled": True}
    for p in (PK, kernel.pack_params(P.with_overrides(overrides))):
        out = np.empty((8, 2))
        kernel.forces_into(0.3, 0.015, z, 1e3, -1e3, 0.08, 0.08, c, p, out)
        assert np.all(np.isfinite(out))


def test_update_contact_matches_pure_state_update():
    c = np.zeros(4)
    s = ContactState()
    for delta in (-1e-6, 5e-8, 1e-7, 8e-8, 1.2e-7, 1e-8, -1e-9):
        kernel.update_contact(c, delta, PK)
        s = update_contact_state(s, delta, P)
        np.testing.assert_allclose(c, s.to_array(), rtol=1e-14, atol=1e-21)


def test_paper_printed_electrostatic_traps_at_upper_wall():
    pp = kernel.pack_params(P.with_overrides({"interactions.electrostatic_model": "paper_printed"}))
    t = 0.25  # D(t) = D
    z = 1.5e-3 - 250e-6  # touching the upper wall
    out = np.empty((8, 2))
    kernel.forces_into(t, 0.0, z, 0.0, 0.0, 0.0, 0.0, np.zeros(4), pp, out)
    q = 1e-6 * 4 * math.pi * 250e-6**2 * 30 * (100 * 250e-6) ** -0.3
    eps = 70 * 8.8541878128e-12
    far = q * q / (4 * math.pi * eps * (250e-6 + 2.5e-3) ** 2)  # the lower wall's pull
    assert out[5, 1] == pytest.approx(q * q / (4 * math.pi * eps * 250e-6**2) - far, rel=1e-9)
    assert out[5, 1] > 0.8 * 4 / 3 * math.pi * 250e-6**3 * 1.72e6 * 0.08


def test_brush_limited_vdw_no_longer_traps_but_atomic_floor_does():
    # robot pressed on the upper wall at t = 0.25 s (D(t) = D): the vdW term is floored
    t, r, A = 0.25, 250e-6, 4e-19
    z = 1.5e-3 - r + 1e-9  # 1 nm penetration
    bp_max = 0.8 * 4 / 3 * math.pi * r**3 * 1.72e6 * 0.08  # largest bead-pulling force, 7.2e-6 N
    out = np.empty((8, 2))

    def vdw_hand(g):  # 2 A / (3 r h^2 (h+2)^2), h = g / r, minus the far wall's pull
        h = g / r
        hf = (3e-3 - 2 * r) / r
        return 2 * A / (3 * r * h * h * (h + 2) ** 2) - 2 * A / (3 * r * hf * hf * (hf + 2) ** 2)

    kernel.forces_into(t, 0.0, z, 0.0, 0.0, 0.0, 0.0, np.zeros(4), PK, out)
    assert out[4, 1] == pytest.approx(vdw_hand(20e-9), rel=1e-6)
    assert out[4, 1] == pytest.approx(A * r / (6 * (20e-9) ** 2), rel=2e-3)  # ~4.2e-8 N
    assert out[4, 1] < 0.01 * bp_max
    atomic = kernel.pack_params(P.with_overrides({"interactions.vdw_min_separation": "explicit",
                                                  "interactions.vdw_min_separation_m": 0.4e-9}))
    kernel.forces_into(t, 0.0, z, 0.0, 0.0, 0.0, 0.0, np.zeros(4), atomic, out)
    assert out[4, 1] == pytest.approx(vdw_hand(0.4e-9), rel=1e-6)
    assert out[4, 1] > 10 * bp_max  # ~1e-4 N: the robot sticks


def test_onto_lumen_puts_a_centre_in_or_near_the_wall_gap_from_it_and_drops_the_velocity_into_it() -> None:
    from vesselbot_ros.physics.kernel import diameter_at, onto_lumen
    from vesselbot_ros.physics.params import PhysicsParams
    from vesselbot_ros.vessels.cfd import packed_params

    ph = PhysicsParams()
    p = packed_params(ph)
    t = 0.2
    touch = 0.5 * float(diameter_at(t, p)) - ph.robot.radius_m
    # lower wall: in it, or within the gap -> gap from it; the velocity into it (down) goes, along it stays
    for z in (-touch - 1e-4, -touch + 0.5e-7):
        x0, x1, z0, z1 = onto_lumen(t, 1e-3, z, 3e-3, -5e-3, p, 1e-7)
        assert (x0, z0, z1) == (1e-3, 3e-3, 0.0) and x1 == pytest.approx(-touch + 1e-7, abs=1e-15)
    # upper wall, moving away from it: only the position moves
    assert onto_lumen(t, 0.0, touch + 1e-5, 0.0, -1e-3, p, 0.0)[1:] == pytest.approx((touch, 0.0, -1e-3), abs=1e-15)
    # clear of both walls: untouched
    assert onto_lumen(t, 0.0, 0.0, 1.0, 2.0, p, 1e-7) == (0.0, 0.0, 1.0, 2.0)


# --- the wall forces on any axes (the plane and 3-D trees) ---------------------------------------------

_P_NET = cfd.packed_params(load_scenario(shipped_scenarios()["paper_iiic_network_upper"]).physics)
_CONTACTS = (np.zeros(4), np.array([1.0, 2e-8, 1e-6, 0.0]), np.array([2.0, 3e-8, 2e-6, 1e-8]))


def _planar_and_3d(t: float, x: float, z: float, vx: float, vz: float, gx: float, gz: float, contact: np.ndarray):
    out2 = np.empty((8, 2))
    kernel._forces_network(t, x, z, vx, vz, gx, gz, contact, _P_NET, out2)
    s_t, nx, nz, d_t, eta, vfx, vfz = kernel.network_geometry(t, x, z, _P_NET)
    out3 = np.empty((8, 3))
    kernel.wall_forces_into(np.array([vx, 0.0, vz]), np.array([gx, 0.0, gz]), s_t, np.array([nx, 0.0, nz]), d_t, eta,
                  np.array([vfx, 0.0, vfz]), contact, _P_NET, out3)
    return out2, out3


def test_wall_forces_on_three_axes_in_the_plane_are_the_planar_networks_doubles() -> None:
    """Points all over the III-C network's lumen (junction, near the walls, in contact): x and z bit for bit, y = 0."""
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(400):
        x, z = rng.uniform(-1e-3, 20e-3), rng.uniform(-6e-3, 6e-3)
        if kernel.network_geometry(0.3, x, z, _P_NET)[0] <= 0.0:
            continue
        vx, vz, gx, gz = rng.normal(0, 5e-3), rng.normal(0, 5e-3), rng.normal(0, 0.08), rng.normal(0, 0.08)
        for contact in _CONTACTS:
            out2, out3 = _planar_and_3d(0.3, x, z, vx, vz, gx, gz, contact)
            assert np.array_equal(out3[:, [0, 2]], out2)
            assert np.all(out3[:, 1] == 0.0)
            checked += 1
    assert checked > 300


@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 2 * math.pi), st.floats(2.6e-4, 1.4e-3), st.floats(-0.01, 0.01), st.floats(-0.01, 0.01),
       st.floats(-0.1, 0.1), st.floats(-0.1, 0.1))
def test_turning_the_scene_about_the_vertical_turns_the_wall_forces(angle: float, s: float, vx: float, vz: float,
                                                               gx: float, gz: float) -> None:
    """Gravity is along z, everything else turns with the scene: a rotation about z of the velocity, gradient, wall
    normal and flow rotates every force term (the weight stays along z)."""
    c, sn = math.cos(angle), math.sin(angle)
    rot = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
    v, g = np.array([vx, 0.0, vz]), np.array([gx, 0.0, gz])
    n = np.array([0.6, 0.0, -0.8])
    vf = np.array([0.02, 0.0, 0.001])
    a, b = np.empty((8, 3)), np.empty((8, 3))
    kernel.wall_forces_into(v, g, s, n, 3e-3, 3.5e-3, vf, _CONTACTS[0], _P_NET, a)
    kernel.wall_forces_into(rot @ v, rot @ g, s, rot @ n, 3e-3, 3.5e-3, rot @ vf, _CONTACTS[0], _P_NET, b)
    scale = np.abs(a).max()
    np.testing.assert_allclose(b, a @ rot.T, rtol=0, atol=1e-12 * scale)


@pytest.mark.parametrize("name", ["sound_small_artery", "paper_iiic_network_lower"])
def test_flow_scaled_params_are_the_model_with_v_f_scaled_from_any_start(name: str) -> None:
    """``flow_scaled_into`` gives ``p`` with V_f times s whatever ``p_s`` held before (fresh, garbage, another
    scale), though a network's field block is copied only into a ``p_s`` that does not hold it yet."""
    p = cfd.packed_params(load_scenario(shipped_scenarios()[name]).physics)
    want = p.copy()
    want[kernel.I_V_F] = p[kernel.I_V_F] * 1.05
    for start in (np.zeros_like(p), np.full_like(p, np.nan), p * 3.0 + 1.0):
        p_s = start
        kernel.flow_scaled_into(p, 1.05, p_s)
        np.testing.assert_array_equal(p_s, want)
        kernel.flow_scaled_into(p, 0.9, p_s)  # again, on what it now holds
        want2 = p.copy()
        want2[kernel.I_V_F] = p[kernel.I_V_F] * 0.9
        np.testing.assert_array_equal(p_s, want2)


def test_inflow_fraction_scales_v_f_in_the_packed_parameters_and_is_exact_at_one() -> None:
    p = PhysicsParams()
    assert kernel.pack_params(p)[kernel.I_V_F] == p.flow.centreline_velocity_m_per_s
    low = p.with_overrides({"flow.inflow_fraction": 0.1})
    head, base = kernel.pack_params(low), kernel.pack_params(p)
    assert head[kernel.I_V_F] == 0.025 * 0.1
    others = np.arange(kernel.N_FIXED) != kernel.I_V_F
    assert np.array_equal(head[:kernel.N_FIXED][others], base[:kernel.N_FIXED][others])
