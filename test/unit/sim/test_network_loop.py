"""The closed loop in a vessel network: straight regression, navigation through the III-C bifurcation."""

from __future__ import annotations

import numpy as np
import pytest

from vesselbot_ros.control.route import navigation_outcome, planned_reference
from vesselbot_ros.physics.kernel import forces_into, wall_delta_xz
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios
from vesselbot_ros.vessels.cfd import packed_params

STRAIGHT = "physics.vessel.network=straight_table3"
KEYS = ("tracking_error_max_m", "tracking_error_rms_m", "estimation_error_max_m", "estimation_error_rms_m",
        "max_gradient_T_per_m")


def test_network_kernel_equals_the_analytic_straight_kernel() -> None:
    sc = load_scenario(shipped_scenarios()["sound_small_artery"])
    net = load_scenario(shipped_scenarios()["sound_small_artery"], sets=[STRAIGHT])
    pa, pn = packed_params(sc.physics), packed_params(net.physics)
    fa, fn = np.empty((8, 2)), np.empty((8, 2))
    contact = np.zeros(4)
    for t, x, z, vx, vz in [(0.1, 2e-3, 0.9e-3, 1e-3, -2e-4), (0.37, 5e-3, -1.1e-3, 0.0, 1e-3), (0.8, 9e-3, 1.2e-3, -3e-3, 0.0),
                            (0.25, 1e-3, 1.35e-3, 0.0, 0.0)]:
        forces_into(t, x, z, vx, vz, 0.01, -0.02, contact, pa, fa)
        forces_into(t, x, z, vx, vz, 0.01, -0.02, contact, pn, fn)
        scale = np.abs(fa).max()
        np.testing.assert_allclose(fn, fa, atol=2e-4 * scale)
        np.testing.assert_allclose(wall_delta_xz(t, x, z, pn), wall_delta_xz(t, x, z, pa), atol=1e-9)


# paper_small_artery is left out: its stick/slide on the wall is chaotic (README, reproducibility), so any change
# of the last bits moves its metrics by several per cent (measured: 5 % on seed 0 through the CFD path)
@pytest.mark.parametrize(("name", "seeds"), [("sound_small_artery", range(5)), ("sound_small_artery_ekf", (0,))])
def test_one_branch_network_reproduces_the_straight_vessel_within_1_percent(name: str, seeds: range) -> None:
    path = shipped_scenarios()[name]
    for seed in seeds:
        a = run_closed_loop(load_scenario(path), seed).metrics
        n = run_closed_loop(load_scenario(path, sets=[STRAIGHT]), seed).metrics
        for k in KEYS:
            assert n[k] == pytest.approx(a[k], rel=0.01), (name, seed, k)
        assert n["contact_time_s"] == pytest.approx(a["contact_time_s"], rel=0.01, abs=0.005)
        assert n["branch_final"] == "trunk" and n["outside_lumen_time_s"] == 0.0


@pytest.mark.parametrize(("name", "outlet"), [("paper_iiic_network_upper", "upper"), ("paper_iiic_network_lower", "lower"),
                                            ("small_artery_4gen_udu", "g0udu")])
def test_network_scenarios_reach_the_chosen_branch_on_seeds_0_to_4(name: str, outlet: str) -> None:
    sc = load_scenario(shipped_scenarios()[name])
    ref = planned_reference(sc)
    assert ref.anchors_x_m[0] == sc.initial.p0_m[0]  # the route starts at the injection point
    for seed in range(5):
        m = run_closed_loop(sc, seed).metrics
        assert m["branch_final"] == outlet and m["reached_target"] == 1, (seed, m["branch_final"])
        assert m["outside_lumen_time_s"] == 0.0
        assert m["tracking_error_rms_m"] < 1e-3


def test_leaving_the_lumen_is_a_recorded_event() -> None:
    t = np.arange(5) * 1e-3
    p = np.array([[0.0, 0.0], [0.0, 1.0e-3], [0.0, 1.6e-3], [0.0, 1.7e-3], [0.0, 1.0e-3]])
    out = navigation_outcome("paper_iiic_artery", "upper", t, p)
    assert out["outside_lumen_time_s"] == pytest.approx(2e-3)
    assert out["outside_lumen_first_s"] == pytest.approx(2e-3)
    assert out["branch_final"] == "trunk_a" and out["reached_target"] == 0


