"""Tests of the Fig. 7 design maps."""

import math

import numpy as np
import pytest

from vesselbot_ros.analysis.design_map import (
    DesignStudy,
    GridParams,
    VesselCase,
    all_design_maps,
    design_map,
    load_forces,
    summarize,
)
from vesselbot_ros.config import ConfigError
from vesselbot_ros.physics.blood_viscosity import blood_viscosity
from vesselbot_ros.physics.params import PhysicsParams

P = PhysicsParams()
SMALL = DesignStudy(grid=GridParams(n_lambda=21, n_delta=11))


def test_bp_ratio_at_centreline_by_hand():
    vessel = VesselCase("test", 1e-3, 0.02)
    m = design_map(vessel, "BP", P, SMALL)
    i = 5
    lam = m.lam[i]
    r = lam * 0.5e-3
    j = 5  # xi = 0: centreline, interactions cancel
    assert m.xi[j] == 0.0
    eta = float(blood_viscosity(1e-3, 0.45, 5e-3))
    f = (1 + (lam / 0.29) ** 1.5) / (1 - lam**1.5)
    u = 0.02
    re = 2 * r * 1060 * f * u / eta
    drag = 0.5 * 1060 * (f * u) ** 2 * math.pi * r * r * (24 / re + 6 / (1 + math.sqrt(re)) + 0.4)
    vol = 4 / 3 * math.pi * r**3
    weight = vol * (6599.2 - 1060) * 9.81
    fm = 0.8 * vol * 1.72e6 * 0.08
    assert m.ratio[i, j] == pytest.approx(fm / math.hypot(drag, weight), rel=1e-9)


def test_maps_shape_and_symmetry_breaking():
    maps = all_design_maps(P, SMALL)
    assert len(maps) == 12
    for m in maps:
        assert m.ratio.shape == (21, 11) and np.all(np.isfinite(m.ratio)) and np.all(m.ratio > 0)
    bp_art = next(m for m in maps if m.vessel == "small_artery" and m.design == "BP")
    # attraction to the upper wall offsets the weight: upper wall better than lower wall
    assert np.all(bp_art.ratio[:, -1] > bp_art.ratio[:, 0])


def test_interaction_terms_cancel_on_the_centreline():
    t = load_forces(np.array([1e-4]), np.array([0.0]), 1e-3, 0.02, 0.01, P)
    for name in ("van_der_waals", "electrostatic", "steric"):
        assert t[name][1][0] == 0.0


def test_summary_range_contains_argmax():
    m = design_map(VesselCase("test", 1e-3, 0.02), "BP", P, SMALL)
    s = summarize(m)
    assert s.max_ratio == pytest.approx(float(m.ratio.max()))
    assert s.lam_range_90[0] <= s.lam_at_max <= s.lam_range_90[1]


def test_config_errors():
    with pytest.raises(ConfigError, match="lambda_max must be in"):
        GridParams(lambda_min=0.5, lambda_max=0.4)
    with pytest.raises(ConfigError, match=r"design_study.vessels\[0\].diameter_m must be > 0"):
        DesignStudy.from_mapping({"vessels": [{"name": "a", "diameter_m": -1.0, "velocity_m_per_s": 1.0}]})
    with pytest.raises(ConfigError, match="design must be one of"):
        design_map(VesselCase(), "XX", P, SMALL)  # type: ignore[arg-type]


def test_a_study_whose_maps_would_not_fit_is_refused_before_any_map(tmp_path):  # type: ignore[no-untyped-def]
    """2000 vessels x 3 designs on 1000 x 1000 points: 144 GB of kept maps (the old study computed them one by one
    until the memory ran out); one line naming the key, the count and the estimate, exit 2, under a 3 GiB limit."""
    import yaml

    from vesselbot_ros.testing import cli_under_memory_limit

    vessels = [{"name": f"v{i}", "diameter_m": 1e-3, "velocity_m_per_s": 0.02} for i in range(2000)]
    path = tmp_path / "study.yaml"
    path.write_text(yaml.safe_dump({"design_study": {"vessels": vessels, "grid": {"n_lambda": 1000, "n_delta": 1000}}}))
    proc = cli_under_memory_limit(["design-map", "--study-config", str(path), "--no-png", "--out", str(tmp_path / "o")],
                                  timeout=60)
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr and "MemoryError" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "design_study.vessels=2000 vessels: the 6000 maps of 1000000 points needs about 134.6 GiB" in lines[0]
    assert not (tmp_path / "o").exists()
