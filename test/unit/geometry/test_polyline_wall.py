"""The plant's wall is the meshed wall (vesselbot_ros.geometry.polyline_wall), checked through the packed-parameter path.

The reference is brute force over the boundary edges of the gmsh triangulation (caps left out),
written here independently of geometry/polyline_wall.py.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt
import pytest

from vesselbot_ros.physics import kernel
from vesselbot_ros.physics.force_balance import force_terms
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.physics.wall_contact import ContactState
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios
from vesselbot_ros.vessels import cfd
from vesselbot_ros.vessels.network import VESSELS_DIR, load_network

# the 2-D networks: the 3-D trees are the 3-D consumers' (the 2-D CFD refuses them), and paper_iiic_artery_3d,
# though planar, is paper_iiic_artery's geometry under another name (its field would be one more solve)
NETWORKS = sorted(p.stem for p in VESSELS_DIR.glob("*.yaml") if not p.stem.endswith("_3d"))


def _physics(network: str) -> PhysicsParams:
    """The III-C scenario's physics in ``network`` with a steady wall and flow (s_t = s, v = V_f field)."""
    ph = load_scenario(shipped_scenarios()["paper_iiic_network_upper"]).physics
    return dataclasses.replace(ph, vessel=dataclasses.replace(ph.vessel, network=network),
                               flow=dataclasses.replace(ph.flow, pulsatility=0.0, diameter_pulsation=0.0))


def _meshed_wall(network: str) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], object]:
    """(a (k, 2), b (k, 2)) wall edges of the gmsh mesh of ``network`` (caps left out), and its triangulation."""
    from matplotlib.tri import Triangulation

    m = cfd.mesh_network(load_network(network))
    t = m.triangles
    e = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    u, c = np.unique(e, axis=0, return_counts=True)
    b = u[c == 1]
    a_, b_ = m.points[b[:, 0]], m.points[b[:, 1]]
    mid = 0.5 * (a_ + b_)
    cap = np.zeros(len(b), dtype=bool)
    for centre, n_out, r in m.caps.values():
        along = (mid - centre) @ n_out
        across = np.abs((mid - centre) @ np.array([-n_out[1], n_out[0]]))
        cap |= (np.abs(along) < 1e-3 * r) & (across <= r * (1 + 1e-6))
    return a_[~cap], b_[~cap], Triangulation(m.points[:, 0], m.points[:, 1], t)


def _brute_force(q: npt.NDArray[np.float64], a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]
                 ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(unsigned distance (m,), nearest wall point (m, 2)) of points q (m, 2) to segments a -> b."""
    d = b - a
    dist = np.empty(len(q))
    foot = np.empty_like(q)
    for s in range(0, len(q), 500):
        qq = q[s:s + 500, None, :]
        t = np.clip(((qq - a) * d).sum(-1) / (d * d).sum(-1), 0.0, 1.0)
        f = a + t[..., None] * d
        dd = np.hypot(*(qq - f).transpose(2, 0, 1))
        k = dd.argmin(axis=1)
        dist[s:s + 500] = dd[np.arange(len(k)), k]
        foot[s:s + 500] = f[np.arange(len(k)), k]
    return dist, foot


@pytest.mark.parametrize("network", NETWORKS)
def test_kernel_distance_and_normal_are_the_meshed_walls_within_5_um_and_2_deg(network: str) -> None:
    """Random points within 1 mm of the wall, inside and just outside the lumen, through packed_params."""
    p = cfd.packed_params(_physics(network))
    a, b, tri = _meshed_wall(network)
    rng = np.random.default_rng(28)
    lo, hi = np.minimum(a, b).min(axis=0) - 3e-4, np.maximum(a, b).max(axis=0) + 3e-4
    q = rng.uniform(lo, hi, size=(12000, 2))
    dist, foot = _brute_force(q, a, b)
    inside = tri.get_trifinder()(q[:, 0], q[:, 1]) >= 0
    caps = cfd.mesh_network(load_network(network)).caps.values()
    # outside: only beside a wall, not beyond an open end (where the lumen continues, see geometry/polyline_wall.py)
    far_from_caps = np.all([np.hypot(*(q - c).T) > 2.0 * r + 1e-3 for c, _n, r in caps], axis=0)
    keep = (inside & (dist < 1e-3)) | (~inside & (dist < 2e-4) & far_from_caps)
    q, dist, foot, inside = q[keep], dist[keep], foot[keep], inside[keep]
    assert inside.sum() > 1000 and (~inside).sum() > 50
    sign = np.where(inside, 1.0, -1.0)
    n_true = sign[:, None] * (q - foot) / dist[:, None]
    got = np.array([kernel.network_geometry(0.0, x, z, p)[:3] for x, z in q])
    err_um = np.abs(got[:, 0] - sign * dist) * 1e6
    ang = np.degrees(np.arccos(np.clip((got[:, 1:] * n_true).sum(axis=1), -1.0, 1.0)))
    ok = dist > 1e-7  # the normal of a point on the wall itself is the wall's, checked below
    assert err_um.max() <= 5.0, (network, err_um.max())
    assert ang[ok].max() <= 2.0, (network, ang[ok].max(), q[ok][int(np.argmax(ang[ok]))])
    # the wall orientation seen at the nearest wall point itself: the inward normal there points into the lumen
    s_in = np.array([kernel.network_geometry(0.0, *(f + 1e-6 * n), p)[0] for f, n in zip(foot[:200], n_true[:200])])
    np.testing.assert_allclose(s_in, 1e-6, atol=5e-9)


def test_no_phantom_contact_upstream_of_the_iii_c_apex() -> None:
    """(12.1, 0) mm, 0.28 mm upstream of the apex: the centreline tubes said clearance 0.141 mm and normal
    (-0.5, 0.866), a contact of delta = +109 um with the scenario's robot; the meshed wall is 0.281 mm away along +x."""
    ph = _physics("paper_iiic_artery")
    p = cfd.packed_params(ph)
    s, nx, nz, _d, _eta, _vx, _vz = kernel.network_geometry(0.0, 12.1e-3, 0.0, p)
    a, b, _tri = _meshed_wall("paper_iiic_artery")
    dist, foot = _brute_force(np.array([[12.1e-3, 0.0]]), a, b)
    assert s == pytest.approx(dist[0], abs=5e-6) and s == pytest.approx(2.81e-4, abs=2e-6)
    assert np.degrees(np.arccos(min(1.0, -nx))) < 2.0 and abs(nz) < 0.03
    assert foot[0, 0] > 12.1e-3  # the apex lies downstream
    ft = force_terms(0.0, [12.1e-3, 0.0], [0.0, 0.0], [0.0, 0.0], ContactState(), ph, packed=cfd.packed_params(ph))
    assert ft.delta_m == pytest.approx(ph.robot.radius_m - s) and ft.delta_m < 0.0  # no contact
    np.testing.assert_array_equal(ft.contact, [0.0, 0.0])
    np.testing.assert_allclose(ft.normal_W, [1.0, 0.0], atol=0.03)  # outward: towards the apex