def test_the_lumen_is_judged_where_the_pulsating_wall_was() -> None:
    """A centre just past the wall at rest is inside while the wall is dilated, and one just inside it is outside
    while the wall is contracted: the plant's own wall, ``s_t = s + D eps(t) / 2`` (eq. (13))."""
    from vesselbot_ros.control.route import pulsation_of
    from vesselbot_ros.physics.params import FlowParams
    from vesselbot_ros.vessels.network import load_network
    from vesselbot_ros.vessels.tree_field import meshed_wall

    wall = meshed_wall(load_network("paper_iiic_artery"))
    base = np.array([0.0, 1.4e-3])
    s0 = float(wall.query(base[None])["sdist"][0])
    n = wall.query(base[None])["normal"][0]
    d = float(wall.query(base[None])["diameter"][0])
    flow = FlowParams(diameter_pulsation=0.1, angular_frequency_rad_per_s=2.0 * np.pi, phase_rad=0.0)
    gap = 0.25 * 0.5 * d * 0.1  # a quarter of the pulsation's amplitude
    past = base - (s0 + gap) * n  # outside the wall at rest
    inside = base - (s0 - gap) * n  # inside the wall at rest
    t = np.array([0.25, 0.75])  # eps = +0.1 (dilated), then -0.1 (contracted)
    pulsing = navigation_outcome("paper_iiic_artery", "upper", t, np.array([past, inside]), pulsation=pulsation_of(flow))
    steady = navigation_outcome("paper_iiic_artery", "upper", t, np.array([past, inside]))
    assert pulsing["outside_lumen_first_s"] == pytest.approx(0.75)  # the inside point, the wall contracted onto it
    assert steady["outside_lumen_first_s"] == pytest.approx(0.25)  # the point past the wall at rest
    assert pulsing["outside_lumen_time_s"] == steady["outside_lumen_time_s"] == pytest.approx(0.5)


def test_a_planar_scenario_switched_to_a_3d_tree_asks_for_its_third_axis_in_one_line() -> None:
    from vesselbot_ros.config import ConfigError

    with pytest.raises(ConfigError, match=r"^initial\.p0_m must have 3 values \(x, y, z: the vessel is a 3-D tree\)") as ei:
        load_scenario(shipped_scenarios()["paper_iiic_network_upper"],
                      sets=["physics.vessel.network=carotid_bifurcation_3d"])
    assert "\n" not in str(ei.value)


def test_a_scenario_refuses_a_reference_path_in_three_dimensions_in_a_planar_vessel_in_one_line() -> None:
    from vesselbot_ros.config import ConfigError

    with pytest.raises(ConfigError, match=r"^reference\.anchors_y_m: a path in three dimensions needs a 3-D vessel tree") as ei:
        load_scenario(shipped_scenarios()["sound_small_artery"], sets=["reference.anchors_y_m=[0.0, 1.0e-4, 0.0, 0.0]"])
    assert "\n" not in str(ei.value)


@pytest.mark.parametrize(("name", "sets"), [
    ("paper_iiic_network_lower", ["controller.wall_contact=carried"]),
    ("carotid_bifurcation_3d_eca", ["controller.wall_contact=carried", "controller.kind=predictive"]),
    ("paper_iiic_network_upper_3d", ["reference.timing=flow_synchronised", "reference.sync_along=path"]),
    ("paper_iiic_network_lower", ["reference.timing=flow_synchronised", "reference.sync_along=path"])])
def test_carried_contact_and_flow_synchronised_timing_run_in_networks_and_3d_trees_compiled_as_per_tick(name: str, sets: list[str]) -> None:
    sc = load_scenario(shipped_scenarios()[name], sets=["sim.duration_s=0.3", *sets])
    a, b = run_closed_loop(sc, 0), run_closed_loop(sc, 0, path="per_tick")
    assert a.path == "compiled" and a.metrics["status"] == "ok"
    for k in a.timeseries:
        assert np.array_equal(a.timeseries[k], b.timeseries[k], equal_nan=True), k


_FLOOR = ["reference.anchors_x_m=[0.0, 3.0e-3, 6.0e-3, 9.0e-3]", "reference.anchors_z_m=[-1.2e-3, -1.2e-3, -1.2e-3, -1.2e-3]",
          "reference.wall_follow=[1.0, 1.0, 0.5, 0.0]"]


