"""VMTK centreline files in, network YAML out (vesselbot_ros.vessels.tree_io, `vesselbot vessels import`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vesselbot_ros.cli import main
from vesselbot_ros.config import ConfigError
from vesselbot_ros.vessels.network import load_network
from vesselbot_ros.vessels.tree_io import (
    import_vmtk_centerlines,
    network_mapping_from_paths,
    read_vmtk_centerlines,
    write_network_yaml,
    write_vmtk_centerlines,
)
from vesselbot_ros.vessels.tube_geometry import NetworkGeometry


def _seg(a, b, n):  # type: ignore[no-untyped-def]
    t = np.linspace(0.0, 1.0, n)[:, None]
    return np.asarray(a, float) + (np.asarray(b, float) - np.asarray(a, float)) * t


# a 3-generation tree in mm: trunk (r 1.5) to N1, two daughters (r 1.2), the first one splitting again (r 0.9)
N0, N1, A, B = (0.0, 0.0, 0.0), (10.0, 0.0, 0.0), (20.0, 5.0, 2.0), (20.0, -5.0, -2.0)
A1, A2 = (30.0, 12.0, 6.0), (30.0, 5.0, -6.0)
TRUNK = (_seg(N0, N1, 51), np.full(51, 1.5))
PIECES = {"a": (_seg(N1, A, 41)[1:], np.full(40, 1.2)), "b": (_seg(N1, B, 41)[1:], np.full(40, 1.2)),
          "a1": (_seg(A, A1, 41)[1:], np.full(40, 0.9)), "a2": (_seg(A, A2, 41)[1:], np.full(40, 0.9))}


def _path(*names):  # type: ignore[no-untyped-def]
    parts = [TRUNK] + [PIECES[n] for n in names]
    return np.vstack([p for p, _r in parts]), np.concatenate([r for _p, r in parts])


RAW = [_path("a", "a1"), _path("a", "a2"), _path("b")]


def _check_tree(net, names, nodes=(N1, A)) -> None:  # type: ignore[no-untyped-def]
    """The imported tree is the one drawn above (in metres), with the given branch names and nodes."""
    root, a, a1, a2, b = names
    by = {br.name: br for br in net.branches}
    assert set(by) == set(names)
    assert by[root].parent == "" and by[a].parent == root and by[b].parent == root
    assert by[a1].parent == a and by[a2].parent == a
    for name, end, r in ((root, nodes[0], 1.5), (a, nodes[1], 1.2), (b, B, 1.2), (a1, A1, 0.9), (a2, A2, 0.9)):
        p = by[name].points_3d()
        np.testing.assert_allclose(p[-1], np.asarray(end) * 1e-3, atol=1e-9)
        assert by[name].radius_m[-1] == pytest.approx(r * 1e-3, abs=1e-12)
    assert not net.is_planar


def test_raw_vmtk_paths_split_where_they_part(tmp_path: Path) -> None:
    f = tmp_path / "tree.vtp"
    write_vmtk_centerlines(RAW, f)
    net = import_vmtk_centerlines(f)
    assert net.name == "tree"
    _check_tree(net, ("b0", "b0_0", "b0_0_0", "b0_0_1", "b0_1"))
    # the shared trunk is one branch of the 51 points, the node exactly at 10 mm
    assert len(net.root.x_m) == 51 and net.root.y_m == () and net.root.x_m[-1] == 0.01
    # lengths (m) of the smoothed centrelines: straight segments, so the chords
    g = NetworkGeometry(net, dims=3)
    assert g.length_m("b0") == pytest.approx(0.010, rel=1e-9)
    assert g.length_m("b0_0") == pytest.approx(np.linalg.norm(np.subtract(A, N1)) * 1e-3, rel=1e-9)


def test_reversed_paths_and_path_order_import_the_same_tree(tmp_path: Path) -> None:
    write_vmtk_centerlines(RAW, tmp_path / "t.vtp")
    write_vmtk_centerlines([(p[::-1], r[::-1]) for p, r in RAW], tmp_path / "r.vtp")
    assert import_vmtk_centerlines(tmp_path / "r.vtp", name="t") == import_vmtk_centerlines(tmp_path / "t.vtp")


def test_branch_split_form(tmp_path: Path) -> None:
    # vmtkbranchextractor: tracts of each centreline, bifurcation zones blanked (groups 1 and 3)
    def cut(p, r, lo, hi):  # type: ignore[no-untyped-def]
        return p[lo:hi + 1], r[lo:hi + 1]

    tracts, cid, tid, gid, blank = [], [], [], [], []
    for c, (path, groups) in enumerate(zip(RAW, ([0, 1, 2, 3, 4], [0, 1, 2, 3, 5], [0, 1, 6]), strict=True)):
        p, r = path
        cuts = [0, 46, 54, 86, 94, len(p) - 1][:len(groups) + 1]
        cuts[-1] = len(p) - 1
        for t, g in enumerate(groups):
            tracts.append(cut(p, r, cuts[t], cuts[t + 1]))
            cid.append(c)
            tid.append(t)
            gid.append(g)
            blank.append(int(g in (1, 3)))
    f = tmp_path / "split.vtp"
    write_vmtk_centerlines(tracts, f, {"CenterlineIds": cid, "TractIds": tid, "GroupIds": gid, "Blanking": blank})
    assert read_vmtk_centerlines(f).branch_split
    net = import_vmtk_centerlines(f)
    # a group ends where its bifurcation's blanked zone starts (points 46 and 86 of the paths)
    _check_tree(net, ("g0", "g2", "g4", "g5", "g6"), nodes=(RAW[0][0][46], RAW[0][0][86]))
    # the daughters run through the blanked zone from their parent's end
    by = {b.name: b for b in net.branches}
    assert by["g2"].points_3d()[0].tolist() == by["g0"].points_3d()[-1].tolist()
    # ... with their own radius through it (the parent's radius there is the junction's, not theirs)
    assert set(by["g2"].radius_m) == set(by["g6"].radius_m) == {1.2e-3}
    assert set(by["g4"].radius_m) == set(by["g5"].radius_m) == {0.9e-3}


def test_written_yaml_reloads_to_the_same_network(tmp_path: Path) -> None:
    write_vmtk_centerlines(RAW, tmp_path / "t.vtp")
    net = import_vmtk_centerlines(tmp_path / "t.vtp")
    write_network_yaml(net, tmp_path / "t.yaml", header="a tree\nof three generations")
    text = (tmp_path / "t.yaml").read_text()
    assert text.startswith("# a tree\n# of three generations\nname: t\n")
    assert load_network(str(tmp_path / "t.yaml")) == net


@pytest.mark.parametrize(("content", "cause"), [
    (None, "no such file"),
    (b"not xml at all", "not a VTK XML PolyData file"),
    (b"<?xml version='1.0'?><VTKFile type='PolyData' version='1.0'><PolyData>",
     "VTK could not parse it: Error parsing XML in stream at line 1, column 70"),
])
def test_unreadable_files_are_one_line_errors(tmp_path: Path, content: bytes | None, cause: str) -> None:
    f = tmp_path / "bad.vtp"
    if content is not None:
        f.write_bytes(content)
    with pytest.raises(ConfigError, match=f"^VMTK centreline file '{f}': {cause}") as ei:
        import_vmtk_centerlines(f)
    assert "\n" not in str(ei.value)


def test_no_lines_or_no_radii_are_errors(tmp_path: Path) -> None:
    from vtkmodules.vtkFiltersSources import vtkSphereSource
    from vtkmodules.vtkIOXML import vtkXMLPolyDataWriter

    s = vtkSphereSource()
    s.Update()
    w = vtkXMLPolyDataWriter()
    w.SetFileName(str(tmp_path / "surface.vtp"))
    w.SetInputData(s.GetOutput())
    w.Write()
    with pytest.raises(ConfigError, match=r"surface.vtp': holds no polylines \(50 points, 96 polygons\)"):
        import_vmtk_centerlines(tmp_path / "surface.vtp")
    write_vmtk_centerlines(RAW, tmp_path / "t.vtp")
    with pytest.raises(ConfigError, match=r"t.vtp': has no point array 'Radius' of radii; point arrays: "
                                          r"\['MaximumInscribedSphereRadius'\]"):
        import_vmtk_centerlines(tmp_path / "t.vtp", radius_array="Radius")
    p, r = RAW[2]
    write_vmtk_centerlines([RAW[0], (p, np.where(np.arange(len(r)) == 7, -0.1, r))], tmp_path / "neg.vtp")
    with pytest.raises(ConfigError, match=r"neg.vtp': MaximumInscribedSphereRadius\[138\] \(line 1, point 7\) must "
                                          r"be > 0, got -0.1"):
        import_vmtk_centerlines(tmp_path / "neg.vtp")


def test_a_tree_the_network_refuses_names_the_file(tmp_path: Path) -> None:
    # two outlets side by side 1 mm apart (the second path's daughter moved 1 mm along z), radii 1.2 mm: they overlap
    p, r = RAW[2]
    twin = (np.vstack([p[:51], p[51:] + [0.0, 0.0, 1.0]]), r)
    write_vmtk_centerlines([RAW[2], twin], tmp_path / "twin.vtp")
    with pytest.raises(ConfigError, match=r"^VMTK centreline file '.*twin.vtp': branches 'b0_0' and 'b0_1' overlap"):
        import_vmtk_centerlines(tmp_path / "twin.vtp")


def test_cli_import_writes_the_yaml_or_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_vmtk_centerlines(RAW, tmp_path / "t.vtp")
    out = tmp_path / "my_tree.yaml"
    assert main(["vessels", "import", str(tmp_path / "t.vtp"), "--out", str(out)]) == 0
    assert "network 'my_tree', 5 branches (3 outlets), 3-D" in capsys.readouterr().out
    assert load_network(str(out)).name == "my_tree"
    (tmp_path / "junk.vtp").write_text("junk")
    bad = tmp_path / "bad.yaml"
    assert main(["vessels", "import", str(tmp_path / "junk.vtp"), "--out", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("vesselbot vessels: error: VMTK centreline file") and "junk.vtp" in err[0]
    assert not bad.exists() and not list(tmp_path.glob(".bad.yaml*"))


@settings(max_examples=25, deadline=None)
@given(angle=st.floats(20.0, 70.0), length=st.floats(4.0, 12.0), rot=st.floats(0.0, 2.0 * np.pi),
       step=st.sampled_from([0.1, 0.25, 0.5]))
def test_symmetric_bifurcation_splits_at_its_node(angle: float, length: float, rot: float, step: float) -> None:
    # a trunk along x and two daughters at +/- angle in a plane turned by rot about x, sampled every step mm
    r0, r1 = 1.0, 0.79
    n0 = int(round(8.0 / step)) + 1
    trunk = _seg((0.0, 0.0, 0.0), (8.0, 0.0, 0.0), n0)
    paths = []
    for sgn in (1.0, -1.0):
        a = np.radians(angle) * sgn
        d = np.array([np.cos(a), -np.sin(a) * np.sin(rot), np.sin(a) * np.cos(rot)])
        n1 = int(round(length / step)) + 1
        dau = _seg((8.0, 0.0, 0.0), np.array([8.0, 0.0, 0.0]) + length * d, n1)[1:]
        paths.append((np.vstack([trunk, dau]) * 1e-3, np.concatenate([np.full(n0, r0), np.full(n1 - 1, r1)]) * 1e-3))
    m = network_mapping_from_paths(paths, "y")
    names = [b["name"] for b in m["branches"]]
    assert names == ["b0", "b0_0", "b0_1"]
    assert m["branches"][0]["x_m"][-1] == pytest.approx(8e-3, abs=1e-12)  # the node is the true one
    for b, (p, _r) in zip(m["branches"][1:], paths, strict=True):
        np.testing.assert_allclose([b["x_m"][-1], b["y_m"][-1], b["z_m"][-1]], p[-1], atol=1e-12)


def test_shipped_synthetic_tree_is_its_vtp_imported() -> None:
    root = Path(__file__).resolve().parents[3]
    vtp = root / "config" / "vessels" / "sources" / "synthetic_tree_3d.vtp"
    shipped = load_network(str(root / "config" / "vessels" / "synthetic_tree_3d.yaml"))
    imported = import_vmtk_centerlines(vtp, name="synthetic_tree_3d")
    assert imported == dataclasses.replace(shipped, cfd=imported.cfd, flow_presets=())  # the tool adds the 3-D solve's mesh
    assert shipped.flow_presets  # and the small arteries' flow presets (tools/small_artery_flow_presets.py)
    assert (shipped.cfd.mesh_size_3d_m, shipped.cfd.wall_elements_per_circle_3d) == (3.0e-4, 24)
    f = read_vmtk_centerlines(vtp)
    assert len(f.lines) == 8 and not f.branch_split  # the raw form: one path per outlet


def test_the_generator_writes_the_shipped_files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import importlib.util
    import sys

    root = Path(__file__).resolve().parents[3]
    spec = importlib.util.spec_from_file_location("make_synthetic_tree_3d", root / "tools" / "make_synthetic_tree_3d.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "make_synthetic_tree_3d", mod)
    spec.loader.exec_module(mod)
    monkeypatch.setattr(mod, "VTP", tmp_path / "synthetic_tree_3d.vtp")
    monkeypatch.setattr(mod, "YAML", tmp_path / "synthetic_tree_3d.yaml")
    monkeypatch.setattr(mod, "ROOT", tmp_path)
    assert mod.main() == 0
    shipped = root / "config" / "vessels"
    assert (tmp_path / "synthetic_tree_3d.yaml").read_bytes() == (shipped / "synthetic_tree_3d.yaml").read_bytes()
    assert (tmp_path / "synthetic_tree_3d.vtp").read_bytes() == (shipped / "sources" / "synthetic_tree_3d.vtp").read_bytes()


def test_daughters_take_their_radius_from_beyond_the_junctions_sphere(tmp_path: Path) -> None:
    # as VMTK writes it: the inscribed sphere is inflated near the node (1.5 mm at N1, 1.2 mm from 2 mm on)
    def inflated(path):  # type: ignore[no-untyped-def]
        p, r = path
        d = np.linalg.norm(p - np.asarray(N1), axis=1)
        beyond_n1 = np.arange(len(p)) > 50
        return p, np.where(beyond_n1 & (d < 2.0), 1.5 - 0.15 * d, r)

    write_vmtk_centerlines([inflated(p) for p in RAW], tmp_path / "t.vtp")
    by = {b.name: b for b in import_vmtk_centerlines(tmp_path / "t.vtp").branches}
    for name in ("b0_0", "b0_1"):
        r = np.asarray(by[name].radius_m)
        p = by[name].points_3d()
        d = np.linalg.norm(p - p[0], axis=1)
        first_beyond = int(np.argmax(d >= 1.5e-3))  # the junction's sphere: the trunk's end radius
        assert r[0] == r[first_beyond] == pytest.approx(1.5e-3 - 0.15 * d[first_beyond], abs=1e-9)
        assert (r[:first_beyond] == r[first_beyond]).all() and r[-1] == pytest.approx(1.2e-3)
    assert by["b0"].radius_m == (1.5e-3,) * 51  # the parent keeps its radii
    kept = {b.name: b for b in import_vmtk_centerlines(tmp_path / "t.vtp", junction_factor=0.0).branches}
    assert kept["b0_0"].radius_m[0] == pytest.approx(1.5e-3) and kept["b0_0"].radius_m[1] > 1.4e-3
    # the same tree without inflation: a daughter starts at its own radius, not its parent's
    write_vmtk_centerlines(RAW, tmp_path / "plain.vtp")
    plain = {b.name: b for b in import_vmtk_centerlines(tmp_path / "plain.vtp").branches}
    assert set(plain["b0_0"].radius_m) == {1.2e-3} and set(plain["b0_0_0"].radius_m) == {0.9e-3}
    with pytest.raises(ConfigError, match=r"junction_factor must be in \[0, 10\], got -1.0"):
        import_vmtk_centerlines(tmp_path / "plain.vtp", junction_factor=-1.0)


# --- issue 38 section 3: a file in the wrong unit is refused at import, before any sample is made -------------


def _refused(proc, *fragments: str) -> str:  # type: ignore[no-untyped-def]
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-3000:])
    assert "Traceback" not in proc.stderr and "MemoryError" not in proc.stderr, proc.stderr[-3000:]
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    for f in fragments:
        assert f in lines[0], (f, lines[0])
    return str(lines[0])


def test_import_in_metres_of_a_file_in_mm_is_refused_in_one_line_within_a_memory_limit(tmp_path: Path) -> None:
    """``--unit-m 1`` on a file in mm: tubes metres wide along 40 m (the old importer went on to a 17.5 GiB
    array of sample pairs); refused naming the option, its value and the radii it gives, nothing written."""
    from vesselbot_ros.testing import cli_under_memory_limit

    write_vmtk_centerlines(RAW, tmp_path / "t.vtp")
    assert sum(len(p) for p, _r in RAW) == 353
    proc = cli_under_memory_limit(["vessels", "import", str(tmp_path / "t.vtp"), "--out", str(tmp_path / "t.yaml"),
                                   "--unit-m", "1"], timeout=60)
    _refused(proc, "t.vtp", "length_unit_m (--unit-m) = 1.0", "radii are 0.9 to 1.5 m", "1e-06 to 0.02 m")
    assert not (tmp_path / "t.yaml").exists()


def test_a_radius_of_1e6_mm_is_refused_at_import(tmp_path: Path) -> None:
    """The old importer accepted it (and ``simulate`` ended in a gmsh traceback)."""
    from vesselbot_ros.testing import cli_under_memory_limit

    p, r = RAW[2]
    write_vmtk_centerlines([(p, np.where(np.arange(len(r)) == 60, 1e6, r))], tmp_path / "huge.vtp")  # one path
    proc = cli_under_memory_limit(["vessels", "import", str(tmp_path / "huge.vtp"), "--out", str(tmp_path / "h.yaml")],
                                  timeout=60)
    _refused(proc, "huge.vtp", "radii are 0.0012 to 1e+03 m", "outside a blood vessel's 1e-06 to 0.02 m")
    assert not (tmp_path / "h.yaml").exists()
    write_vmtk_centerlines([(p, r / 100.0) for p, r in RAW], tmp_path / "thin.vtp")  # radii right in 0.1 m, not lengths
    with pytest.raises(ConfigError, match=r"thin\.vtp'?: with length_unit_m \(--unit-m\) = 0\.1 it spans 3 m, more than a "
                                          r"vessel tree's 1 m"):
        import_vmtk_centerlines(tmp_path / "thin.vtp", length_unit_m=0.1)


def test_the_importer_s_help_states_the_limits(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["vessels", "import", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "1 um to 20 mm" in text and "at most 1 m" in text and "MAX_RADIUS_M" in text


def test_a_file_too_large_to_read_is_refused_before_vtk_reads_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    write_vmtk_centerlines(RAW, tmp_path / "t.vtp")
    size = (tmp_path / "t.vtp").stat().st_size
    monkeypatch.setattr("vesselbot_ros.resources.memory_budget_bytes", lambda: 4 * size)  # less than 16 bytes a byte
    with pytest.raises(ConfigError, match=rf"^VMTK centreline file '.*t\.vtp'={size} bytes: reading it needs about "):
        read_vmtk_centerlines(tmp_path / "t.vtp")