def test_force_terms_in_a_network_reports_the_networks_geometry_and_both_velocity_components() -> None:
    ph = dataclasses.replace(load_scenario(shipped_scenarios()["paper_iiic_network_upper"]).physics)
    p = cfd.packed_params(ph)
    x, z, t = 13.0e-3, 1.2e-3, 0.37  # in the upper daughter, where the blood flows up at 30 deg
    ft = force_terms(t, [x, z], [0.0, 0.0], [0.0, 0.0], ContactState(), ph, packed=cfd.packed_params(ph))
    s_t, nx, nz, d_t, _eta, vfx, vfz = kernel.network_geometry(t, x, z, p)
    assert ft.delta_m == ph.robot.radius_m - s_t and ft.diameter_m == d_t
    np.testing.assert_array_equal(ft.normal_W, [-nx, -nz])
    np.testing.assert_array_equal(ft.v_fluid_W, [vfx, vfz])
    assert vfz > 0.3 * vfx > 0.0
    assert ft.diameter_m == pytest.approx(2.38e-3 * (1.0 + ph.flow.diameter_pulsation * np.sin(
        ph.flow.angular_frequency_rad_per_s * t + ph.flow.phase_rad)), rel=0.02)


@pytest.mark.parametrize("network", NETWORKS)
def test_velocity_next_to_an_open_end_continues_the_profile_inside(network: str) -> None:
    """A grid node just outside an inlet or outlet cap carries the profile (it was zero: up to 0.99 V_f off
    within 25 um of straight_table3's inlet)."""
    ph = _physics(network)
    p = cfd.packed_params(ph)
    vf = ph.flow.centreline_velocity_m_per_s
    worst = 0.0
    for centre, n_out, r in cfd.mesh_network(load_network(network)).caps.values():
        tang = np.array([-n_out[1], n_out[0]])
        for eta in np.linspace(-0.8, 0.8, 9):
            base = centre + eta * r * tang
            for back in (2e-6, 1e-5, 2.5e-5):
                v_edge = np.array(kernel.fluid_velocity_xz(0.0, *(base - back * n_out), p)) / vf
                v_in = np.array(kernel.fluid_velocity_xz(0.0, *(base - 1.5e-4 * n_out), p)) / vf
                worst = max(worst, float(np.hypot(*(v_edge - v_in)) / max(1.0, abs(v_in @ n_out))))
    assert worst < 0.02, (network, worst)


def test_nodes_check_and_metrics_read_the_plants_wall_bit_for_bit() -> None:
    """network_wall (the nodes' position check, the scenario check, outside_lumen_time_s) and the kernel agree."""
    from vesselbot_ros.vessels.cfd import network_wall

    ph = _physics("paper_iiic_artery")
    p = cfd.packed_params(ph)
    wall = network_wall(load_network("paper_iiic_artery"), ph.blood)
    rng = np.random.default_rng(3)
    q = rng.uniform([-4e-3, -6e-3], [19e-3, 6e-3], size=(2000, 2))
    got = wall.query(q)
    for k in range(0, len(q), 10):
        s, nx, nz, d, _eta, _vx, _vz = kernel.network_geometry(0.0, q[k, 0], q[k, 1], p)
        assert (got["sdist"][k], got["normal"][k, 0], got["normal"][k, 1]) == (s, nx, nz)
        assert wall.clearance(q[k, 0], q[k, 1])[0] == s
        assert wall.clearance(q[k, 0], q[k, 1])[1] == pytest.approx(d, rel=1e-12)