def test_wall_follow_in_a_network_moves_as_the_straight_vessels_lower_wall() -> None:
    """A reference riding the floor of the one-branch network follows its meshed wall's pulsation as the straight
    vessel's reference follows its analytic lower wall (eq. (13)): the same path within a nanometre, and the same
    velocity and acceleration."""
    from vesselbot_ros.sim.closed_loop import build_stages

    base = shipped_scenarios()["sound_small_artery"]
    ra = build_stages(load_scenario(base, sets=_FLOOR), 0).reference
    rb = build_stages(load_scenario(base, sets=[*_FLOOR, STRAIGHT]), 0).reference
    still = build_stages(load_scenario(base, sets=_FLOOR[:2]), 0).reference
    ts = np.linspace(0.0, 2.0, 81)
    (pa, va, aa), (pb, vb, ab), (p0, _v0, _a0) = ra.sample_many(ts), rb.sample_many(ts), still.sample_many(ts)
    assert np.abs(pa - p0).max() > 1e-4  # it moves: up to 150 um (D eps / 2 of a 3 mm vessel at eps = 0.1)
    np.testing.assert_allclose(pb, pa, rtol=0, atol=1e-9)
    np.testing.assert_allclose(vb, va, rtol=0, atol=1e-8 * np.abs(va).max())
    np.testing.assert_allclose(ab, aa, rtol=0, atol=1e-6 * np.abs(aa).max())


def test_wall_follow_in_a_3d_tree_rides_its_floor_and_runs_compiled_as_per_tick() -> None:
    """In the 3-D III-C tree (the planar network at y = 0) the reference on the trunk's floor moves down with the
    tube's lower wall, D eps / 2 below its rest path, as in the straight vessel, and stays in the plane y = 0."""
    from vesselbot_ros.sim.closed_loop import build_stages

    floor = ['reference.route_outlet=""', "reference.anchors_x_m=[-1.5e-3, -0.5e-3, 0.5e-3, 1.5e-3]",
             "reference.anchors_y_m=[0.0, 0.0, 0.0, 0.0]", "reference.anchors_z_m=[-1.1e-3, -1.1e-3, -1.1e-3, -1.1e-3]",
             "initial.p0_m=[-1.5e-3, 0.0, -1.1e-3]", "reference.duration_s=1.0", "sim.duration_s=0.3"]
    sc = load_scenario(shipped_scenarios()["paper_iiic_network_upper_3d"], sets=[*floor, "reference.wall_follow=[1.0, 1.0, 1.0, 1.0]"])
    ref = build_stages(sc, 0).reference
    still = build_stages(load_scenario(shipped_scenarios()["paper_iiic_network_upper_3d"], sets=floor), 0).reference
    ts = np.linspace(0.0, 1.0, 41)
    p, p0 = ref.sample_many(ts)[0], still.sample_many(ts)[0]
    f = sc.physics.flow
    eps = f.diameter_pulsation * np.sin(f.angular_frequency_rad_per_s * ts + f.phase_rad)
    drop = 0.5 * 3.0e-3 * eps  # the trunk: D = 3 mm
    np.testing.assert_allclose(p[:, 0], p0[:, 0], atol=1e-6)
    np.testing.assert_allclose(p[:, 1], 0.0, atol=2e-6)
    np.testing.assert_allclose(p0[:, 2] - p[:, 2], drop, atol=0.02 * 0.5 * 3.0e-3 * f.diameter_pulsation)
    a, b = run_closed_loop(sc, 0), run_closed_loop(sc, 0, path="per_tick")
    assert a.path == "compiled"
    for k in a.timeseries:
        assert np.array_equal(a.timeseries[k], b.timeseries[k], equal_nan=True), k


@pytest.mark.parametrize("name", ["paper_iiic_network_upper_3d", "carotid_bifurcation_3d_eca", "synthetic_tree_3d_deep"])
def test_3d_trees_run_on_three_axes_reproducibly(name: str) -> None:
    sc = load_scenario(shipped_scenarios()[name], sets=["sim.duration_s=0.3"])
    assert sc.dims == 3
    a, b = run_closed_loop(sc, 1), run_closed_loop(sc, 1)
    assert a.path == "compiled"  # the compiled 3-D loop (bit-identical to the per-tick one: test_compiled_loop.py)
    for k in ("p_true", "v_true", "meas_p", "x_hat", "z_hat", "u_cmd", "g_cmd", "g_applied", "slew_limited"):
        assert a.timeseries[k].shape == (300, 3), k
        assert np.array_equal(a.timeseries[k], b.timeseries[k], equal_nan=True), k
    assert np.nanstd(a.timeseries["meas_p"][:, 1] - a.timeseries["p_true"][:, 1]) == pytest.approx(1e-4, rel=0.2)
    assert a.metrics["outside_lumen_time_s"] == 0.0


