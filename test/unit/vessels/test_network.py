"""Vessel-network format, validation, centreline smoothing and loading (vesselbot_ros.vessels.network)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vesselbot_ros.config import ConfigError, load_dataclass
from vesselbot_ros.vessels.network import VesselNetworkParams, load_network, route_to_outlet, with_flow_preset
from vesselbot_ros.vessels.tube_geometry import NetworkGeometry


def _net(branches, **kw):  # type: ignore[no-untyped-def]
    return load_dataclass(VesselNetworkParams, {"name": "t", "branches": branches, **kw}, "")


Y = [
    {"name": "a", "parent": "", "x_m": [0.0, 5e-3], "z_m": [0.0, 0.0], "radius_m": [1e-3]},
    {"name": "b", "parent": "a", "x_m": [5e-3, 12e-3], "z_m": [0.0, 5e-3], "radius_m": [0.8e-3]},
    {"name": "c", "parent": "a", "x_m": [5e-3, 12e-3], "z_m": [0.0, -5e-3], "radius_m": [0.8e-3]},
]


def test_non_positive_radius_names_the_key_and_the_value() -> None:
    bad = [dict(Y[0], radius_m=[1e-3, -2e-4])]
    with pytest.raises(ConfigError, match=r"branches\[0\]\.radius_m\[1\] must be > 0, got -0\.0002"):
        _net(bad)


def test_unknown_key_and_missing_parent_are_errors() -> None:
    with pytest.raises(ConfigError, match="unknown key branches\\[0\\].diameter_m"):
        _net([dict(Y[0], diameter_m=1.0)])
    with pytest.raises(ConfigError, match="parent 'zz' is not a branch name"):
        _net([Y[0], dict(Y[1], parent="zz")])


def test_daughter_must_start_at_its_parents_end() -> None:
    with pytest.raises(ConfigError, match=r"branches\[1\] \('b'\) must start at the last point of its parent 'a'"):
        _net([Y[0], dict(Y[1], x_m=[5.5e-3, 12e-3])])


def test_overlapping_branches_are_named_with_where() -> None:
    # two siblings that run side by side 1 mm apart with radii summing to 1.6 mm
    close = [Y[0], dict(Y[1], x_m=[5e-3, 8e-3, 20e-3], z_m=[0.0, 0.5e-3, 0.5e-3]),
             dict(Y[2], x_m=[5e-3, 8e-3, 20e-3], z_m=[0.0, -0.5e-3, -0.5e-3])]
    with pytest.raises(ConfigError, match=r"branches 'b' and 'c' overlap near \(x, z\) = .* radii sum 0\.0016"):
        _net(close)
    _net(Y)  # the same daughters diverging are fine


def test_routes_over_the_tree() -> None:
    net = _net(Y)
    assert route_to_outlet(net, "c") == ["a", "c"]
    assert net.outlets == ["b", "c"]
    with pytest.raises(ConfigError, match="route outlet 'x'"):
        route_to_outlet(net, "x")


def test_shipped_networks_load() -> None:
    net = load_network("paper_iiic_artery")
    assert net.outlets == ["side_down", "side_up", "upper", "lower"]
    assert load_network("config/vessels/straight_table3.yaml").root.name == "trunk"


# --- three-dimensional trees (y_m) -----------------------------------------------------------------

def _rot_x(branches, theta):  # type: ignore[no-untyped-def]
    """The branches rotated by ``theta`` about the x axis: (y, z) = (-z sin, z cos) of the planar ones."""
    out = []
    for b in branches:
        z = np.asarray(b["z_m"], dtype=float)
        out.append(dict(b, y_m=(-z * np.sin(theta)).tolist(), z_m=(z * np.cos(theta)).tolist()))
    return out


def test_planar_networks_map_and_hash_as_before_y_m() -> None:
    from vesselbot_ros.config import to_mapping

    plain = _net(Y)
    zeros = _net([dict(b, y_m=[0.0] * len(b["x_m"])) for b in Y])
    assert plain.is_planar and zeros.is_planar
    assert all("y_m" not in b for b in to_mapping(plain)["branches"])
    assert all("y_m" not in b for b in to_mapping(zeros)["branches"])
    assert plain.geometry_hash() == zeros.geometry_hash()
    # a branch that leaves the plane is in the mapping, so in every hash
    tilted = _net(_rot_x(Y, 0.3))
    assert not tilted.is_planar
    assert any("y_m" in b for b in to_mapping(tilted)["branches"])
    assert tilted.geometry_hash() != plain.geometry_hash()


def test_shipped_cfd_fields_keep_their_names() -> None:
    from vesselbot_ros.physics.params import BloodParams
    from vesselbot_ros.vessels.cfd import field_file

    # the shipped fields (config/cfd) are named by field_key: y_m must not have moved them
    assert field_file(load_network("paper_iiic_artery"), BloodParams()) == "paper_iiic_artery-4ad5cdaaef7b33dc1ee13a11.npz"
    assert field_file(load_network("small_artery_4gen"), BloodParams()) == "small_artery_4gen-3366ae647ac05fd7c63f6ad9.npz"


def test_2d_consumers_refuse_a_non_planar_network_in_one_line() -> None:
    from vesselbot_ros.physics.params import BloodParams
    from vesselbot_ros.vessels.cfd import mesh_network, network_field

    net = _net(_rot_x(Y, 0.3))
    for call in (lambda: NetworkGeometry(net, dims=2), lambda: network_field(net, BloodParams()), lambda: mesh_network(net)):
        with pytest.raises(ConfigError, match=r"^vessel network 't' is not planar \(branch 'b' leaves the plane y = 0") as ei:
            call()
        assert "\n" not in str(ei.value)
    g = NetworkGeometry(net, dims=3)  # the 3-D geometry takes it
    assert g.centreline("b").shape[1] == 3 and not g.is_planar


def test_y_m_validation_names_the_key_and_the_value() -> None:
    with pytest.raises(ConfigError, match=r"branches\[0\]\.y_m must have as many points as x_m \(2\) or none .* got 3"):
        _net([dict(Y[0], y_m=[0.0, 1e-3, 2e-3])])
    with pytest.raises(ConfigError, match=r"branches\[0\]\.y_m\[1\] must be finite, got nan"):
        _net([dict(Y[0], y_m=[0.0, float("nan")])])
    # the same (x, z) at two heights y is two points in 3-D, a repeated (x, y, z) is not
    _net([dict(Y[0], x_m=[0.0, 0.0], z_m=[0.0, 0.0], y_m=[0.0, 5e-3])])
    with pytest.raises(ConfigError, match=r"branches\[0\]\.x_m, y_m, z_m: points must be distinct, got a repeated point "
                                          r"at index 2: \[0\.005, 0\.001, 0\.0\]"):
        _net([dict(Y[0], x_m=[0.0, 5e-3, 5e-3], z_m=[0.0, 0.0, 0.0], y_m=[0.0, 1e-3, 1e-3])])


def test_3d_daughter_must_start_at_its_parents_end_and_tree_rules_hold() -> None:
    tilted = _rot_x(Y, 0.5)
    off = dict(tilted[1], y_m=[1e-4] + tilted[1]["y_m"][1:])  # right x and z, wrong y
    with pytest.raises(ConfigError, match=r"branches\[1\] \('b'\) must start at the last point of its parent 'a' "
                                          r"\(\[0\.005, -?0\.0, 0\.0\]\), got \[0\.005, 0\.0001, 0\.0\]"):
        _net([tilted[0], off, tilted[2]])
    with pytest.raises(ConfigError, match=r"exactly one branch must have parent ''"):
        _net([tilted[0], dict(tilted[1], parent=""), tilted[2]])
    cyc = [tilted[0], dict(tilted[1], parent="c", x_m=[12e-3, 14e-3], y_m=[tilted[2]["y_m"][-1], 0.0],
                                     z_m=[tilted[2]["z_m"][-1], -9e-3]),
           dict(tilted[2], parent="b")]
    with pytest.raises(ConfigError, match="must start at the last point|cycle"):
        _net(cyc)


def test_3d_overlap_is_measured_in_3d() -> None:
    # two siblings that run parallel 1 mm apart along y (radii 0.8 mm each): they overlap in 3-D
    a = dict(Y[0], y_m=[0.0, 0.0])
    b = dict(Y[1], x_m=[5e-3, 8e-3, 20e-3], y_m=[0.0, 0.5e-3, 0.5e-3], z_m=[0.0, 0.0, 0.0])
    c = dict(Y[2], x_m=[5e-3, 8e-3, 20e-3], y_m=[0.0, -0.5e-3, -0.5e-3], z_m=[0.0, 0.0, 0.0])
    with pytest.raises(ConfigError, match=r"branches 'b' and 'c' overlap near \(x, y, z\) = .* radii sum 0\.0016"):
        _net([a, b, c])
    # siblings whose XZ projections cross but which pass 4 mm apart in y do not
    b2 = dict(b, y_m=[0.0, 2e-3, 2e-3], z_m=[0.0, 1e-3, -1e-3])
    c2 = dict(c, y_m=[0.0, -2e-3, -2e-3], z_m=[0.0, -1e-3, 1e-3])
    assert not _net([a, b2, c2]).is_planar


@settings(max_examples=40, deadline=None)
@given(theta=st.floats(0.0, 2.0 * np.pi), gap=st.floats(0.2, 3.0))
def test_overlap_of_rotated_parallel_siblings_follows_their_3d_gap(theta: float, gap: float) -> None:
    # parent along x, two siblings that diverge within the node's reach (3 radii sums, 2.4 mm) then run
    # parallel at +/- dy (polylines), the whole tree turned about x: they overlap iff dy < r
    r = 0.4e-3
    dy = gap * r
    base = [
        {"name": "a", "parent": "", "x_m": [0.0, 5e-3], "z_m": [0.0, 0.0], "radius_m": [1e-3]},
        {"name": "b", "parent": "a", "x_m": [5e-3, 5.5e-3, 20e-3], "z_m": [0.0, dy, dy], "radius_m": [r]},
        {"name": "c", "parent": "a", "x_m": [5e-3, 5.5e-3, 20e-3], "z_m": [0.0, -dy, -dy], "radius_m": [r]},
    ]
    branches = _rot_x(base, theta)
    if gap < 0.97:
        with pytest.raises(ConfigError, match="branches 'b' and 'c' overlap near"):
            _net(branches, smoothing="none")
    elif gap > 1.03:
        _net(branches, smoothing="none")


@settings(max_examples=30, deadline=None)
@given(theta=st.floats(0.0, 2.0 * np.pi), name=st.sampled_from(["paper_iiic_artery", "small_artery_4gen"]))
def test_rotated_planar_network_keeps_its_lengths_and_radii(theta: float, name: str) -> None:
    from vesselbot_ros.config import to_mapping

    planar = load_network(name)
    m = to_mapping(planar)
    m["branches"] = _rot_x(m["branches"], theta)
    net = load_dataclass(VesselNetworkParams, m, "")
    g2, g3 = NetworkGeometry(planar), NetworkGeometry(net, dims=3)
    for b in planar.branches:
        p2, r2, s2 = g2.branches[b.name]
        p3, s3 = g3.centreline(b.name), g3.arc_length(b.name)
        assert abs(s3[-1] - s2[-1]) < 1e-12 * s2[-1]
        # (a chord that is a whole number of sample spacings may round to one sample more or fewer)
        assert abs(len(s3) - len(s2)) <= 1
        # the 3-D spline of the turned points is the turned 2-D spline (compared at equal arc length)
        x2, z2 = np.interp(s3, s2, p2[:, 0]), np.interp(s3, s2, p2[:, 1])
        np.testing.assert_allclose(p3[:, 0], x2, atol=1e-7)
        np.testing.assert_allclose(p3[:, 1], -z2 * np.sin(theta), atol=1e-7)
        np.testing.assert_allclose(p3[:, 2], z2 * np.cos(theta), atol=1e-7)
        np.testing.assert_allclose(g3.radius(b.name), np.interp(s3, s2, r2), rtol=1e-12)


def test_3d_spline_through_a_helix() -> None:
    # 17 points on a helix of radius 4 mm and pitch 6 mm per turn, one turn: C2 spline in chord length
    R, pitch = 4e-3, 6e-3
    t = np.linspace(0.0, 2.0 * np.pi, 17)
    x, y, z = R * np.cos(t), R * np.sin(t), pitch * t / (2.0 * np.pi)
    net = _net([{"name": "h", "parent": "", "x_m": x.tolist(), "y_m": y.tolist(), "z_m": z.tolist(),
                 "radius_m": [0.5e-3] + [0.3e-3] * 16}])
    g = NetworkGeometry(net, dims=3)
    p = g.centreline("h")
    np.testing.assert_allclose(p[0], [x[0], y[0], z[0]], atol=1e-15)
    np.testing.assert_allclose(p[-1], [x[-1], y[-1], z[-1]], atol=1e-15)
    # on the helix's cylinder within 1 % of R (0.76 %: the natural ends), 0.2 % away from the ends
    # (0.12 %); the length the helix's within 0.05 % (-0.035 %)
    off = np.abs(np.hypot(p[:, 0], p[:, 1]) - R)
    inner = (p[:, 2] > 0.1 * pitch) & (p[:, 2] < 0.9 * pitch)
    assert off.max() < 0.01 * R and off[inner].max() < 0.002 * R
    exact = np.hypot(2.0 * np.pi * R, pitch)
    assert abs(g.length_m("h") - exact) < 5e-4 * exact
    assert g.radius("h")[0] == 0.5e-3 and g.radius("h")[-1] == 0.3e-3
    q = g.query(np.array([p[400] + [0.0, 0.0, 0.1e-3]]))  # 0.1 mm above a sample where r = 0.3 mm
    assert q["branch"][0] == 0 and 0.19e-3 < q["sdist"][0] <= 0.3e-3
    x0, x1, y0, y1, z0, z1 = g.bbox
    assert x0 < -R and x1 > R and y0 < -R and y1 > R and z0 < 0.0 and z1 > pitch


# --- the shipped 3-D trees -------------------------------------------------------------------------

SHIPPED_3D = ("paper_iiic_artery_3d", "carotid_bifurcation_3d", "synthetic_tree_3d")


def test_paper_iiic_artery_3d_is_the_planar_network() -> None:
    planar, tree = load_network("paper_iiic_artery"), load_network("paper_iiic_artery_3d")
    assert tree.is_planar and all(len(b.y_m) == len(b.x_m) for b in tree.branches)  # y_m given, all 0
    g2, g3 = NetworkGeometry(planar), NetworkGeometry(tree, dims=3)
    assert g3.names == g2.names
    for name in g2.names:
        p2, r2, s2 = g2.branches[name]
        p3 = g3.centreline(name)
        assert np.array_equal(p3[:, 0], p2[:, 0]) and np.array_equal(p3[:, 2], p2[:, 1]) and not p3[:, 1].any()
        assert np.array_equal(g3.radius(name), r2) and np.array_equal(g3.arc_length(name), s2)
    assert [(b.name, b.parent) for b in tree.branches] == [(b.name, b.parent) for b in planar.branches]


def test_a_network_is_3d_when_any_branch_gives_y_m_even_all_zero() -> None:
    assert not any(load_network(n).is_3d for n in ("paper_iiic_artery", "small_artery_4gen", "straight_table3"))
    assert all(load_network(n).is_3d for n in SHIPPED_3D)  # paper_iiic_artery_3d: y_m all 0, planar and 3-D
    assert not _net(Y).is_3d
    one = [dict(b, y_m=[0.0] * len(b["x_m"])) if i == 0 else b for i, b in enumerate(Y)]
    assert _net(one).is_3d and _net(one).is_planar


def test_carotid_bifurcation_has_the_models_dimensions_and_leaves_the_plane() -> None:
    net = load_network("carotid_bifurcation_3d")
    g = NetworkGeometry(net, dims=3)
    assert not net.is_planar and net.outlets == ["ica", "eca"]
    D = 8.0e-3
    assert g.radius("cca").min() == g.radius("cca").max() == pytest.approx(0.5 * D)
    assert g.radius("ica").max() == pytest.approx(0.5 * 1.10 * D, rel=2e-4)  # the sinus (between two samples)
    assert g.radius("ica")[-1] == pytest.approx(0.5 * 0.70 * D)
    assert g.radius("eca").max() == pytest.approx(0.5 * 0.58 * D)
    d_ica = g.centreline("ica")[-1] / np.linalg.norm(g.centreline("ica")[-1])
    d_eca = g.centreline("eca")[-1] / np.linalg.norm(g.centreline("eca")[-1])
    # 25 deg each side of the CCA's axis in the model's plane, each turned 15 deg about it
    assert np.degrees(np.arccos(d_ica[0])) == pytest.approx(25.0, abs=1e-6)
    assert np.degrees(np.arccos(d_eca[0])) == pytest.approx(25.0, abs=1e-6)
    assert np.degrees(np.arccos(d_ica @ d_eca)) == pytest.approx(48.19, abs=0.01)
    n = np.cross(d_ica, d_eca)
    assert np.degrees(np.arcsin(abs(n[0]) / np.linalg.norm(n))) == pytest.approx(6.9, abs=0.05)  # planarity angle
    with pytest.raises(ConfigError, match="vessel network 'carotid_bifurcation_3d' is not planar"):
        NetworkGeometry(net, dims=2)


@pytest.mark.parametrize("name", SHIPPED_3D)
def test_shipped_3d_trees_let_the_bead_pass(name: str) -> None:
    # Table III's bead has r = 250 um: every lumen radius is at least 0.35 mm (the III-C side branches)
    g = NetworkGeometry(load_network(name), dims=3)
    assert min(float(g.radius(b).min()) for b in g.names) >= 0.35e-3


def test_synthetic_tree_obeys_murrays_law_over_four_generations() -> None:
    net = load_network("synthetic_tree_3d")
    assert not net.is_planar and len(net.branches) == 15 and len(net.outlets) == 8
    depth = {b.name: b.name.count("_") for b in net.branches}
    assert max(depth.values()) == 3  # generations 0-3
    for b in net.branches:
        kids = net.children(b.name)
        if kids:
            # r^3 = r_a^3 + r_b^3 with r_a^3 / r^3 = 0.6 (radii rounded to 1 nm: 3 nm / 0.6 mm in r^3)
            r, ra, rb = b.radius_m[-1], kids[0].radius_m[-1], kids[1].radius_m[-1]
            assert ra ** 3 + rb ** 3 == pytest.approx(r ** 3, rel=1e-5)
            assert ra ** 3 / r ** 3 == pytest.approx(0.6, rel=1e-5)
    g = NetworkGeometry(net, dims=3)
    assert g.radius("b0").max() == pytest.approx(1.5e-3) and min(g.radius(n).min() for n in g.names) == pytest.approx(0.6e-3)


# --- issue 38 section 3: sizes and physical limits, refused before anything is allocated -----------------------


def _one_line_refusal(proc, *fragments: str) -> str:  # type: ignore[no-untyped-def]
    """A refused command: exit 2, one line on stderr naming every fragment, no traceback."""
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-3000:])
    assert "Traceback" not in proc.stderr and "MemoryError" not in proc.stderr, proc.stderr[-3000:]
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    for f in fragments:
        assert f in lines[0], (f, lines[0])
    return str(lines[0])


@pytest.mark.parametrize(("radius", "rule"), [(1e6, "got 1000000.0"), (2.5e-2, "got 0.025"), (5e-7, "got 5e-07")])
def test_a_radius_no_blood_vessel_has_is_refused_naming_the_limits(radius: float, rule: str) -> None:
    with pytest.raises(ConfigError, match=r"branches\[0\]\.radius_m\[0\] must be a blood vessel's lumen radius, "
                                          r"between 1e-06 and 0\.02 m, " + rule):
        _net([dict(Y[0], radius_m=[radius])])


def test_a_branch_or_a_network_longer_than_a_body_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"branches\[0\]\.x_m, z_m: a branch is at most 1 m long, got 1\.5 m"):
        _net([dict(Y[0], x_m=[0.0, 1.5])])
    far = [dict(Y[0], x_m=[0.0, 0.6]), dict(Y[1], parent="a", x_m=[0.6, 1.2], z_m=[0.0, 0.01])]
    with pytest.raises(ConfigError, match=r"branches: a network spans at most 1 m along x, y and z, got \[1\.2, 0\.0, 0\.01\]"):
        _net(far)


def test_a_sample_spacing_whose_samples_would_not_fit_is_refused_with_the_estimate() -> None:
    # 22 mm of centreline at 1e-12 m: 2.2e10 samples; the old check built them (and their pairs) first
    with pytest.raises(ConfigError, match=r"^sample_spacing_m=1e-12: the network's 2\.22e\+10 centreline samples .* needs about "
                                          r"[0-9.]+ TiB of memory"):
        _net(Y, sample_spacing_m=1e-12)


def test_the_overlap_check_in_blocks_finds_the_whole_array_s_first_worst_pair(monkeypatch: pytest.MonkeyPatch) -> None:
    from vesselbot_ros.vessels import network

    monkeypatch.setattr(network, "_OVERLAP_BLOCK", 16)  # many blocks, some skipped, on small arrays
    rng = np.random.default_rng(7)
    for _ in range(300):
        na, nb = (int(v) for v in rng.integers(1, 120, 2))
        # walks (blocks of consecutive samples lie together, as a centreline's do; far blocks are skipped), on a
        # 0.05 lattice (many ties)
        qa = np.round(np.cumsum(rng.normal(0.0, 0.03, (na, 3)), axis=0) * 20.0) / 20.0
        qb = np.round((np.cumsum(rng.normal(0.0, 0.03, (nb, 3)), axis=0) + rng.uniform(-0.5, 0.5, 3)) * 20.0) / 20.0
        ra, rb = np.round(rng.uniform(0, 0.05, na), 2), np.round(rng.uniform(0, 0.05, nb), 2)
        d = np.hypot(np.hypot(*(qa[:, None, ::2] - qb[None, :, ::2]).transpose(2, 0, 1)), qa[:, None, 1] - qb[None, :, 1])
        need = ra[:, None] + rb[None, :]
        got = network._worst_overlap(qa, ra, qb, rb)
        if (d < need).any():
            ia, ib = np.unravel_index(int(np.argmax(need - d)), d.shape)
            assert got is not None and got[1:3] == (ia, ib)
            assert got[3] == d[ia, ib] and got[4] == need[ia, ib]
        else:
            assert got is None


def test_a_long_network_validates_in_bounded_memory_and_its_flow_solve_is_refused_with_the_estimate(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A 0.7 m Y (the old overlap check made a 4+ GiB array of its daughters' sample pairs): validated within a
    3 GiB address space, and the 2-D flow solve its default mesh would need is refused in one line, exit 2."""
    import yaml

    from vesselbot_ros.testing import cli_under_memory_limit

    net = {"name": "long_y", "branches": [
        {"name": "trunk_a", "parent": "", "x_m": [-2e-3, 0.3], "z_m": [0.0, 0.0], "radius_m": [1.5e-3]},
        {"name": "upper", "parent": "trunk_a", "x_m": [0.3, 0.65], "z_m": [0.0, 0.2], "radius_m": [1.19e-3]},
        {"name": "lower", "parent": "trunk_a", "x_m": [0.3, 0.65], "z_m": [0.0, -0.2], "radius_m": [1.19e-3]}]}
    path = tmp_path / "long_y.yaml"
    path.write_text(yaml.safe_dump(net))
    proc = cli_under_memory_limit(["simulate", "--config", "paper_iiic_network_upper", "--set",
                                   f"physics.vessel.network={path}", "--out", str(tmp_path / "out")],
                                  cwd=tmp_path, timeout=120)
    line = _one_line_refusal(proc, "cfd.mesh_size_m=0.0001", "the 2-D flow solve of network 'long_y'", "GiB")
    assert "triangles) needs about" in line
    assert not (tmp_path / "out").exists()


