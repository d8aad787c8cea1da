"""The 3-D force terms: the planar network's doubles in the plane y = 0, and rotation-covariant about the vertical."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from vesselbot_ros.physics import kernel
from vesselbot_ros.physics.kernel3d import accel3d, forces3d_into
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios
from vesselbot_ros.vessels import cfd

_P = cfd.packed_params(load_scenario(shipped_scenarios()["paper_iiic_network_upper"]).physics)
_CONTACTS = (np.zeros(4), np.array([1.0, 2e-8, 1e-6, 0.0]), np.array([2.0, 3e-8, 2e-6, 1e-8]))


def _planar(t: float, x: float, z: float, vx: float, vz: float, gx: float, gz: float, contact: np.ndarray):
    out2 = np.empty((8, 2))
    kernel._forces_network(t, x, z, vx, vz, gx, gz, contact, _P, out2)
    s_t, nx, nz, d_t, eta, vfx, vfz = kernel.network_geometry(t, x, z, _P)
    out3 = np.empty((8, 3))
    forces3d_into(np.array([vx, 0.0, vz]), np.array([gx, 0.0, gz]), s_t, np.array([nx, 0.0, nz]), d_t, eta,
                  np.array([vfx, 0.0, vfz]), contact, _P, out3)
    return out2, out3


def test_in_the_plane_it_is_the_planar_networks_doubles() -> None:
    """Points all over the III-C network's lumen (junction, near the walls, in contact): x and z bit for bit, y = 0."""
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(400):
        x, z = rng.uniform(-1e-3, 20e-3), rng.uniform(-6e-3, 6e-3)
        if kernel.network_geometry(0.3, x, z, _P)[0] <= 0.0:
            continue
        vx, vz, gx, gz = rng.normal(0, 5e-3), rng.normal(0, 5e-3), rng.normal(0, 0.08), rng.normal(0, 0.08)
        for contact in _CONTACTS:
            out2, out3 = _planar(0.3, x, z, vx, vz, gx, gz, contact)
            assert np.array_equal(out3[:, [0, 2]], out2)
            assert np.all(out3[:, 1] == 0.0)
            checked += 1
    assert checked > 300


@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 2 * math.pi), st.floats(2.6e-4, 1.4e-3), st.floats(-0.01, 0.01), st.floats(-0.01, 0.01),
       st.floats(-0.1, 0.1), st.floats(-0.1, 0.1))
def test_turning_the_scene_about_the_vertical_turns_the_forces(angle: float, s: float, vx: float, vz: float,
                                                               gx: float, gz: float) -> None:
    """Gravity is along z, everything else turns with the scene: a rotation about z of the velocity, gradient, wall
    normal and flow rotates every force term (the weight stays along z)."""
    c, sn = math.cos(angle), math.sin(angle)
    rot = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
    v, g = np.array([vx, 0.0, vz]), np.array([gx, 0.0, gz])
    n = np.array([0.6, 0.0, -0.8])
    vf = np.array([0.02, 0.0, 0.001])
    a, b = np.empty((8, 3)), np.empty((8, 3))
    forces3d_into(v, g, s, n, 3e-3, 3.5e-3, vf, _CONTACTS[0], _P, a)
    forces3d_into(rot @ v, rot @ g, s, rot @ n, 3e-3, 3.5e-3, rot @ vf, _CONTACTS[0], _P, b)
    scale = np.abs(a).max()
    np.testing.assert_allclose(b, a @ rot.T, rtol=0, atol=1e-12 * scale)
    np.testing.assert_array_equal(accel3d(v, g, s, n, 3e-3, 3.5e-3, vf, _CONTACTS[0], _P), a[7] / _P[kernel.I_MASS])
