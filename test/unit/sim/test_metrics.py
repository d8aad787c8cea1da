"""Tests of compute_metrics on hand-built time series."""

from __future__ import annotations

import numpy as np
import pytest

from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.sim.metrics import compute_metrics


def _series(n: int = 10) -> dict[str, np.ndarray]:
    t = np.arange(n) * 0.1
    p = np.zeros((n, 2))
    ref = np.zeros((n, 2))
    ref[:, 0] = np.where(t >= 0.6 - 1e-12, 3e-6, 50e-6)  # 3 um after 0.6 s
    ref[:, 1] = np.where(t >= 0.6 - 1e-12, 4e-6, 0.0)  # -> |e| = 5 um after 0.6 s
    return {
        "t_s": t, "p_true": p, "v_true": np.zeros((n, 2)), "p_ref": ref,
        "x_hat": p + np.array([1e-6, 0.0]), "z_hat": np.zeros((n, 2)),
        "g_applied": np.tile([0.03, 0.04], (n, 1)),
        "saturated": np.array([0, 1, 1, 0, 0, 0, 0, 0, 0, 0], bool),
        "slew_limited": np.zeros((n, 2), bool),
        "in_contact": np.array([0, 1, 1, 0, 1, 0, 0, 0, 1, 1], bool),
    }


def test_hand_computed_metrics() -> None:
    m = compute_metrics(_series(), after_s=0.6)
    assert m["tracking_error_max_m"] == pytest.approx(5e-6, rel=1e-12)
    assert m["tracking_error_rms_m"] == pytest.approx(5e-6, rel=1e-12)
    assert m["tracking_error_max_all_m"] == pytest.approx(50e-6, rel=1e-12)
    assert m["estimation_error_max_m"] == pytest.approx(1e-6, rel=1e-12)
    assert m["saturation_time_s"] == pytest.approx(0.2)
    assert m["wall_contacts"] == 3
    assert m["contact_time_s"] == pytest.approx(0.5)
    assert m["max_gradient_T_per_m"] == pytest.approx(0.05)


def test_missing_key_and_bad_lengths() -> None:
    s = _series()
    del s["x_hat"]
    with pytest.raises(ModelInputError, match="lacks key"):
        compute_metrics(s)
    s = _series()
    s["p_ref"] = s["p_ref"][:5]
    with pytest.raises(ModelInputError, match=r"timeseries\['p_ref'\] has 5 rows"):
        compute_metrics(s)


def test_missing_samples_are_left_out_not_propagated():
    from vesselbot_ros.sim.metrics import compute_metrics

    n = 10
    t = np.arange(n) * 1e-3
    p = np.zeros((n, 2))
    ref = np.zeros((n, 2))
    ref[:, 1] = 1e-4  # 100 um tracking error everywhere
    g = np.zeros((n, 2))
    g[:, 0] = 0.05
    g[3] = np.nan  # a coil sample that never arrived
    ref[5] = np.nan
    ts = {"t_s": t, "p_true": p, "v_true": p, "p_ref": ref, "x_hat": p, "z_hat": p, "g_applied": g,
          "saturated": np.zeros(n, bool), "slew_limited": np.zeros(n, bool), "in_contact": np.zeros(n, bool)}
    m = compute_metrics(ts, after_s=0.0)
    assert m["max_gradient_T_per_m"] == pytest.approx(0.05)
    assert m["tracking_error_max_m"] == pytest.approx(1e-4)
    assert m["tracking_error_rms_m"] == pytest.approx(1e-4)
