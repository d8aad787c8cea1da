"""The 3-D plant's samples of a tree (vesselbot_ros.vessels.tree_field): shipped, keyed, the wall without its
caps, the flow normalised to the inlet and zero outside, the packed inputs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.geometry.field_lookup import field_points3d
from vesselbot_ros.physics.params import BloodParams
from vesselbot_ros.vessels import tree_field as pf
from vesselbot_ros.vessels.network import load_network
from vesselbot_ros.vessels.tube_geometry import NetworkGeometry

TREES = ("paper_iiic_artery_3d", "carotid_bifurcation_3d", "synthetic_tree_3d")


@pytest.mark.parametrize("name", TREES)
def test_every_shipped_tree_ships_its_samples(name: str) -> None:
    net = load_network(f"config/vessels/{name}.yaml")
    path = pf.shipped_dir() / f"{name}-{pf.field_key(net, BloodParams())}.3d.npz"
    assert path.is_file(), f"{path} missing: run the tree once and copy its samples from the cache"
    fld = pf.TreeField.load(path)
    assert fld.key == pf.field_key(net, BloodParams()) and fld.h == pf.grid_spacing_m(net)
    assert fld.velocity.shape == (fld.shape[2], fld.shape[1], fld.shape[0], 3)
    # the plant's wall: no triangle on a cap, every vertex on its branch's tube (up to the junctions' creases),
    # facets sagging 0.5 um or so, 0.2-0.45 million of them; the view's wall: the flow mesh's, tens of thousands
    for v, t in ((fld.vertices, fld.triangles), (fld.view_vertices, fld.view_triangles)):
        cen = v[t].mean(axis=1)
        for c, n, r in fld.caps.values():  # in a cap's plane only a sliver of the tube between rim vertices
            in_plane = np.abs((cen - c) @ n) < 1e-4 * r
            assert (np.linalg.norm(cen[in_plane] - c, axis=1) > r * (1 - 1e-3)).all()
        sd = NetworkGeometry(net, dims=3).query(v)["sdist"]
        assert np.max(np.abs(sd)) < 0.15e-3  # the smoothed centrelines' tubes against the solid's (junctions)
    assert 2e5 < len(fld.triangles) < 5e5 and 5e3 < len(fld.view_triangles) < 3e4
    assert fld.meta["wall"]["sag_p99_um"] < 0.5 and fld.meta["wall"]["sag_max_um"] < 1.0
    assert path.stat().st_size < 7e6
    q = np.rint((fld.vertices - fld.origin) / 1e-9)  # on the file's 1 nm lattice
    np.testing.assert_allclose(fld.origin + 1e-9 * q, fld.vertices, rtol=0, atol=1e-15)


def test_the_wall_arrays_are_the_lookup_with_the_exact_query_pruned() -> None:
    """The cached wall arrays: the lookup's field and the exact query kept only where the lookup asks it (int32
    lists and nodes, a fraction of the triangles); the carotid's well under 200 MB."""
    net = load_network("config/vessels/carotid_bifurcation_3d.yaml")
    wa = pf.wall_arrays(net)
    assert len(wa.args) == 9 and wa.args[7].dtype == np.int32 and wa.args[8].dtype == np.int32
    assert sum(a.nbytes for a in wa.args) < 150e6
    assert wa.stats["exact_triangles"] < 0.5 * len(pf.plant_field(net).triangles)
    assert wa.stats["v"] == pf.WALL_VERSION


def test_the_wall_cache_is_mapped_and_an_earlier_single_file_is_taken_over(tmp_path, monkeypatch,  # type: ignore[no-untyped-def]
                                                                           capsys) -> None:
    """The cached lookup is a folder of arrays mapped copy-on-write (a run's processes share its pages; the
    kernels see ordinary writable arrays); the single ``.wall.npz`` an earlier version cached is taken over
    without a build; a folder missing a file is not read."""
    net = load_network("config/vessels/paper_iiic_artery_3d.yaml")
    wa = pf.wall_arrays(net)
    assert all(isinstance(a, np.memmap) and a.flags.writeable and a.flags.c_contiguous for a in wa.args)
    fld = pf.plant_field(net)
    monkeypatch.setenv("VESSELBOT_CFD_CACHE", str(tmp_path))
    path = pf.wall_cache_path(fld.name, fld.key)
    old = path.with_name(path.name + ".npz")
    old.parent.mkdir(parents=True)
    np.savez(old, stats=np.array(json.dumps(wa.stats)), **dict(zip(pf.WALL_NAMES, wa.args, strict=True)))
    pf.wall_arrays.cache_clear()
    try:
        moved = pf.wall_arrays(net)
        assert capsys.readouterr().err == ""  # nothing built
        assert not old.exists() and sorted(p.name for p in path.iterdir()) == sorted(
            [f"{n}.npy" for n in pf.WALL_NAMES] + ["stats.json"])
        assert moved.stats == wa.stats and all(isinstance(a, np.memmap) for a in moved.args)
        assert all(np.array_equal(a, b) and a.dtype == b.dtype for a, b in zip(moved.args, wa.args, strict=True))
        (path / "fine.npy").unlink()
        with pytest.raises(OSError):
            pf._read_wall(path)
    finally:
        pf.wall_arrays.cache_clear()


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
    k = pf.packed_tree(sc.physics)
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


