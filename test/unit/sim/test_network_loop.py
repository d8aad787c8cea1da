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


def test_a_scenario_refuses_a_non_planar_network_in_one_line() -> None:
    from vesselbot_ros.config import ConfigError

    with pytest.raises(ConfigError, match=r"^physics\.vessel\.network: vessel network 'carotid_bifurcation_3d' is not "
                                          r"planar .*: the 2-D plant takes XZ networks only") as ei:
        load_scenario(shipped_scenarios()["paper_iiic_network_upper"],
                      sets=["physics.vessel.network=carotid_bifurcation_3d"])
    assert "\n" not in str(ei.value)


def test_a_scenario_refuses_a_reference_path_in_three_dimensions_in_one_line() -> None:
    from vesselbot_ros.config import ConfigError

    with pytest.raises(ConfigError, match=r"^reference\.anchors_y_m: a path in three dimensions needs the 3-D plant") as ei:
        load_scenario(shipped_scenarios()["sound_small_artery"], sets=["reference.anchors_y_m=[0.0, 1.0e-4, 0.0, 0.0]"])
    assert "\n" not in str(ei.value)
