"""The CFD path (vesselbot_ros.vessels.cfd): small solves from scratch, validated against theory."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vesselbot_ros.config import load_dataclass
from vesselbot_ros.physics.params import BloodParams
from vesselbot_ros.vessels import cfd
from vesselbot_ros.vessels.network import FlowPresetParams, VesselNetworkParams, with_flow_preset

CFD = {"inlet_centreline_velocity_m_per_s": 0.025, "mesh_size_m": 4e-4, "grid_spacing_m": 5e-5, "grid_margin_m": 1e-4}


def _straight() -> VesselNetworkParams:
    return load_dataclass(VesselNetworkParams, {"name": "s", "cfd": CFD, "branches": [
        {"name": "a", "parent": "", "x_m": [0.0, 8e-3], "z_m": [0.0, 0.0], "radius_m": [1.5e-3]}]}, "")


def _bifurcation() -> VesselNetworkParams:
    return load_dataclass(VesselNetworkParams, {"name": "y", "cfd": CFD, "branches": [
        {"name": "a", "parent": "", "x_m": [0.0, 4e-3], "z_m": [0.0, 0.0], "radius_m": [1.5e-3]},
        {"name": "b", "parent": "a", "x_m": [4e-3, 9e-3], "z_m": [0.0, 2.9e-3], "radius_m": [1.19e-3]},
        {"name": "c", "parent": "a", "x_m": [4e-3, 9e-3], "z_m": [0.0, -2.9e-3], "radius_m": [0.9e-3]}]}, "")


@pytest.fixture(scope="module")
def straight_field(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    import os

    old = os.environ.get("VESSELBOT_CFD_CACHE")
    os.environ["VESSELBOT_CFD_CACHE"] = str(tmp_path_factory.mktemp("cfd"))
    try:
        yield cfd.network_field(_straight(), BloodParams())
    finally:
        if old is None:
            os.environ.pop("VESSELBOT_CFD_CACHE")
        else:
            os.environ["VESSELBOT_CFD_CACHE"] = old


def test_straight_vessel_profile_is_the_analytic_parabola_within_1_percent(straight_field) -> None:  # type: ignore[no-untyped-def]
    f = straight_field
    x, z = f.grid()
    vx = f.field("vx")
    for xc in (1e-3, 4e-3, 7.5e-3):  # near the inlet, mid-vessel, near the outlet
        i = int(np.argmin(np.abs(x - xc)))
        inside = np.abs(z) < 1.5e-3
        err = np.abs(vx[inside, i] - (1.0 - (z[inside] / 1.5e-3) ** 2))
        assert err.max() < 0.01, (xc, err.max())
    np.testing.assert_allclose(f.field("vz")[np.abs(z) < 1.5e-3], 0.0, atol=1e-3)
    # geometry fields: signed distance, normal and diameter of the tube
    j = np.abs(z) < 1.4e-3
    i = int(np.argmin(np.abs(x - 4e-3)))
    np.testing.assert_allclose(f.field("sdist")[j, i], 1.5e-3 - np.abs(z[j]), atol=1e-9)
    np.testing.assert_allclose(f.field("diameter")[j, i], 3e-3, rtol=1e-6)


def test_cache_is_keyed_by_geometry_and_blood_and_reused(straight_field, tmp_path) -> None:  # type: ignore[no-untyped-def]
    again = cfd.network_field(_straight(), BloodParams())  # same key: read from the cache, no solve
    np.testing.assert_array_equal(again.data, straight_field.data)
    assert cfd.field_key(_straight(), BloodParams()) != cfd.field_key(_straight(), BloodParams(hematocrit=0.3))
    net2 = load_dataclass(VesselNetworkParams, {"name": "s", "cfd": dict(CFD, mesh_size_m=3e-4), "branches": [
        {"name": "a", "parent": "", "x_m": [0.0, 8e-3], "z_m": [0.0, 0.0], "radius_m": [1.5e-3]}]}, "")
    assert cfd.field_key(net2, BloodParams()) != cfd.field_key(_straight(), BloodParams())


def _bilinear(f: cfd.NetworkField, name: str, q: np.ndarray) -> np.ndarray:
    """The kernel's bilinear lookup (kernel._grid_cell / _grid_value) of field ``name`` at points q (m, 2)."""
    fx, fz = (q[:, 0] - f.x0_m) / f.h_m, (q[:, 1] - f.z0_m) / f.h_m
    i = np.clip(np.floor(fx).astype(int), 0, f.nx - 2)
    j = np.clip(np.floor(fz).astype(int), 0, f.nz - 2)
    tx, tz = np.clip(fx - i, 0, 1), np.clip(fz - j, 0, 1)
    g = f.field(name)
    return (1 - tx) * (1 - tz) * g[j, i] + tx * (1 - tz) * g[j, i + 1] + (1 - tx) * tz * g[j + 1, i] + tx * tz * g[j + 1, i + 1]


