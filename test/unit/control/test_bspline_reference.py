"""Tests of the C2 B-spline reference trajectory."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError, load_dataclass, to_mapping
from vesselbot_ros.control.bspline_reference import ReferenceParams, ReferenceTrajectory, propose_anchors
from vesselbot_ros.errors import ModelInputError

PARAMS = ReferenceParams(
    anchors_x_m=(0.0, 3e-3, 6e-3, 9e-3, 12e-3),
    anchors_z_m=(1e-3, 0.8e-3, 1.0e-3, 0.7e-3, 0.9e-3),
    duration_s=2.0,
)


def test_passes_through_anchors() -> None:
    ref = ReferenceTrajectory(PARAMS)
    anchors = np.column_stack([PARAMS.anchors_x_m, PARAMS.anchors_z_m])
    pts = ref._path(ref.anchor_u_m)  # the path at the anchors' parameters
    np.testing.assert_allclose(pts, anchors, atol=1e-15)
    # and in time: constant timing reaches anchor i at t = T u_i / U
    ts = PARAMS.duration_s * ref.anchor_u_m / ref.length_m
    p, _, _ = ref.sample_many(ts)
    np.testing.assert_allclose(p, anchors, atol=1e-12)


@pytest.mark.parametrize("timing", ["constant", "rest_to_rest"])
def test_c2_continuity_across_knots(timing: str) -> None:
    ref = ReferenceTrajectory(ReferenceParams(**{**PARAMS.__dict__, "timing": timing}))
    ts = PARAMS.duration_s * ref.anchor_u_m[1:-1] / ref.length_m
    if timing == "rest_to_rest":  # anchor times differ; check at the interior knots' times via bisection-free grid
        ts = np.linspace(0.1, 1.9, 7)
    h = 1e-9
    for t in ts:
        lo = ref.sample(t - h)
        hi = ref.sample(t + h)
        # position, velocity and acceleration continuous (jumps would be O(1), not O(h))
        np.testing.assert_allclose(lo.p, hi.p, atol=1e-10)
        np.testing.assert_allclose(lo.v, hi.v, atol=1e-9)
        np.testing.assert_allclose(lo.a, hi.a, atol=1e-6)


def test_derivatives_match_finite_differences() -> None:
    ref = ReferenceTrajectory(ReferenceParams(**{**PARAMS.__dict__, "timing": "rest_to_rest"}))
    h = 1e-5
    for t in (0.2, 0.77, 1.3):
        s0, sp, sm = ref.sample(t), ref.sample(t + h), ref.sample(t - h)
        np.testing.assert_allclose((sp.p - sm.p) / (2 * h), s0.v, rtol=1e-6, atol=1e-12)
        np.testing.assert_allclose((sp.v - sm.v) / (2 * h), s0.a, rtol=1e-5, atol=1e-10)


def test_rest_to_rest_starts_and_ends_at_rest_and_holds() -> None:
    ref = ReferenceTrajectory(ReferenceParams(**{**PARAMS.__dict__, "timing": "rest_to_rest"}))
    for t in (0.0, 2.0):
        s = ref.sample(t)
        np.testing.assert_allclose(s.v, 0.0, atol=1e-15)
        np.testing.assert_allclose(s.a, 0.0, atol=1e-12)
    after = ref.sample(5.0)
    np.testing.assert_allclose(after.p, [12e-3, 0.9e-3], atol=1e-15)
    np.testing.assert_array_equal(after.v, [0.0, 0.0])


def test_sample_equals_sample_many() -> None:
    ref = ReferenceTrajectory(PARAMS)
    ts = np.arange(0, 2000) * 1e-3
    p, v, a = ref.sample_many(ts)
    for k in (0, 1, 999, 1999):
        s = ref.sample(float(ts[k]))
        np.testing.assert_array_equal(s.p, p[k])
        np.testing.assert_array_equal(s.v, v[k])
        np.testing.assert_array_equal(s.a, a[k])


def test_flow_synchronised_velocity_follows_flow() -> None:
    def vf(t: float, p: np.ndarray) -> np.ndarray:
        return np.array([0.01 * (1.0 + 0.5 * math.sin(2 * math.pi * t)), 0.0])

    prm = ReferenceParams(anchors_x_m=(0.0, 0.02, 0.04, 0.06), anchors_z_m=(0.0, 0.0, 0.0, 0.0),
                          duration_s=2.0, timing="flow_synchronised", sync_ratio=0.5)
    ref = ReferenceTrajectory(prm, flow_velocity=vf)
    for t in (0.1, 0.6, 1.4):
        assert ref.sample(t).v[0] == pytest.approx(0.5 * vf(t, np.zeros(2))[0], rel=1e-4)
    # x_ref(t) = 0.005 (t + (1 - cos 2 pi t) / (4 pi))  (hand-integrated)
    t = 1.3
    assert ref.sample(t).p[0] == pytest.approx(0.005 * (t + (1 - math.cos(2 * math.pi * t)) / (4 * math.pi)), rel=1e-5)


def test_flow_synchronised_needs_flow() -> None:
    with pytest.raises(ConfigError, match="needs the blood-flow velocity"):
        ReferenceTrajectory(ReferenceParams(timing="flow_synchronised"))


def test_path_and_bad_input() -> None:
    ref = ReferenceTrajectory(PARAMS)
    pts = ref.path(50)
    assert pts.shape == (50, 2)
    np.testing.assert_allclose(pts[0], [0.0, 1e-3], rtol=1e-12, atol=1e-15)
    with pytest.raises(ModelInputError, match="finite"):
        ref.sample(math.nan)


def test_config_validation() -> None:
    with pytest.raises(ConfigError, match="reference.duration_s must be > 0, got -1"):
        load_dataclass(ReferenceParams, {"duration_s": -1}, "reference")
    with pytest.raises(ConfigError, match="anchors_z_m must have as many points"):
        ReferenceParams(anchors_x_m=(0.0, 1.0), anchors_z_m=(0.0,))
    with pytest.raises(ConfigError, match="repeated point"):
        ReferenceParams(anchors_x_m=(0.0, 0.0), anchors_z_m=(0.0, 0.0))


def test_propose_anchors_picks_best_delta() -> None:
    grid = np.linspace(-1e-3, 1e-3, 21)
    # a map that prefers the upper wall (artery) ...
    prm = propose_anchors(0.0, 9e-3, 4, grid, lambda d: 1.0 + d * 1e3)
    assert prm.anchors_z_m == pytest.approx((1e-3,) * 4)
    assert prm.anchors_x_m == pytest.approx((0.0, 3e-3, 6e-3, 9e-3))
    # ... and one that prefers the centre (small vessel)
    prm = propose_anchors(0.0, 9e-3, 4, grid, lambda d: 1.0 - abs(d) * 1e3)
    assert prm.anchors_z_m == pytest.approx((0.0,) * 4, abs=1e-18)
    with pytest.raises(ConfigError, match="n_anchors must be >= 2"):
        propose_anchors(0.0, 1.0, 1, grid, lambda d: 1.0)


# ------------------------------------------------------------------ planned timing and wall follow
def _planned(**kw):
    ref = ReferenceTrajectory(PARAMS)
    ts = np.linspace(0.0, 3.0, 61)
    us = ref.length_m * (ts / 3.0) ** 2 * (3.0 - 2.0 * ts / 3.0)  # a smooth rest-to-rest table
    return ReferenceParams(**{**PARAMS.__dict__, "timing": "planned", "duration_s": 3.0,
                              "planned_t_s": tuple(ts), "planned_u_m": tuple(us), **kw})


def test_planned_timing_follows_its_table_and_ends_at_the_last_anchor() -> None:
    params = _planned()
    ref = ReferenceTrajectory(params)
    u = ref.parameter_at(np.asarray(params.planned_t_s))
    np.testing.assert_allclose(u, params.planned_u_m, atol=1e-12)
    np.testing.assert_allclose(ref.sample(3.0).p, [PARAMS.anchors_x_m[-1], PARAMS.anchors_z_m[-1]], atol=1e-12)
    np.testing.assert_allclose(ref.sample(3.5).v, 0.0)  # holds its end after the table


@pytest.mark.parametrize("follow", [(0.0, 1.0, 1.0, 0.5, 0.0), (1.0,) * 5])
def test_wall_follow_moves_with_the_wall_and_its_derivatives_are_exact(follow) -> None:
    from vesselbot_ros.control.bspline_reference import lower_wall_shift

    shift = lower_wall_shift(3e-3, 0.1, 2.0 * math.pi, math.pi / 2.0)
    still = ReferenceTrajectory(_planned())
    ref = ReferenceTrajectory(_planned(wall_follow=follow), wall_shift=shift)
    ts = np.linspace(0.05, 2.95, 30)
    p0, _, _ = still.sample_many(ts)
    p, _, _ = ref.sample_many(ts)
    m, _, _ = ref.follow_weight(ref.parameter_at(ts))
    h, _, _ = shift(ts)
    np.testing.assert_allclose(p[:, 0], p0[:, 0])
    np.testing.assert_allclose(p[:, 1], p0[:, 1] - m * h, atol=1e-15)  # down by the weight times the wall's shift
    assert np.all((m >= 0.0) & (m <= 1.0))
    hstep = 1e-5
    for t in (0.31, 1.27, 2.2):
        s0, sp, sm = ref.sample(t), ref.sample(t + hstep), ref.sample(t - hstep)
        np.testing.assert_allclose((sp.p - sm.p) / (2 * hstep), s0.v, rtol=1e-5, atol=1e-9)
        np.testing.assert_allclose((sp.v - sm.v) / (2 * hstep), s0.a, rtol=1e-4, atol=1e-6)


def test_planned_timing_and_wall_follow_bad_input() -> None:
    with pytest.raises(ConfigError, match="duration_s must equal planned_t_s"):
        _planned(duration_s=2.0)
    with pytest.raises(ConfigError, match="planned_u_m must not decrease"):
        ReferenceParams(**{**_planned().__dict__, "planned_u_m": (0.0, 2e-3, 1e-3, 3e-3)[:4],
                           "planned_t_s": (0.0, 1.0, 2.0, 3.0)})
    with pytest.raises(ConfigError, match="timing 'planned' only"):
        ReferenceParams(**{**PARAMS.__dict__, "planned_t_s": (0.0, 1.0)})
    with pytest.raises(ConfigError, match=r"wall_follow\[1\] must be in \[0, 1\]"):
        ReferenceParams(**{**PARAMS.__dict__, "wall_follow": (0.0, 1.5, 0.0, 0.0, 0.0)})
    with pytest.raises(ConfigError, match="one weight per anchor"):
        ReferenceParams(**{**PARAMS.__dict__, "wall_follow": (0.0, 1.0)})
    with pytest.raises(ConfigError, match="needs the wall's motion"):
        ReferenceTrajectory(_planned(wall_follow=(1.0,) * 5))  # no wall displacement given
    short = _planned()
    with pytest.raises(ConfigError, match="must end at the path's length"):
        ReferenceTrajectory(ReferenceParams(**{**short.__dict__,
                                               "planned_u_m": tuple(0.9 * u for u in short.planned_u_m)}))


# ---- a path in three dimensions ------------------------------------------------------------------------------------
@pytest.mark.parametrize("timing", ["constant", "rest_to_rest"])
def test_a_3d_path_in_the_plane_is_the_planar_paths_doubles(timing: str) -> None:
    """Anchors with y = 0 given: the trajectory's x and z are the planar trajectory's doubles, y is 0."""
    base = ReferenceParams(anchors_x_m=(0.0, 2e-3, 5e-3, 7e-3, 9e-3), anchors_z_m=(1e-3, 0.5e-3, 0.8e-3, 0.2e-3, 0.0),
                           duration_s=1.5, timing=timing)
    flat = ReferenceTrajectory(base)
    spatial = ReferenceTrajectory(dataclasses.replace(base, anchors_y_m=(0.0,) * 5))
    ts = np.linspace(-0.1, 1.7, 901)
    for two, three in zip(flat.sample_many(ts), spatial.sample_many(ts)):
        assert three.shape == (901, 3)
        np.testing.assert_array_equal(three[:, [0, 2]], two)
        assert np.all(three[:, 1] == 0.0)
    assert "anchors_y_m" not in to_mapping(base) and to_mapping(spatial.params)["anchors_y_m"] == [0.0] * 5


def test_a_3d_path_is_c2_through_its_anchors_and_its_derivatives_are_consistent() -> None:
    """A helix-like path: it passes through its anchors, v and a are the time derivatives of p (central differences),
    and a is continuous across the anchors (C2)."""
    ang = np.linspace(0.0, 3.0, 7)
    params = ReferenceParams(anchors_x_m=tuple(2e-3 * ang), anchors_y_m=tuple(1e-3 * np.sin(ang)),
                             anchors_z_m=tuple(1e-3 * np.cos(ang)), duration_s=2.0, timing="rest_to_rest")
    ref = ReferenceTrajectory(params)
    u = ref.anchor_u_m
    np.testing.assert_allclose(np.array([ref.path_point(float(v)) for v in u]), params.anchor_points(), atol=1e-15)
    ts = np.linspace(0.05, 1.95, 381)
    h = 1e-5
    _p0, v0, a0 = ref.sample_many(ts)
    pp, vp, _ = ref.sample_many(ts + h)
    pm, vm, _ = ref.sample_many(ts - h)
    np.testing.assert_allclose((pp - pm) / (2 * h), v0, atol=1e-9 * np.abs(v0).max() + 1e-12, rtol=1e-6)
    np.testing.assert_allclose((vp - vm) / (2 * h), a0, atol=1e-6 * np.abs(a0).max(), rtol=1e-5)
    dense = np.linspace(0.0, 2.0, 200_001)
    t_anchor = np.interp(u[1:-1], ref.parameter_at(dense), dense)  # u(t) increases
    _p1, _v1, a_left = ref.sample_many(t_anchor - 1e-7)
    _p2, _v2, a_right = ref.sample_many(t_anchor + 1e-7)
    np.testing.assert_allclose(a_left, a_right, atol=1e-4 * np.abs(a0).max())


def test_anchors_y_m_of_another_length_or_non_finite_is_one_line_naming_it() -> None:
    with pytest.raises(ConfigError, match=r"anchors_y_m must be empty or have as many points as anchors_x_m \(4\), got 2"):
        ReferenceParams(anchors_y_m=(0.0, 1e-3))
    with pytest.raises(ConfigError, match=r"anchors_y_m\[1\]"):
        ReferenceParams(anchors_y_m=(0.0, math.nan, 0.0, 0.0))


# --- issue 38 section 3: the reference's spline set-up is bounded before it starts -------------------------------


def test_a_reference_of_35000_anchors_is_refused_before_its_spline_is_built(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A 0.6 MB scenario of 35000 anchors: the old set-up made a 9.13 GiB identity matrix (and a dense solve of
    35002^2 Python floats); now one line names the key, the count and the estimate, exit 2, under a 3 GiB limit."""
    import yaml

    from vesselbot_ros.testing import cli_under_memory_limit

    n = 35000
    path = tmp_path / "many.yaml"
    path.write_text(yaml.safe_dump({"base": "sound_small_artery", "name": "many", "reference": {"anchors_x_m": [i * 1e-7 for i in range(n)],
                                                                  "anchors_z_m": [0.0] * n}}, width=1 << 30))
    proc = cli_under_memory_limit(["simulate", "--config", str(path), "--out", str(tmp_path / "out")], timeout=60)
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr and "MemoryError" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "reference.anchors_x_m=35000 points: the reference's B-spline set-up needs about" in lines[0]
    assert "GiB of memory" in lines[0] and "use fewer anchors" in lines[0]
    assert not (tmp_path / "out").exists()