def test_a_3d_trees_coil_takes_the_db_dt_of_three_axes() -> None:
    from vesselbot_ros.scanner.hardware import dbdt_axis_slew_limit
    from vesselbot_ros.sim.closed_loop import build_stage

    sc = load_scenario(shipped_scenarios()["paper_iiic_network_upper_3d"], sets=["dbdt.mode=iec_normal_mode"])
    coil = build_stage(sc, "coil")
    s3 = dbdt_axis_slew_limit(sc.coil.saturation_T_per_m, sc.dbdt.radius_m, axes=3)
    assert coil.limits.slew_rate_T_per_m_per_s == s3 < dbdt_axis_slew_limit(sc.coil.saturation_T_per_m, sc.dbdt.radius_m)
    assert s3 < sc.coil.slew_rate_T_per_m_per_s  # it binds: 58 T/m/s against the clinical 100


def test_the_3d_trees_reach_their_outlets_on_seeds_0_to_4() -> None:
    """The stored reference runs (test_reference_metrics.py checks them against fresh runs, number for number)."""
    from vesselbot_ros.sim.reference_metrics import load_reference

    runs = load_reference()["runs"]
    for name in ("paper_iiic_network_upper_3d", "carotid_bifurcation_3d_eca", "synthetic_tree_3d_deep"):
        for seed in range(5):
            m = runs[f"{name}/{seed}"]
            assert m["reached_target"] == 1, (name, seed)  # the final point in the route's outlet branch
            assert m["outside_lumen_time_s"] == 0.0, (name, seed)


@pytest.mark.parametrize("name", ["paper_iiic_network_lower_ekf", "paper_iiic_network_upper_3d_ekf"])
@pytest.mark.parametrize("controller", ["law24", "predictive"])
def test_the_best_loops_reach_the_outlet_in_a_network_and_a_tree_compiled_as_per_tick(name: str, controller: str) -> None:
    """The extended Kalman filter (flow scale, delay compensation) with law (24) or with the predictive controller,
    on a planned route through a planar network and through a 3-D tree: into the outlet, 0 s outside the lumen,
    the compiled loop equal to the per-tick loop bit for bit (every metric and every column)."""
    sets = [] if controller == "law24" else ["controller.kind=predictive"]
    sc = load_scenario(shipped_scenarios()[name], sets=sets)
    assert sc.observer.kind == "ekf"
    a = run_closed_loop(sc, 0, path="compiled")
    b = run_closed_loop(sc, 0, path="per_tick")
    assert a.path == "compiled" and b.path == "per_tick"
    m = a.metrics
    assert m["status"] == "ok" and m["reached_target"] == 1 and m["outside_lumen_time_s"] == 0.0
    assert m["tracking_error_max_m"] < 150e-6
    for k, v in m.items():
        assert v == b.metrics[k] or (isinstance(v, float) and np.isnan(v) and np.isnan(b.metrics[k])), k
    for k, col in a.timeseries.items():
        np.testing.assert_array_equal(col, b.timeseries[k], err_msg=k)


def test_the_docs_tree_campaign_table_is_what_the_stored_campaigns_render() -> None:
    """docs/reproduction.md's 100-seed table of the best loops is tools/network_numbers.py's rendering of the
    stored campaign tables (docs/trees_best/<tree>/results.parquet): no figure in it is typed by hand."""
    import importlib.util
    from pathlib import Path

    root = Path(__file__).resolve().parents[3]
    spec = importlib.util.spec_from_file_location("network_numbers", root / "tools" / "network_numbers.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    doc = (root / "docs" / "reproduction.md").read_text(encoding="utf-8")
    assert f"{mod.CBEGIN}\n{mod.campaign_block()}\n{mod.CEND}" in doc
    assert {p.stem for p in (root / "config" / "campaigns" / "trees_best").glob("*.yaml")} == set(mod.SCENARIOS)


def test_a_shipped_best_loop_scenario_is_what_its_generator_writes() -> None:
    """config/<tree>_ekf.yaml is tools/gen_tree_scenarios.py's output to the byte (here the III-C lower route's; the
    tool's --check compares all six): the planned table is regenerated, never edited."""
    import importlib.util
    from pathlib import Path

    root = Path(__file__).resolve().parents[3]
    spec = importlib.util.spec_from_file_location("gen_tree_scenarios", root / "tools" / "gen_tree_scenarios.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert set(mod.TREES) == {p.stem.removesuffix("_ekf") for p in (root / "config").glob("*_ekf.yaml")} - {"sound_small_artery"}
    shipped = (root / "config" / "paper_iiic_network_lower_ekf.yaml").read_text(encoding="utf-8")
    assert mod.text("paper_iiic_network_lower") == shipped
