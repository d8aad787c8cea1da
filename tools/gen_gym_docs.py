#!/usr/bin/env python3
"""docs/gym.md's generated blocks: the reward's defaults, the benchmark table and (``--bench``) the bench figures.

Blocks (``tools/doc_sections.py``):

* ``gym_reward``: :class:`~vesselbot_ros.envs.copies.RewardParams`' fields and defaults;
* ``gym_benchmark``: ``vesselbot benchmark`` over every tier, the shipped controllers (law (24), the EKF loop,
  ``predictive``), seeds 0-4 (:func:`vesselbot_ros.analysis.benchmark.benchmark`; about half a minute once numba's
  cache is warm);
* ``gym_bench`` (``--bench``): ``bench/bench_env.py``'s figures, one second per figure, with the machine's load
  average (wall-clock figures: other jobs on the machine stretch them);
* ``gym_ppo``: the learned baseline's evaluation beside the shipped controllers, read from
  ``docs/gym/ppo_eval.csv`` (written by ``tools/train_ppo.py``) when that file exists.

Usage: .venv/bin/python tools/gen_gym_docs.py [--write] [--bench]
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import importlib.util
import os
import sys
from pathlib import Path

from vesselbot_ros.analysis.benchmark import CONTROLLERS, benchmark, markdown_table
from vesselbot_ros.atomic_io import write_text
from vesselbot_ros.envs.copies import RewardParams
from vesselbot_ros.envs.registration import TIERS
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "gym.md"
PPO_EVAL = ROOT / "docs" / "gym" / "ppo_eval.csv"
sys.path.insert(0, str(ROOT / "tools"))
from doc_sections import replace_section  # noqa: E402 - tools/ is not a package: its path first

#: What each reward parameter means, in the block's words (its unit where it has one).
MEANING = {
    "error_scale_m": ("tracking error that costs 1 per step", 1.0, "m"),
    "energy_weight": ("weight of the applied gradient's squared norm over the coil's maximum squared", 1.0, ""),
    "lumen_penalty": ("subtracted on the step the robot's centre leaves the lumen (the episode ends)", 1.0, ""),
    "outlet_bonus": ("added on the step the robot reaches the route's outlet (the episode ends)", 1.0, ""),
    "goal_radius_m": ("distance to the route's end that counts as reached", 1.0, "m"),
    "contact_ends_episode": ("any wall contact ends the episode as leaving the lumen does", 1.0, ""),
}


def reward_block() -> str:
    """The reward's parameters and defaults as a Markdown table."""
    lines = ["| `reward=` key | default | meaning |", "|---|---|---|"]
    for f in dataclasses.fields(RewardParams):
        what, scale, unit = MEANING[f.name]
        v = f.default
        text = str(v).lower() if isinstance(v, bool) else f"{float(v) * scale:g}{' ' + unit if unit else ''}"
        lines.append(f"| `{f.name}` | {text} | {what} |")
    return "\n".join(lines) + "\n"


def benchmark_block() -> str:
    """Every tier, the shipped controllers, seeds 0-4."""
    rows, notes = benchmark(list(TIERS), list(CONTROLLERS), range(5))
    text = markdown_table(rows)
    if notes:
        text += "\n" + "".join(f"- {n}\n" for n in notes)
    return text


def bench_block() -> str:
    """bench/bench_env.py's figures, one second each."""
    spec = importlib.util.spec_from_file_location("bench_env", ROOT / "bench" / "bench_env.py")
    assert spec is not None and spec.loader is not None
    be = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(be)
    sc = load_scenario(TIERS["Straight"])
    actions = run_closed_loop(sc, 0).timeseries["g_cmd"]
    loop1, loop2 = be.loop_rate(sc, 1.0)
    scalar = be.scalar_rate(sc, actions, 1.0)
    vec1 = be.vector_rate(sc, actions, 256, 1, 1.0)
    vec2 = be.vector_rate(sc, actions, 256, 2, 1.0)
    one, five, _ = os.getloadavg()
    return "\n".join([
        f"`bench/bench_env.py --seconds 1` on `{sc.name}` ({sc.sim.n_ticks} ticks per episode), load average "
        f"{one:.2f} (1 min) / {five:.2f} (5 min) on {os.cpu_count()} cores:",
        "",
        "| what | rate | target | met |",
        "|---|---|---|---|",
        f"| compiled loop, 1 thread (CPU time) | {loop1:,.0f} ticks/s | | |",
        f"| compiled loop, 2 threads (wall time) | {loop2:,.0f} ticks/s | | |",
        f"| scalar environment, 1 thread (CPU time) | {scalar:,.0f} steps/s | >= 50,000 steps/s | "
        f"{'yes' if scalar >= 50_000 else 'no'} |",
        f"| scalar environment's overhead over the loop's tick | {loop1 / scalar:.2f}x | <= 2x | "
        f"{'yes' if loop1 / scalar <= 2 else 'no'} |",
        f"| vector environment, 256 copies, 1 thread (CPU time) | {vec1:,.0f} steps/s | | |",
        f"| vector environment, 256 copies, 2 threads (wall time) | {vec2:,.0f} steps/s = {vec2 / loop2:.2f}x the loop "
        f"on 2 threads | >= 0.8x | {'yes' if vec2 / loop2 >= 0.8 else 'no'} |",
        f"| vector environment's overhead over the loop's tick (1 thread) | {loop1 / vec1:.2f}x | <= 1.2x | "
        f"{'yes' if loop1 / vec1 <= 1.2 else 'no'} |",
    ]) + "\n"


def ppo_block() -> str | None:
    """The learned baseline's evaluation (docs/gym/ppo_eval.csv), or None if it was not trained here."""
    if not PPO_EVAL.is_file():
        return None
    with PPO_EVAL.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    head = ["tier", "controller", "seeds", "success", "tracking mean (um)", "tracking worst (um)",
            "outside lumen (ms)", "energy (T^2 s/m^2)", "not ok", "training steps", "training time (s)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        lines.append(
            f"| {r['tier']} | {r['controller']} | {r['seeds']} | {float(r['success']) * 100:.0f} % | "
            f"{float(r['tracking_mean_m']) * 1e6:.1f} | {float(r['tracking_worst_m']) * 1e6:.1f} | "
            f"{float(r['outside_lumen_s']) * 1e3:.1f} | {float(r['energy_T2s_per_m2']):.4g} | {r['not_ok']} | "
            f"{r.get('training_steps') or '-'} | {r.get('training_s') or '-'} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--write", action="store_true", help="rewrite docs/gym.md's blocks")
    ap.add_argument("--bench", action="store_true", help="also time bench/bench_env.py's figures (about 20 s)")
    args = ap.parse_args()
    blocks = {"gym_reward": reward_block(), "gym_benchmark": benchmark_block()}
    if args.bench:
        blocks["gym_bench"] = bench_block()
    ppo = ppo_block()
    if ppo is not None:
        blocks["gym_ppo"] = ppo
    for name, body in blocks.items():
        print(f"<!-- {name} -->\n{body}")
    if args.write:
        doc = DOC.read_text(encoding="utf-8")
        for name, body in blocks.items():
            doc = replace_section(doc, name, body, "docs/gym.md")
        write_text(DOC, doc)
        print(f"wrote {DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