def test_the_anchor_bound_is_the_resource_check_s_estimate(monkeypatch: pytest.MonkeyPatch) -> None:
    from vesselbot_ros import resources
    from vesselbot_ros.resources import spline_setup_cost

    monkeypatch.setattr(resources, "memory_budget_bytes", lambda: 8 * 2**30)  # a machine of 16 GiB

    b, s = spline_setup_cost(35000)
    assert b == pytest.approx(112.0 * 35002 ** 2) and s == pytest.approx(0.8e-6 * 35002 ** 2)
    pts = np.linspace(0.0, 9e-3, 2000)
    ReferenceParams(anchors_x_m=tuple(pts), anchors_z_m=(0.0,) * 2000)  # 0.45 GB, 3 s: fits a machine's budget
    with pytest.raises(ConfigError, match=r"^anchors_x_m=20000 points: the reference's B-spline set-up needs about "
                                          r"41\.7 GiB of memory, more than the 8\.0 GiB"):
        ReferenceParams(anchors_x_m=tuple(np.linspace(0.0, 9e-3, 20000)), anchors_z_m=(0.0,) * 20000)


def test_flow_synchronised_along_the_path_drifts_with_the_blood_along_a_route_that_turns() -> None:
    """``sync_along: path`` on a route that climbs and turns back in 3-D (dx/du changes sign on the way, where the
    printed ``x`` reading divides by it): the reference's speed along the path is c times the blood's along the
    tangent."""
    ys, zs = (0.0, 2e-3, 4e-3, 4e-3, 2e-3), (0.0, 1e-3, 4e-3, 8e-3, 10e-3)
    kw = dict(anchors_x_m=(0.0, 3e-3, 5e-3, 3e-3, 0.0), anchors_y_m=ys, anchors_z_m=zs, duration_s=1.0,
              timing="flow_synchronised", sync_ratio=0.8)
    flow = np.array([0.004, 0.003, 0.012])

    def vf(t: float, p: np.ndarray) -> np.ndarray:
        return flow * (1.0 + 0.3 * math.sin(2 * math.pi * t))

    ref = ReferenceTrajectory(ReferenceParams(**kw, sync_along="path"), flow_velocity=vf)
    for t in (0.1, 0.35, 0.7):
        s = ref.sample(t)
        u = ref.parameter_at(t)[0]
        tangent = np.asarray(ref._d1(u))
        tangent /= np.linalg.norm(tangent)
        assert np.linalg.norm(s.v) > 0.0
        assert s.v @ tangent == pytest.approx(0.8 * vf(t, s.p) @ tangent, rel=1e-3)
    assert ReferenceParams(**kw, sync_along="path").sync_along == "path"
    with pytest.raises(ConfigError, match="sync_along"):
        ReferenceParams(**kw, sync_along="y")
