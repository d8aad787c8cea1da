"""The 3-D plant's compiled geometry, forces and integrators (vesselbot_ros.physics.tree_vessel) in a meshed cylinder.

A gmsh cylinder (R = 1.5 mm along +x, 0.1 mm triangles) sampled on a 0.2 mm grid with a Poiseuille flow
``1 - (rho / R)^2`` along x and a constant viscosity: the lookups against the analytic tube, the pulsation of
(13), the integrators against each other, settling in still blood, and a non-finite input's code.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from vesselbot_ros.control.high_gain_observer import integrator_vector
from vesselbot_ros.geometry.field_build import build_wall_field3d
from vesselbot_ros.geometry.fixtures import cylinder_wall
from vesselbot_ros.geometry.surface_wall import Wall3D
from vesselbot_ros.physics import tree_vessel as p3
from vesselbot_ros.physics.integrator import NON_FINITE, OK, IntegratorParams, integrate, new_workspace
from vesselbot_ros.physics.kernel import I_D_PULSE, I_MASS, I_R, I_V_F, pack_params
from vesselbot_ros.physics.params import PhysicsParams

R = 1.5e-3
H = 0.2e-3
ETA = 3.0e-3


@pytest.fixture(scope="module")
def tube():  # type: ignore[no-untyped-def]
    v, t, caps, _nv = cylinder_wall(R, 8e-3, 0.1e-3)
    field = build_wall_field3d(Wall3D(v, t, caps, margin_m=1.05e-3 + 3 * H), h_m=H)
    nx, ny, nz = field.shape
    o, h = field.head[:3], field.head[3]
    zz, yy = np.meshgrid(o[2] + h * np.arange(nz), o[1] + h * np.arange(ny), indexing="ij")
    rho2 = (yy * yy + zz * zz) / (R * R)
    F = np.zeros((nz, ny, nx, 4))
    F[..., 0] = np.clip(1.0 - rho2, 0.0, None)[:, :, None]
    F[..., 3] = ETA
    fh = np.array([*o, h, nx, ny, nz])
    return field.args, F, fh


def _params(**flow: float) -> np.ndarray:
    phys = PhysicsParams()
    if flow:
        phys = dataclasses.replace(phys, flow=dataclasses.replace(phys.flow, **flow))
    return np.array(pack_params(phys))


def test_geometry_matches_the_tube_and_its_poiseuille_flow(tube) -> None:  # type: ignore[no-untyped-def]
    W, F, fh = tube
    p = _params(diameter_pulsation=0.0, pulsatility=0.0)
    rng = np.random.default_rng(0)
    for _ in range(200):
        rho = rng.uniform(0.0, 1.2e-3)
        th = rng.uniform(0.0, 2.0 * math.pi)
        x = rng.uniform(2e-3, 6e-3)
        y, z = rho * math.cos(th), rho * math.sin(th)
        s, n0, n1, n2, d, eta, vx, vy, vz = p3.tree_geometry(0.0, x, y, z, p, W, F, fh)
        if R - rho <= 1e-3:  # the standard's band
            assert s == pytest.approx(R - rho, abs=12e-6)  # the facets' sag: 0.1^2 / (8 R) = 0.8 um, and the grid's
        else:  # beyond it the lookup interpolates across the axis, the tip of the cone s = R - rho (wall_field3d)
            assert s == pytest.approx(R - rho, abs=0.5 * H)
        if rho > 0.5e-3:  # off the axis, where the nearest wall has a direction (and within the band)
            ang = math.degrees(math.acos(min(1.0, -(n1 * y + n2 * z) / rho)))
            assert ang < 2.0 and abs(n0) < 0.035
        assert d == pytest.approx(2 * R, rel=0.01)
        assert eta == pytest.approx(ETA, rel=1e-12)
        assert vx == pytest.approx(p[I_V_F] * (1.0 - rho * rho / (R * R)), abs=0.02 * p[I_V_F])
        assert vy == 0.0 and vz == 0.0


def test_pulsation_moves_the_wall_out_and_dilates_the_flow(tube) -> None:  # type: ignore[no-untyped-def]
    W, F, fh = tube
    p = _params(pulsatility=0.0)
    t = 0.0  # the phase pi/2 at t = 0: eps = D_PULSE
    eps = p[I_D_PULSE] * math.sin(PhysicsParams().flow.phase_rad)
    s0, *_ = p3.tree_geometry(t, 4e-3, 0.0, 1.0e-3, _params(diameter_pulsation=0.0, pulsatility=0.0), W, F, fh)
    s1, _a, _b, _c, d1, _e, vx, _vy, _vz = p3.tree_geometry(t, 4e-3, 0.0, 1.0e-3, p, W, F, fh)
    d0 = p3.tree_geometry(t, 4e-3, 0.0, 1.0e-3, _params(diameter_pulsation=0.0, pulsatility=0.0), W, F, fh)[4]
    assert s1 == pytest.approx(s0 + 0.5 * d0 * eps, rel=1e-12)
    assert d1 == pytest.approx(d0 * (1.0 + eps), rel=1e-12)
    rho_eff = 1.0e-3 / (1.0 + eps)  # sampled at the point moved towards the axis
    assert vx == pytest.approx(p[I_V_F] * (1.0 - rho_eff ** 2 / R ** 2), abs=0.02 * p[I_V_F])


def test_dopri5_and_fine_rk4_agree(tube) -> None:  # type: ignore[no-untyped-def]
    W, F, fh = tube
    p = _params()
    g = np.array([0.03, -0.02, 0.05])
    ys = []
    for ig in (IntegratorParams(), IntegratorParams(method="rk4", fixed_step_s=2e-6)):
        y = np.array([3e-3, 0.2e-3, -0.3e-3, 0.0, 0.0, 0.0])
        work, fbuf, sc = new_workspace(3)
        stats = np.zeros(4, dtype=np.int64)
        h = ig.max_step_s
        for k in range(20):
            code, h = integrate(k * 1e-3, (k + 1) * 1e-3, y, g, np.zeros(3), np.zeros(4), (p, W, F, fh), h,
                                     integrator_vector(ig), stats, work, fbuf, sc)
            assert code == OK
        ys.append(y)
    assert np.allclose(ys[0][:3], ys[1][:3], atol=1e-8, rtol=0)  # dopri5's default tolerances: nanometres
    assert np.allclose(ys[0][3:], ys[1][3:], atol=1e-6, rtol=0)
    assert ys[0][1] != 0.2e-3  # the y gradient moved it along y


def test_a_bead_settles_at_its_terminal_velocity_in_still_blood(tube) -> None:  # type: ignore[no-untyped-def]
    W, F, fh = tube
    F0 = F.copy()
    F0[..., :3] = 0.0
    F0[..., 3] = 0.3  # a viscous fluid: relaxation time 2 r^2 rho / (9 eta) ~ 0.1 ms, settled within 5 ms
    p = _params(diameter_pulsation=0.0)
    y = np.array([4e-3, 0.0, 0.9e-3, 0.0, 0.0, 0.0])
    work, fbuf, sc = new_workspace(3)
    ig = integrator_vector(IntegratorParams())
    stats = np.zeros(4, dtype=np.int64)
    h = 1e-4
    for k in range(5):
        code, h = integrate(k * 1e-3, (k + 1) * 1e-3, y, np.zeros(3), np.zeros(3), np.zeros(4), (p, W, F0, fh), h, ig,
                                 stats, work, fbuf, sc)
        assert code == OK
    p3.tree_forces_at(5e-3, y, np.zeros(3), np.zeros(4), p, W, F0, fh, fbuf)
    assert y[5] < 0.0 and abs(fbuf[7, 2]) < 1e-3 * abs(fbuf[2, 2])  # the weight balanced by the drag
    assert abs(y[3]) < 1e-3 * abs(y[5]) and abs(y[4]) < 1e-3 * abs(y[5])  # still blood, a vertical weight: falls straight


def test_a_non_finite_gradient_stops_with_its_code(tube) -> None:  # type: ignore[no-untyped-def]
    W, F, fh = tube
    p = _params()
    y = np.array([4e-3, 0.0, 0.0, 0.0, 0.0, 0.0])
    work, fbuf, sc = new_workspace(3)
    code, _h = integrate(0.0, 1e-3, y, np.array([np.nan, 0.0, 0.0]), np.zeros(3), np.zeros(4), (p, W, F, fh), 1e-4,
                              integrator_vector(IntegratorParams()), np.zeros(4, dtype=np.int64), work, fbuf, sc)
    assert code == NON_FINITE


def test_contact_state_advances_with_the_distance_to_the_wall(tube) -> None:  # type: ignore[no-untyped-def]
    W, F, fh = tube
    p = _params(diameter_pulsation=0.0)
    r = p[I_R]
    y = np.array([4e-3, 0.0, R - r + 2e-6, 0.0, 0.0, 0.0])  # 2 um into the upper wall
    contact = np.zeros(4)
    p3.tree_contact_update(0.0, y, contact, p, W, F, fh)
    assert contact[0] == 1.0  # loading
    assert p[I_MASS] > 0
