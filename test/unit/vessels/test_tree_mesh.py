"""The solid and the wall surface of a vessel tree (vesselbot_ros.vessels.tree_mesh): the network adapter, one
lumen or a ConfigError, volumes, the wall's sag, the shipped and imported trees."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.vessels import tree_mesh
from vesselbot_ros.vessels.network import load_network

R, L = 1.5e-3, 6e-3


def _tube() -> tree_mesh.Tree3D:
    return tree_mesh.Tree3D("tube", (tree_mesh.Branch3D("a", "", ((0.0, 0.0, 0.0), (L, 0.0, 0.0)), (R,)),))


def test_network_adapter_puts_the_planar_network_in_y_0() -> None:
    net = load_network("paper_iiic_artery")
    tree = tree_mesh.tree_from_network(net)
    assert [b.name for b in tree.branches] == [b.name for b in net.branches]
    for b3, b in zip(tree.branches, net.branches):
        p = b3.points()
        np.testing.assert_allclose(p[:, 1], 0.0)
        np.testing.assert_allclose(p[[0, -1]][:, [0, 2]], [[b.x_m[0], b.z_m[0]], [b.x_m[-1], b.z_m[-1]]], atol=1e-12)
        assert b3.parent == b.parent and b3.radius_m == (b.radius_m[0],)
    assert tree.outlets == net.outlets


def test_tree_gmsh_cannot_fuse_into_one_lumen_is_a_config_error() -> None:
    tree = tree_mesh.Tree3D("apart", (tree_mesh.Branch3D("a", "", ((0, 0, 0), (4e-3, 0, 0)), (1e-3,)),
                                  tree_mesh.Branch3D("b", "a", ((8e-3, 0, 0), (12e-3, 0, 0)), (1e-3,))))
    with pytest.raises(ConfigError, match=r"'apart'.*2 volumes"):
        tree_mesh.mesh_tree(tree, 1e-3, 12)


def _volume_m3(ms: tree_mesh.Meshed3D) -> float:
    a, b, c, d = (ms.points[ms.tets[:, i]] for i in range(4))
    return float(np.sum(np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)) / 6.0)


def test_tapered_and_curved_branches_mesh_to_their_volume() -> None:
    st = (5e-4, 24)  # mesh size (m), elements per circle
    cone = tree_mesh.Tree3D("cone", (tree_mesh.Branch3D("a", "", ((0, 0, 0), (6e-3, 0, 0)), (1.5e-3, 1.0e-3)),))
    th = np.linspace(0.0, np.pi / 2, 6)
    arc = tuple((5e-3 * math.sin(t), 0.0, 5e-3 * (1 - math.cos(t))) for t in th)
    bend = tree_mesh.Tree3D("bend", (tree_mesh.Branch3D("a", "", arc, (1e-3,)),))
    # the polygonal section is short of the circle by (2 pi / 24)^2 / 6 = 1.1 %
    v_cone = math.pi * 6e-3 * (1.5e-3 ** 2 + 1.5e-3 * 1.0e-3 + 1.0e-3 ** 2) / 3
    assert _volume_m3(tree_mesh.mesh_tree(cone, *st)) == pytest.approx(v_cone, rel=0.02)
    v_bend = math.pi * 1e-3 ** 2 * 5e-3 * math.pi / 2
    assert _volume_m3(tree_mesh.mesh_tree(bend, *st)) == pytest.approx(v_bend, rel=0.02)
    # a non-planar Y: fused into one lumen with its three caps
    y3 = tree_mesh.Tree3D("y3", (
        tree_mesh.Branch3D("p", "", ((0, 0, 0), (3e-3, 0, 0)), (1.2e-3,)),
        tree_mesh.Branch3D("d1", "p", ((3e-3, 0, 0), (5e-3, 1e-3, 1e-3), (7e-3, 2e-3, 1.5e-3), (9e-3, 3e-3, 1.5e-3)), (0.9e-3,)),
        tree_mesh.Branch3D("d2", "p", ((3e-3, 0, 0), (6e-3, -1e-3, -1.5e-3)), (0.8e-3,))))
    ms = tree_mesh.mesh_tree(y3, *st)
    assert sorted(ms.boundaries) == ["inlet", "outlet:d1", "outlet:d2", "wall"]
    for name, (centre, normal, r) in ms.caps.items():
        tri = ms.points[ms.boundaries[name]]  # (k, 3, 3): every cap vertex in the cap's plane, within its circle
        np.testing.assert_allclose((tri - centre) @ normal, 0.0, atol=1e-9)
        assert np.linalg.norm(tri - centre, axis=2).max() <= r * (1 + 1e-9)


def test_the_wall_alone_is_meshed_to_its_sag_without_its_caps() -> None:
    """mesh_wall: the solid's surface, caps left out (every boundary edge on a cap's rim), vertices on the
    cylinder, facets sagging about the target (0.5 um here, 67 um triangles on 1.5 mm); the caps' normals."""
    wm = tree_mesh.mesh_wall(_tube(), sag_m=0.5e-6)
    v, t = wm.vertices, wm.triangles
    rho = np.hypot(v[:, 1], v[:, 2])
    assert np.abs(rho - R).max() < 1e-9 * L  # on the CAD surface
    cen = v[t].mean(axis=1)
    sag = R - np.hypot(cen[:, 1], cen[:, 2])
    assert 0.2e-6 < np.percentile(sag, 99) < 0.6e-6 and sag.max() < 1.0e-6
    assert wm.meta["sag_max_um"] == pytest.approx(sag.max() * 1e6, rel=0.05)
    assert sorted(wm.caps) == ["inlet", "outlet:a"]
    np.testing.assert_allclose(wm.caps["inlet"][1], [-1.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(wm.caps["outlet:a"][1], [1.0, 0.0, 0.0], atol=1e-9)
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    key = np.sort(e, axis=1)
    _u, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    rim = np.unique(key[cnt[inv.ravel()] == 1])
    assert np.isin(np.round(v[rim, 0] / L, 9), [0.0, 1.0]).all()  # boundary edges only at the two ends
    assert (cen[:, 0] > 1e-9).all() and (cen[:, 0] < L - 1e-9).all()  # no cap triangle
    assert cnt.max() == 2


def test_a_shipped_non_planar_tree_with_a_sinus_meshes_into_one_lumen() -> None:
    net = load_network("carotid_bifurcation_3d")
    tree = tree_mesh.tree_from_network(net)
    ica = next(b for b in tree.branches if b.name == "ica")
    assert len(ica.radius_m) > 1 and max(ica.radius_m) == pytest.approx(4.4e-3)  # the sinus profile is kept
    ms = tree_mesh.mesh_tree(tree, 1.5e-3, 16)
    assert sorted(ms.boundaries) == ["inlet", "outlet:eca", "outlet:ica", "wall"]
    assert ms.caps["outlet:ica"][2] == pytest.approx(2.8e-3)


def _contains(ms: tree_mesh.Meshed3D, q: np.ndarray) -> bool:
    """True if a tetrahedron of the mesh holds the point q (3,)."""
    P = ms.points[ms.tets]  # (t, 4, 3)
    T = np.transpose(P[:, 1:] - P[:, :1], (0, 2, 1))
    lam = np.linalg.solve(T, (q - P[:, 0])[..., None])[..., 0]
    return bool(((lam >= -1e-9).all(axis=1) & (lam.sum(axis=1) <= 1 + 1e-9)).any())


def test_the_imported_synthetic_tree_meshes_into_one_lumen() -> None:
    net = load_network("synthetic_tree_3d")
    tree = tree_mesh.tree_from_network(net)
    assert all(len(b.radius_m) == 1 for b in tree.branches)  # the importer's junction rule: no flared starts
    ms = tree_mesh.mesh_tree(tree, 1.5e-3, 12)
    assert sorted(ms.boundaries) == sorted(["inlet", "wall", *(f"outlet:{n}" for n in net.outlets)])
    for b in tree.branches:  # no tube lost in the union
        p = b.points()
        assert _contains(ms, p[len(p) // 2]), b.name
    for name, (centre, normal, r) in ms.caps.items():
        tri = ms.points[ms.boundaries[name]]
        np.testing.assert_allclose((tri - centre) @ normal, 0.0, atol=1e-9)
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
        assert area == pytest.approx(math.pi * r * r, rel=0.06), name  # 12 per circle: 4.6 % short