# --- issue 38 section 3: a tree's wall and flow are estimated and bounded before anything is meshed -------------


def _own_tree(tmp_path, cfd: dict | None = None):  # type: ignore[no-untyped-def]
    """The carotid tree as a user's own file, with no ``cfd:`` block (or the given one)."""
    import yaml

    t = yaml.safe_load((pf.shipped_dir().parent / "vessels" / "carotid_bifurcation_3d.yaml").read_text())
    t.pop("cfd", None)
    t["name"] = "my_tree"
    if cfd is not None:
        t["cfd"] = cfd
    path = tmp_path / "my_tree.yaml"
    path.write_text(yaml.safe_dump(t))
    return path


def test_a_tree_without_a_cfd_block_is_refused_before_meshing_with_the_estimate(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The default fine mesh of a user's tree (the old `simulate` meshed and solved it for 290+ s and 5.9 GB, saying
    nothing): one line naming the key, its default and the estimate, exit 2, under a 3 GiB address space."""
    from vesselbot_ros.testing import cli_under_memory_limit

    tree = _own_tree(tmp_path)
    proc = cli_under_memory_limit(["simulate", "--config", "carotid_bifurcation_3d_eca", "--set",
                                   f"physics.vessel.network={tree}", "--out", str(tmp_path / "out")], timeout=120)
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr and "MemoryError" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "cfd.mesh_size_3d_m=0 (the default, 0.00012 m): the 3-D flow solve of tree 'my_tree'" in lines[0]
    assert "tetrahedra) needs about" in lines[0] and "GiB of memory" in lines[0]
    assert not (tmp_path / "out").exists()


def test_the_build_estimate_matches_the_shipped_trees_and_says_what_it_builds(tmp_path, monkeypatch,  # type: ignore[no-untyped-def]
                                                                             capsys) -> None:
    """The estimate against what the shipped trees' meshes have (their files' meta): within a factor 1.5."""
    for name in ("carotid_bifurcation_3d", "paper_iiic_artery_3d", "synthetic_tree_3d"):
        net = load_network(name)
        est = pf.build_estimate(net)
        fld = pf.plant_field(net)
        assert fld.meta["solve"]["n_tets"] / 1.5 < est.tets < 1.5 * fld.meta["solve"]["n_tets"]
        assert fld.meta["wall_triangles"] / 1.5 < est.triangles < 1.5 * fld.meta["wall_triangles"]
        assert fld.meta["nodes"] / 1.5 < est.nodes < 1.5 * fld.meta["nodes"]
    monkeypatch.setenv("VESSELBOT_CFD_CACHE", str(tmp_path / "cache"))
    carotid = load_network("carotid_bifurcation_3d")
    assert pf.check_build(carotid) is not None  # shipped samples, its wall field not yet built here: no solve
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("building the 3-D wall field of carotid_bifurcation_3d (about 1.8e+06 grid nodes, est. ")
    key = pf.field_key(carotid, BloodParams())
    wall = pf.wall_cache_path("carotid_bifurcation_3d", key)
    wall.mkdir(parents=True)
    (wall / "stats.json").write_text("{}")
    assert pf.check_build(carotid) is None  # nothing to build, nothing said
    assert capsys.readouterr().err == ""
    net = load_network(str(_own_tree(tmp_path, {"mesh_size_3d_m": 8e-4, "wall_elements_per_circle_3d": 24,
                                                "grid_spacing_3d_m": 2.5e-4})))
    monkeypatch.setattr("vesselbot_ros.resources.memory_budget_bytes", lambda: 64 * 2**30)
    est = pf.check_build(net)
    assert est is not None
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"meshing my_tree (about {est.tets:.3g} cells, {est.nodes:.3g} grid nodes, est. ")
    monkeypatch.setattr("vesselbot_ros.resources.memory_budget_bytes", lambda: 2**30)
    with pytest.raises(ConfigError, match=r"^cfd\.mesh_size_3d_m=0\.0008: the 3-D flow solve of tree 'my_tree' \(4\.92e\+04 "
                                          r"tetrahedra\) needs about 1\.5 GiB of memory, more than the 1\.0 GiB"):
        pf.check_build(net)


@pytest.mark.parametrize("name, point", [("paper_iiic_artery", (1e-3, 0.0)), ("paper_iiic_artery_3d", (1e-3, 2e-4, 0.0))])
def test_the_meshed_wall_is_one_query_on_the_networks_own_axes(name: str, point: tuple[float, ...]) -> None:
    """A planar network's wall and a tree's lookup answer the same two calls, on their own axes: ``clearance`` at a
    point is the ``query`` row there, and a point well inside is inside."""
    wall = pf.meshed_wall(load_network(f"config/vessels/{name}.yaml"))
    s, diameter = wall.clearance(*point)
    q = wall.query([point])
    assert q["normal"].shape == (1, len(point))
    assert s == q["sdist"][0] and diameter == q["diameter"][0]
    assert 0.0 < s <= diameter / 2 * (1.0 + 1e-6) and 1e-3 < diameter < 1e-2
