#!/usr/bin/env python3
"""A learned baseline: PPO (stable-baselines3) trained on the environments' tiers, evaluated beside the shipped loops.

Needs the ``learn`` extra, which ``make run`` does not install (``VESSELBOT_EXTRAS=learn make test`` does)::

    .venv/bin/pip install -r requirements-learn.txt

For each tier (``--tiers``, default Straight and Network) it trains PPO's MLP policy for ``--steps`` environment
steps on ``gymnasium.make("vesselbot/<Tier>-v0")`` (the default reward; ``--envs`` copies in a ``DummyVecEnv``), then

* saves the policy (``<out>/ppo_<tier>.zip``) and its training curve (``<out>/ppo_training.png``: each episode's
  return against the steps taken, one line per tier);
* evaluates it with ``vesselbot benchmark``'s code over ``--eval-seeds`` (default 0-99) beside law (24) and the EKF
  loop, the policy run as the ``policy`` controller kind (:func:`act`), and writes ``<out>/ppo_eval.csv`` (the
  rows, with the training steps and time) which ``tools/gen_gym_docs.py --write`` puts in docs/gym.md.

The agent sees :func:`features` of the observation: the estimate's error against the reference (in mm and cm/s),
the reference's acceleration, the applied gradient over the coil's maximum, the measurement's age and the scanner's
phase; its action in [-1, 1] per axis is the gradient over the coil's maximum.  :func:`act` applies the same map
to a raw observation, so the saved policy runs as a controller by name:
``VESSELBOT_PPO_MODEL=<out>/ppo_straight.zip PYTHONPATH=tools vesselbot simulate --set controller.kind=policy
--set controller.policy=train_ppo:act``.

Usage: python tools/train_ppo.py [--tiers Straight,Network] [--steps 200000] [--envs 4] [--eval-seeds 0-99]
[--out docs/gym] [--seed 0]
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import os
import sys
import time
from functools import cache
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import numpy.typing as npt

import vesselbot_ros.envs  # noqa: F401  (registers vesselbot/...)
from vesselbot_ros.analysis.benchmark import benchmark, parse_seeds
from vesselbot_ros.control.policy import observation_fields

ROOT = Path(__file__).resolve().parents[1]
#: The environment variable :func:`act` reads the saved policy's path from.
MODEL_ENV = "VESSELBOT_PPO_MODEL"


def features(obs: npt.NDArray[np.float64], dims: int, g_max: float) -> npt.NDArray[np.float32]:
    """What the agent sees of an observation (without the true state): the estimate's position error (mm) and
    velocity error (cm/s) against the reference, the reference's acceleration (m/s^2), the applied gradient over
    ``g_max``, the measurement's age (s) and, under a sequence, the scanner's phase."""
    f = dict(observation_fields(dims, len(obs) > 6 * dims + 1, False))
    parts = [(obs[f["p_ref_m"]] - obs[f["x_hat_m"]]) * 1e3, (obs[f["v_ref_m_per_s"]] - obs[f["z_hat_m_per_s"]]) * 1e2,
             obs[f["a_ref_m_per_s2"]], obs[f["g_applied_T_per_m"]] / g_max, obs[f["measurement_age_s"]]]
    if "sequence_phase" in f:
        parts.append(obs[f["sequence_phase"]])
    return np.concatenate(parts).astype(np.float32)


class Features(gymnasium.Wrapper):  # type: ignore[type-arg]
    """The environment as the agent trains on it: :func:`features` in, the gradient over the coil's maximum out."""

    def __init__(self, env: gymnasium.Env) -> None:  # type: ignore[type-arg]
        super().__init__(env)
        inner: Any = env.unwrapped
        self.dims, self.g_max = int(inner.dims), float(inner.loop.g_max_T_per_m)
        n = features(np.zeros(inner.observation_space.shape[0]), self.dims, self.g_max).size
        self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (n,), np.float32)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (self.dims,), np.float32)

    def reset(self, **kwargs: Any) -> tuple[npt.NDArray[np.float32], dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        return features(obs, self.dims, self.g_max), info

    def step(self, action: Any) -> tuple[npt.NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        g = self.g_max * np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        obs, r, term, trunc, info = self.env.step(g)
        return features(obs, self.dims, self.g_max), float(r), term, trunc, info


@cache
def _model(path: str) -> Any:
    from stable_baselines3 import PPO  # deferred: the learn extra, only where a policy runs

    return PPO.load(path, device="cpu")


def act(obs: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """The saved policy (``$VESSELBOT_PPO_MODEL``) as the ``policy`` controller kind's callable: a raw observation
    to the gradient (T/m).  The coil's maximum is read from the model's file name's sidecar (``.json``)."""
    path = os.environ.get(MODEL_ENV, "")
    if not path:
        raise RuntimeError(f"set {MODEL_ENV} to a policy saved by tools/train_ppo.py")
    model = _model(path)
    dims, g_max = _meta(path)
    a, _ = model.predict(features(np.asarray(obs, dtype=np.float64), dims, g_max), deterministic=True)
    return g_max * np.clip(np.asarray(a, dtype=np.float64), -1.0, 1.0)


@cache
def _meta(path: str) -> tuple[int, float]:
    text = Path(path).with_suffix(".meta").read_text(encoding="utf-8").split()
    return int(text[0]), float(text[1])


def train(tier: str, steps: int, out: Path, envs: int = 4, seed: int = 0) -> tuple[Path, list[tuple[int, float]], float]:
    """PPO on ``vesselbot/<tier>-v0`` for ``steps`` steps: the saved policy's path, the curve ((steps taken, an
    episode's return) per finished episode) and the training's wall time (s)."""
    import torch  # deferred: the learn extra
    from stable_baselines3 import PPO  # deferred: the learn extra
    from stable_baselines3.common.callbacks import BaseCallback  # deferred: the learn extra
    from stable_baselines3.common.env_util import make_vec_env  # deferred: the learn extra

    torch.set_num_threads(1)
    curve: list[tuple[int, float]] = []

    class Curve(BaseCallback):
        def _on_step(self) -> bool:
            for info in self.locals.get("infos", []):
                if "episode" in info:
                    curve.append((int(self.num_timesteps), float(info["episode"]["r"])))
            return True

    vec = make_vec_env(lambda: Features(gymnasium.make(f"vesselbot/{tier}-v0")), n_envs=envs, seed=seed)
    model = PPO("MlpPolicy", vec, seed=seed, device="cpu", verbose=0, n_steps=max(64, 2048 // envs), batch_size=64)
    t0 = time.perf_counter()
    model.learn(total_timesteps=int(steps), callback=Curve())
    took = time.perf_counter() - t0
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"ppo_{tier.lower()}.zip"
    model.save(path)
    inner: Any = vec.envs[0]
    w = inner if isinstance(inner, Features) else next(e for e in _chain(inner) if isinstance(e, Features))
    path.with_suffix(".meta").write_text(f"{w.dims} {w.g_max!r}\n", encoding="utf-8")
    vec.close()
    return path, curve, took


def _chain(env: Any) -> list[Any]:
    out = []
    while env is not None:
        out.append(env)
        env = getattr(env, "env", None)
    return out


def plot_curves(curves: dict[str, list[tuple[int, float]]], path: Path) -> None:
    """Each tier's episode returns against the steps taken."""
    import matplotlib  # deferred: figures only

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: figures only

    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    for tier, pts in curves.items():
        if pts:
            x, y = zip(*pts, strict=True)
            ax.plot(x, y, marker=".", lw=0.8, label=tier)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("episode return (default reward)")
    ax.set_title("PPO (stable-baselines3) on the vesselbot tiers")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def evaluate(tier: str, model: Path, seeds: list[int], steps: int, took: float,
             sets: list[str] | None = None) -> list[dict[str, Any]]:
    """The benchmark's rows of law (24), the EKF loop and the policy on ``tier`` over ``seeds``."""
    os.environ[MODEL_ENV] = str(model)
    _model.cache_clear()
    _meta.cache_clear()
    here = str(Path(__file__).resolve().parent)
    if here not in sys.path:
        sys.path.insert(0, here)
    rows, _notes = benchmark([tier], ["law24", "ekf", "policy"], seeds, policy="train_ppo:act", sets=sets or [],
                             workers=1)
    out = []
    for r in rows:
        d = dataclasses.asdict(r)
        if r.controller.startswith("policy"):
            d.update(controller=f"PPO ({model.name})", training_steps=steps, training_s=f"{took:.0f}")
        out.append(d)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tiers", default="Straight,Network")
    ap.add_argument("--steps", type=int, default=200_000)
    ap.add_argument("--envs", type=int, default=4)
    ap.add_argument("--eval-seeds", default="0-99")
    ap.add_argument("--out", default=str(ROOT / "docs" / "gym"))
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    out = Path(args.out)
    seeds = parse_seeds(args.eval_seeds)
    curves, rows = {}, []
    for tier in [t.strip() for t in args.tiers.split(",") if t.strip()]:
        path, curve, took = train(tier, args.steps, out, args.envs, args.seed)
        curves[tier] = curve
        print(f"{tier}: {args.steps} steps in {took:.0f} s, {len(curve)} episodes, saved {path}", flush=True)
        rows += evaluate(tier, path, seeds, args.steps, took)
    plot_curves(curves, out / "ppo_training.png")
    keys = ["tier", "controller", "scenario", "seeds", "success", "tracking_mean_m", "tracking_worst_m",
            "outside_lumen_s", "energy_T2s_per_m2", "not_ok", "training_steps", "training_s"]
    with (out / "ppo_eval.csv").open("w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    for r in rows:
        print(r)
    print(f"wrote {out / 'ppo_eval.csv'}, {out / 'ppo_training.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