def _sections(net: VesselNetworkParams) -> list[tuple[str, np.ndarray, np.ndarray, float, float]]:
    """(branch, centre (2,), unit tangent (2,), radius, Murray share of the inflow) of one interior cross-section per
    branch: mid-way between 1.5 parent radii after its start node and 1.5 radii before its end node (branches too
    short for that have none).  The share is the sum of r^3 / sum r^3 over the outlets downstream."""
    from vesselbot_ros.vessels.tube_geometry import NetworkGeometry

    g = NetworkGeometry(net)
    r_out = {o: max(next(b for b in net.branches if b.name == o).radius_m) for o in net.outlets}
    total = sum(r ** 3 for r in r_out.values())

    def downstream(name: str) -> list[str]:
        kids = net.children(name)
        return [name] if not kids else [o for k in kids for o in downstream(k.name)]

    out = []
    for b in net.branches:
        pts, rad, arc = g.branches[b.name]
        start = 1.5 * max(next(a for a in net.branches if a.name == b.parent).radius_m) if b.parent else 0.0
        end = arc[-1] - (1.5 * rad[-1] if net.children(b.name) else 0.0)
        if end - start < rad.max():
            continue
        i = int(np.searchsorted(arc, 0.5 * (start + end)))
        t = pts[i + 1] - pts[i - 1]
        out.append((b.name, pts[i], t / np.hypot(*t), float(rad[i]), sum(r_out[o] ** 3 for o in downstream(b.name)) / total))
    return out


def _flux(velocity, centre: np.ndarray, tang: np.ndarray, r: float, h: float) -> float:  # type: ignore[no-untyped-def]
    """Flux (per unit depth, velocity units x m) of ``velocity`` ((k, 2) -> (k, 2)) across the section through
    ``centre`` normal to ``tang``, wall to wall and two grid cells beyond (Gauss-Legendre, 200 points)."""
    x, w = np.polynomial.legendre.leggauss(200)
    half = r + 2.0 * h
    q = centre + np.outer(x * half, [-tang[1], tang[0]])
    return float((w * half) @ (velocity(q) @ tang))


def test_bifurcation_sampled_field_carries_the_inflow_through_every_branch_by_murray() -> None:
    """Mass conservation where it can fail: the flux of the *sampled* field the plant reads (bilinear on the grid)
    across interior sections of each branch, against the inlet flux and the Murray split.  (The flux balance of
    the outlets cannot fail: Taylor-Hood conserves the discrete flux by construction, 5e-13.)"""
    net = _bifurcation()
    sol = cfd.solve_flow(net, BloodParams())
    q_in = -sol.fluxes["inlet"]
    assert q_in == pytest.approx(4.0 / 3.0 * 0.025 * 1.5e-3, rel=1e-6)  # the parabolic inflow, integrated
    assert sol.picard_change < net.cfd.picard_tol
    f = cfd.sample_field(net, BloodParams(), sol)
    secs = _sections(net)
    assert [s[0] for s in secs] == ["a", "b", "c"]
    for name, c, t, r, share in secs:
        q = _flux(lambda p: np.column_stack([_bilinear(f, "vx", p), _bilinear(f, "vz", p)]), c, t, r, f.h_m)
        assert q / (4.0 / 3.0 * r_in(net)) == pytest.approx(share, rel=0.01), name


def r_in(net: VesselNetworkParams) -> float:
    """Inlet radius (m)."""
    return float(net.root.radius_m[0])


@pytest.mark.parametrize("network", ["paper_iiic_artery", "small_artery_4gen", "straight_table3"])
def test_shipped_networks_sampled_flow_carries_the_inflow_through_every_branch_by_murray(network: str) -> None:
    """The same through the kernel's packed parameters (what the plant integrates), steady flow, every branch."""
    import dataclasses

    from vesselbot_ros.physics import kernel
    from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios
    from vesselbot_ros.vessels.network import load_network

    ph = load_scenario(shipped_scenarios()["paper_iiic_network_upper"]).physics
    ph = dataclasses.replace(ph, vessel=dataclasses.replace(ph.vessel, network=network),
                             flow=dataclasses.replace(ph.flow, pulsatility=0.0, diameter_pulsation=0.0))
    p = cfd.packed_params(ph)
    vf = ph.flow.centreline_velocity_m_per_s
    net = load_network(network)

    def velocity(q: np.ndarray) -> np.ndarray:
        return np.array([kernel.fluid_velocity_xz(0.0, x, z, p) for x, z in q]) / vf

    secs = _sections(net)
    assert len(secs) >= min(3, len(net.branches))
    for name, c, t, r, share in secs:
        q = _flux(velocity, c, t, r, net.cfd.grid_spacing_m)
        assert q / (4.0 / 3.0 * r_in(net)) == pytest.approx(share, rel=0.005), name