def test_a_network_of_too_many_branches_for_the_overlap_check_is_refused_with_its_time() -> None:
    """7000 branches (a 1 MB file holds ten thousand): 24.5 million branch pairs, about 41 min of checking."""
    ends: list[tuple[float, float]] = []
    tree = []
    for i in range(7000):  # a binary tree 13 generations deep, each branch 0.1 mm on from its parent's end
        x0, z0 = ends[(i - 1) // 2] if i else (0.0, 0.0)
        x1, z1 = x0 + 1e-4, z0 + (5e-5 if i % 2 else -5e-5)
        ends.append((x1, z1))
        tree.append({"name": f"b{i}", "parent": f"b{(i - 1) // 2}" if i else "", "x_m": [x0, x1], "z_m": [z0, z1],
                     "radius_m": [1e-6]})
    with pytest.raises(ConfigError, match=r"^branches=7000 branches: the overlap check of every pair of branches would take "
                                          r"about 41 min .*more than the 30 min a set-up step may take"):
        _net(tree)


# --- physiological flow presets (docs/vessels.md "Physiological flow presets") ---

PRESET = {"name": "p", "source": "a cited source", "mean_velocity_m_per_s": 0.1, "peak_centreline_velocity_m_per_s": 0.5,
          "heart_rate_per_min": 72.0, "outlets": ["b", "c"], "outlet_shares": [0.7, 0.3]}


def test_a_flow_preset_maps_mean_and_peak_onto_the_papers_waveform() -> None:
    net = _net(Y, flow_presets=[PRESET])
    v = net.flow_preset("p").flow_values()
    assert v["centreline_velocity_m_per_s"] == 0.2  # Poiseuille: twice the mean velocity
    assert v["pulsatility"] == pytest.approx(0.5 / 0.2 - 1.0, rel=1e-15)  # peak = V_f (1 + a_f)
    assert v["angular_frequency_rad_per_s"] == pytest.approx(2.0 * np.pi * 1.2, rel=1e-15)
    assert _net(Y, flow_presets=[dict(PRESET, heart_rate_per_min=60.0)]).flow_preset("p").angular_frequency_rad_per_s \
        == 2.0 * np.pi  # 60 /min is Table III's omega_f bit for bit


@pytest.mark.parametrize(("change", "message"), [
    ({"mean_velocity_m_per_s": -0.1}, r"flow_presets\[0\]\.mean_velocity_m_per_s must be > 0, got -0\.1"),
    ({"mean_velocity_m_per_s": float("nan")}, r"flow_presets\[0\]\.mean_velocity_m_per_s must be finite, got nan"),
    ({"peak_centreline_velocity_m_per_s": float("nan")},
     r"flow_presets\[0\]\.peak_centreline_velocity_m_per_s must be finite, got nan"),
    ({"outlet_shares": [0.7, 0.2]},
     r"flow_presets\[0\]\.outlet_shares must sum to 1 \(within 1e-09\), got \[0\.7, 0\.2\] \(sum 0\.9\)"),
    ({"outlet_shares": [0.7, 0.3 + 2e-9]}, r"flow_presets\[0\]\.outlet_shares must sum to 1"),
    ({"outlet_shares": [1.2, -0.2]}, r"flow_presets\[0\]\.outlet_shares\[0\] must be in \[0\.0, 1\.0\], got 1\.2"),
    ({"outlets": ["b", "x"]}, r"flow_presets\[0\]\.outlets\[1\] 'x' is not an outlet of network 't'; outlets: \['b', 'c'\]"),
    ({"outlets": ["b"], "outlet_shares": [1.0]}, r"flow_presets\[0\]\.outlets must name every outlet .* \(missing \['c'\]\)"),
    ({"pulsatility": 1.0}, r"flow_presets\[0\]\.peak_centreline_velocity_m_per_s or pulsatility: give exactly one, got "),
    ({"peak_centreline_velocity_m_per_s": 0.1}, r"peak_centreline_velocity_m_per_s must be >= the mean centreline"),
    ({"heart_rate_per_min": 0.0}, r"flow_presets\[0\]\.heart_rate_per_min must be in \(0\.0, 300\.0\], got 0\.0"),
    ({"source": ""}, r"flow_presets\[0\]\.source must cite where the numbers come from, got ''"),
])
def test_a_bad_flow_preset_is_one_line_naming_the_key_and_the_value(change: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message) as info:
        _net(Y, flow_presets=[dict(PRESET, **change)])
    assert "\n" not in str(info.value)


def test_an_unknown_preset_name_lists_the_networks_presets() -> None:
    with pytest.raises(ConfigError, match=r"physics\.flow\.preset: network 't' has no flow preset 'q'; its presets: \['p'\]"):
        _net(Y, flow_presets=[PRESET]).flow_preset("q")


def test_presets_leave_the_networks_hash_and_a_preset_with_shares_takes_its_own_cfd_key() -> None:
    plain, with_presets = _net(Y), _net(Y, flow_presets=[PRESET])
    assert with_presets.geometry_hash() == plain.geometry_hash()
    solved = with_flow_preset(with_presets, "p")
    assert solved.cfd.outlet_split == "shares" and solved.cfd.share_outlets == ("b", "c")
    assert solved.cfd.outlet_shares == (0.7, 0.3) and solved.geometry_hash() != plain.geometry_hash()
    assert with_flow_preset(with_presets, "") is with_presets
    no_shares = _net(Y, flow_presets=[{k: v for k, v in PRESET.items() if k not in ("outlets", "outlet_shares")}])
    assert with_flow_preset(no_shares, "p") is no_shares  # the network's own split stays


@pytest.mark.parametrize("name", ["paper_iiic_artery", "paper_iiic_artery_3d", "small_artery_4gen", "synthetic_tree_3d",
                                  "carotid_bifurcation_3d"])
def test_every_shipped_tree_has_a_cited_flow_preset(name: str) -> None:
    net = load_network(name)
    assert net.flow_presets and all(p.source.strip() for p in net.flow_presets)


def test_the_carotid_preset_is_a_carotids_flow() -> None:
    p = load_network("carotid_bifurcation_3d").flow_preset("healthy_adult_cca")
    q_ml_per_min = p.mean_velocity_m_per_s * np.pi * 4.0e-3 ** 2 * 6.0e7  # through the 8 mm CCA
    assert q_ml_per_min == pytest.approx(415.0, rel=1e-3)
    assert p.peak_centreline_velocity_m_per_s == 0.63
    assert dict(zip(p.outlets, p.outlet_shares)) == {"ica": 0.5755, "eca": 0.4245}
