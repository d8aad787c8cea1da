"""Tests of the rational profile, its fitter and the default table."""

import numpy as np
import pytest

from vesselbot_ros.config import ConfigError
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.bifurcation import (
    fit_profile_table,
    fit_profiles_csv,
    fit_rational_profile,
    load_profile_table,
    rational_profile,
    rational_profile_at,
    save_profile_table,
)


def test_rational_profile_hand_value():
    y, a, b, c, d, e, p, q = 0.5, -0.4, 0.1, 0.3, 0.2, 0.15, 0.4, 0.3
    expected = a * 0.25 + b * 0.5 + c + (d * 0.5 + e) / ((0.5 - 0.4) ** 2 + 0.09)
    assert float(rational_profile(y, a, b, c, d, e, p, q)) == pytest.approx(expected, rel=1e-14)


def test_fitter_recovers_known_parameters_from_noisy_samples():
    true = np.array([-0.6, 0.1, 0.35, 0.05, 0.12, 0.45, 0.25])
    y = np.linspace(-1, 1, 81)
    rng = np.random.default_rng(42)
    u = rational_profile(y, *true) + rng.normal(scale=2e-3, size=y.size)
    fit = fit_rational_profile(y, u)
    assert fit.rms < 3e-3
    assert fit.params[5] == pytest.approx(true[5], abs=0.02)  # pole position p
    assert fit.params[6] == pytest.approx(true[6], abs=0.02)  # pole width q
    np.testing.assert_allclose(fit.params[:5], true[:5], atol=0.03)
    np.testing.assert_allclose(rational_profile(y, *fit.params), rational_profile(y, *true), atol=5e-3)


def test_fitter_rejects_bad_input():
    with pytest.raises(ModelInputError, match="same size >= 8"):
        fit_rational_profile([0, 1], [0, 1])
    with pytest.raises(ModelInputError, match="must be finite"):
        fit_rational_profile(np.linspace(-1, 1, 10), np.full(10, np.nan))


def test_csv_round_trip(tmp_path):
    truth = {0.0: (-0.8, 0.0, 0.8, 0.02, 0.1, 0.3, 0.4), 20.0: (-0.6, 0.1, 0.5, 0.05, 0.12, 0.45, 0.3)}
    y = np.linspace(-1, 1, 41)
    path = tmp_path / "cfd.csv"
    with path.open("w") as fh:
        fh.write("# an exported CFD profile\ntheta_deg,y,u,extra\n")
        for th, prm in truth.items():
            for yy, uu in zip(y, rational_profile(y, *prm)):
                fh.write(f"{th},{yy},{uu},0\n")
    table, rms = fit_profiles_csv(path)
    assert rms[0.0] < 1e-3 and rms[20.0] < 1e-3  # densified angles in between are blends, not rational
    np.testing.assert_allclose(table.profile(y, 20.0), rational_profile(y, *truth[20.0]), atol=2e-3)
    save_profile_table(table, tmp_path / "table.csv", "test")
    back = load_profile_table(str(tmp_path / "table.csv"))
    np.testing.assert_allclose(back.values, table.values, rtol=1e-15, atol=1e-15)
    np.testing.assert_allclose(back.slopes, table.slopes, rtol=1e-12, atol=1e-12)


def test_csv_errors(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("theta,y,u\n0,0,0\n")
    with pytest.raises(ConfigError, match="lacks columns"):
        fit_profiles_csv(bad)
    with pytest.raises(ConfigError, match="does not exist"):
        fit_profiles_csv(tmp_path / "missing.csv")
    with pytest.raises(ConfigError, match="at least 2 angles"):
        fit_profile_table({0.0: (np.linspace(-1, 1, 10), np.zeros(10))})


def test_reconstruction_table_is_still_available():
    t = load_profile_table("reconstruction")
    y = np.linspace(-1, 1, 201)
    np.testing.assert_allclose(t.profile(y, 0.0), 1 - y * y, atol=1e-6)


def test_default_table_is_the_fit_to_our_cfd_samples():
    from vesselbot_ros.physics.bifurcation import CFD_SAMPLES, read_profile_samples

    t = load_profile_table()
    samples = read_profile_samples(CFD_SAMPLES)
    assert set(samples) <= set(t.knots_deg.tolist())
    for th, (y, u) in samples.items():
        rms = float(np.sqrt(np.mean((t.profile(y, th) - u) ** 2)))
        assert rms < 0.03, (th, rms)
    # the apex: the parent's centreline velocity cancels at 30 deg (Fig. 6), the daughter is parabolic at 60 deg
    y0 = np.array([0.0])
    assert float(samples[30.0][1][len(samples[30.0][1]) // 2]) < 0.05
    assert float(t.profile(y0, 60.0)[0]) == pytest.approx(float(np.max(samples[60.0][1])), rel=0.02)


def test_default_table_is_sane_and_smooth():
    t = load_profile_table()
    y = np.linspace(-1, 1, 201)
    np.testing.assert_allclose(t.profile(y, 0.0), 0.97 * (1 - y * y), atol=0.02)  # CFD: 1 mm before the node
    thetas = np.linspace(t.knots_deg[0], t.knots_deg[-1], 241)
    profiles = np.array([t.profile(y, th) for th in thetas])
    assert profiles.max() < 1.1 and profiles.min() > -0.15
    assert np.max(np.abs(profiles[:, [0, -1]])) < 0.1  # ~no slip at both walls
    # continuous in theta: at most 0.1 V_f per 0.25 deg (the CFD's centreline velocity falls from 0.47 to 0.02
    # between 25 and 30 deg, where the section meets the apex)
    assert np.max(np.abs(np.diff(profiles, axis=0))) < 0.1
    # jitable scalar evaluator agrees with the numpy one
    vals, slopes = t.values.ravel(), t.slopes.ravel()
    for th in (12.3, 27.0, 44.4):
        for yy in (-0.7, 0.0, 0.55):
            assert float(rational_profile_at(yy, th, t.knots_deg, vals, slopes)) == pytest.approx(float(t.profile(yy, th)), abs=1e-9)
