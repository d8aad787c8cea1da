"""The 3-D plant's samples of a tree (vesselbot_ros.vessels.plant_field3d): shipped, keyed, the wall without its
caps, the flow normalised to the inlet and zero outside, the packed inputs."""

from __future__ import annotations

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.physics.params import BloodParams
from vesselbot_ros.physics.wall_field3d import field_points3d
from vesselbot_ros.vessels import plant_field3d as pf
from vesselbot_ros.vessels.network import NetworkGeometry3D, load_network

TREES = ("paper_iiic_artery_3d", "carotid_bifurcation_3d", "synthetic_tree_3d")


@pytest.mark.parametrize("name", TREES)
def test_every_shipped_tree_ships_its_samples(name: str) -> None:
    net = load_network(f"config/vessels/{name}.yaml")
    path = pf.shipped_dir() / f"{name}-{pf.field_key(net, BloodParams())}.3d.npz"
    assert path.is_file(), f"{path} missing: run the tree once and copy its samples from the cache"
    fld = pf.PlantField3D.load(path)
    assert fld.key == pf.field_key(net, BloodParams()) and fld.h == pf.grid_spacing_m(net)
    assert fld.velocity.shape == (fld.shape[2], fld.shape[1], fld.shape[0], 3)
    # the wall: no triangle on a cap, every vertex on its branch's tube (the mesh's resolution aside)
    cen = fld.vertices[fld.triangles].mean(axis=1)
    for c, n, r in fld.caps.values():
        assert np.min(np.abs((cen - c) @ n)) > 1e-4 * r
    sd = NetworkGeometry3D(net).query(fld.vertices)["sdist"]
    assert np.max(np.abs(sd)) < 0.15e-3  # fillets at the junctions, facets elsewhere


def test_the_flow_is_normalised_to_the_inlet_and_zero_outside() -> None:
    net = load_network("config/vessels/paper_iiic_artery_3d.yaml")
    fld = pf.plant_field(net)
    nx, ny, nz = fld.shape
    o, h = fld.origin, fld.h
    i, j, k = (int(round((v - o[a]) / h)) for a, v in enumerate((-1.5e-3, 0.0, 0.0)))  # the inlet branch's axis
    assert fld.velocity[k, j, i, 0] == pytest.approx(1.0, abs=0.05)
    wa = pf.wall_arrays(net)
    pts = np.stack(np.meshgrid(o[0] + h * np.arange(nx), o[1] + h * np.arange(ny), o[2] + h * np.arange(nz),
                               indexing="ij"), axis=-1).transpose(2, 1, 0, 3).reshape(-1, 3)
    s = field_points3d(np.ascontiguousarray(pts[::7]), *wa.args)[:, 0]
    v = np.linalg.norm(fld.velocity.reshape(-1, 3)[::7], axis=1)
    assert np.all(v[s < -2 * h] == 0.0)  # outside the mesh


def test_packed_inputs_and_refusals() -> None:
    from vesselbot_ros.sim.scenario import load_scenario  # deferred: the scenario module imports the stages

    sc = load_scenario("config/paper_iiic_network_upper_3d.yaml")
    k = pf.packed3d(sc.physics)
    assert k.F.dtype == np.float32 and k.F.shape[-1] == 4 and len(k.W) == 9
    eta = k.F[..., 3]
    assert 1e-3 < float(eta.min()) and float(eta.max()) < 0.02  # Pries' viscosity at the nodes' diameters
    with pytest.raises(ConfigError, match="gives no y_m"):
        pf.plant_field(load_network("config/vessels/paper_iiic_artery.yaml"))


def test_settings_follow_the_cfd_block() -> None:
    car = load_network("config/vessels/carotid_bifurcation_3d.yaml")
    st = pf.flow_settings(car)
    assert (st.mesh_size_m, st.wall_elements_per_circle, st.outlets) == (8.0e-4, 24, "murray")
    assert pf.grid_spacing_m(car) == 2.5e-4
    iiic = load_network("config/vessels/paper_iiic_artery_3d.yaml")
    assert pf.flow_settings(iiic).mesh_size_m == pytest.approx(1.2 * iiic.cfd.mesh_size_m)
    assert pf.grid_spacing_m(iiic) == pf.DEFAULT_SPACING_M
