"""The learned baseline end to end: PPO trains a few thousand steps, is saved, and flies as the policy kind.

Needs the optional ``learn`` extra (``requirements-learn.txt``: stable-baselines3 and torch), which ``make test``
installs only when asked (``VESSELBOT_EXTRAS=learn make test``, as ``.ci/run`` does): without it the test is skipped
and says why.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3", reason="the optional learn extra is not installed "
                    "(VESSELBOT_EXTRAS=learn make test, or pip install -r requirements-learn.txt): "
                    "stable-baselines3 and torch")

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def train_ppo():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("train_ppo", ROOT / "tools" / "train_ppo.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["train_ppo"] = mod  # the policy kind imports it by name (train_ppo:act)
    spec.loader.exec_module(mod)
    return mod


def test_ppo_trains_saves_and_flies_as_the_policy_kind(train_ppo, tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    path, curve, took = train_ppo.train("Straight", 4096, tmp_path, envs=2, seed=0)
    assert path.is_file() and path.with_suffix(".meta").is_file() and took > 0.0
    assert curve and all(np.isfinite(r) for _s, r in curve)  # episodes of 2000 steps ended, their returns logged
    train_ppo.plot_curves({"Straight": curve}, tmp_path / "curve.png")
    assert (tmp_path / "curve.png").stat().st_size > 1000
    monkeypatch.setenv(train_ppo.MODEL_ENV, str(path))
    rows = train_ppo.evaluate("Straight", path, [0], 4096, took, sets=["sim.duration_s=0.2"])
    assert [r["controller"] for r in rows] == ["law24", "ekf", f"PPO ({path.name})"]
    ppo = rows[-1]
    assert ppo["seeds"] == 1 and np.isfinite(ppo["tracking_worst_m"]) and ppo["training_steps"] == 4096