def test_womersley_numbers_of_the_iii_c_network() -> None:
    from vesselbot_ros.vessels.network import load_network

    a = cfd.womersley_numbers(load_network("paper_iiic_artery"), BloodParams(), 2 * np.pi)
    # alpha = R sqrt(omega rho / eta), eta = Pries at 5 mPa s plasma: ~16 mPa s (docs/vessels.md)
    assert a["trunk_a"] == pytest.approx(0.97, abs=0.01)
    assert a["upper"] == pytest.approx(0.77, abs=0.01)
    assert a["side_up"] == pytest.approx(0.23, abs=0.01)


def test_every_shipped_network_scenario_runs_on_a_shipped_field() -> None:
    """The shipped scenarios' fields are in config/cfd under their current key (else each machine would solve
    its own, and a run touching the walls would differ between CPUs), and nothing else is."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("ship_cfd_fields", Path(__file__).parents[3] / "tools" / "ship_cfd_fields.py")
    tool = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(tool)  # type: ignore[union-attr]
    wanted = tool.shipped_networks()
    assert {n.split("-")[0] for n in wanted} == {"paper_iiic_artery", "small_artery_4gen"}
    planar = [p.name for p in cfd.shipped_field_dir().glob("*.npz") if not p.name.endswith(".3d.npz")]
    assert sorted(planar) == sorted(wanted)
    trees = [p.name for p in cfd.shipped_field_dir().glob("*.3d.npz")]  # the 3-D trees' samples (test_tree_field.py)
    assert sorted(trees) == sorted(tool.shipped_networks(three_d=True))
    for name in wanted:
        f = cfd.NetworkField.load(cfd.shipped_field_dir() / name)
        assert f.data.shape == (len(cfd.FIELD_NAMES), f.nz, f.nx) and np.isfinite(f.data).all()


def test_the_shipped_field_is_what_the_solve_gives(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The III-C network solved here (another CPU: other last bits) against its shipped field, and the shipped
    field is what network_field returns even with an empty cache."""
    from vesselbot_ros.vessels.network import load_network

    monkeypatch.setenv("VESSELBOT_CFD_CACHE", str(tmp_path))
    net, blood = load_network("paper_iiic_artery"), BloodParams()
    shipped = cfd.NetworkField.load(cfd.shipped_field_dir() / cfd.field_file(net, blood))
    np.testing.assert_array_equal(cfd.network_field(net, blood).data, shipped.data)
    assert not list(tmp_path.iterdir())  # nothing solved, nothing cached
    solved = cfd.network_field(net, blood, refresh=True)
    assert (solved.nx, solved.nz, solved.x0_m, solved.z0_m, solved.h_m) == (shipped.nx, shipped.nz, shipped.x0_m,
                                                                             shipped.z0_m, shipped.h_m)
    for i, name in enumerate(cfd.FIELD_NAMES):  # velocities normalised to 1, lengths in m, viscosity in Pa s
        scale = max(1.0, float(np.abs(shipped.data[i]).max()))
        np.testing.assert_allclose(solved.data[i], shipped.data[i], rtol=0, atol=1e-9 * scale, err_msg=name)


def test_a_flow_presets_outlet_shares_are_what_the_2d_solve_imposes() -> None:
    """``physics.flow.preset`` with outlet shares solves the network with ``cfd.outlet_split: shares``: the fixed
    outlet carries its share of the 2-D inflow, the traction-free (widest) one the rest, whatever Murray says."""
    net = with_flow_preset(dataclasses.replace(_bifurcation(), flow_presets=(FlowPresetParams(
        name="p", source="test", mean_velocity_m_per_s=0.1, heart_rate_per_min=60.0, pulsatility=1.0,
        outlets=("b", "c"), outlet_shares=(0.45, 0.55)),)), "p")
    assert net.cfd.outlet_split == "shares"
    sol = cfd.solve_flow(net, BloodParams())
    q_in = -sol.fluxes["inlet"]
    assert sol.fluxes["outlet:c"] / q_in == pytest.approx(0.55, rel=1e-6)  # imposed (Murray: 0.30)
    assert sol.fluxes["outlet:b"] / q_in == pytest.approx(0.45, rel=1e-6)  # the free outlet takes the rest
