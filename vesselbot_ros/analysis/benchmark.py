"""The environments' benchmark: a controller kind or a user's policy on each task tier over fixed seeds.

``vesselbot benchmark`` (:mod:`vesselbot_ros.analysis.benchmark_cli`) runs, on each tier of
:data:`~vesselbot_ros.envs.registration.TIERS` (its default scenario), the runs of one controller per seed and
summarises them in one row per (tier, controller):

==================  ==========================================================================================
controller          the run
==================  ==========================================================================================
``law24``           the tier's scenario as shipped: law (24) with the scenario's own observer
``ekf``             the tier's ``<scenario>_ekf`` shipped scenario (the EKF loop), where one is shipped
``predictive``      the tier's scenario with ``controller.kind=predictive`` (its own observer)
``policy``          the tier's scenario with ``controller.kind=policy`` and ``controller.policy=module:callable``
                    (:mod:`vesselbot_ros.control.policy`): the callable sees the environments' observation and
                    commands the gradient, as an agent does in ``gymnasium.make("vesselbot/<Tier>-v0")``
==================  ==========================================================================================

Every run goes through :func:`~vesselbot_ros.sim.closed_loop.run_many` (the compiled loop for the shipped
controllers; the per-tick loop for a policy, whose numbers are the environment's: ``test/unit/control/test_policy.py``).
Columns of a row (:class:`BenchmarkRow`), over the seeds:

* ``success``: the fraction of runs that reached the path's end without leaving the lumen and without diverging.
  On a route (``reference.route_outlet``) the end is the route's outlet as the environment defines it: the robot
  comes within ``goal_radius_m`` (:class:`~vesselbot_ros.envs.copies.RewardParams`) of the planned route's last
  anchor (:func:`~vesselbot_ros.envs.copies.route_end`) before any tick outside the lumen.  Without a route the
  run must stay in the lumen throughout and end within ``goal_radius_m`` of the reference's last point;
* ``tracking_mean_m``: the mean over seeds of each run's mean tracking error ``|p_true - p_ref|`` over the metrics
  window (ticks from ``sim.metrics_after_s`` on, as :func:`~vesselbot_ros.sim.metrics.compute_metrics` takes it);
* ``tracking_worst_m``: the largest ``tracking_error_max_m`` of the seeds (the project's metric: the max over the
  window);
* ``outside_lumen_s``: the mean time the robot's centre spent outside the lumen (the plant's wall penetration
  ``delta_m`` beyond the robot's radius: the environment's lumen exit), s;
* ``energy_T2s_per_m2``: the mean of ``∫ |G|^2 dt`` over the run, the applied gradient (T^2 s / m^2);
* ``not_ok``: runs whose status (:func:`~vesselbot_ros.sim.metrics.run_status`) is not ``ok``.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.policy import load_policy
from vesselbot_ros.envs.copies import RewardParams, route_end
from vesselbot_ros.envs.registration import TIERS
from vesselbot_ros.errors import ConfigError
from vesselbot_ros.sim.closed_loop import SimResult, run_many
from vesselbot_ros.sim.scenario import Scenario, load_scenario, shipped_scenarios

__all__ = ["CONTROLLERS", "BenchmarkRow", "parse_seeds", "tier_scenario", "run_summary", "benchmark", "format_table",
           "markdown_table"]

#: The shipped controllers' rows, in order (module docstring).
CONTROLLERS = ("law24", "ekf", "predictive")
#: Runs held in memory at once (their time series): seeds go through :func:`run_many` in chunks of this many.
CHUNK = 10
#: At most this many seeds in one benchmark.
MAX_SEEDS = 10_000


@dataclasses.dataclass(frozen=True)
class BenchmarkRow:
    """One controller on one tier over the seeds (module docstring)."""

    tier: str
    controller: str
    scenario: str
    seeds: int
    success: float
    tracking_mean_m: float
    tracking_worst_m: float
    outside_lumen_s: float
    energy_T2s_per_m2: float
    not_ok: int


def parse_seeds(text: str) -> list[int]:
    """The seeds of ``--seeds``: ``0-4``, ``0,3,7`` or a mix (``0-2,9``), each >= 0, none twice.

    Raises:
        ConfigError: anything else, in one line.
    """
    seeds: list[int] = []
    for part in str(text).split(","):
        part = part.strip()
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if m is None:
            raise ConfigError(f"--seeds must be seeds >= 0 as 'A-B' or 'A,B,C' (e.g. 0-4), got {text!r}")
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) is not None else a
        if b < a:
            raise ConfigError(f"--seeds: the range {part!r} runs backwards")
        if len(seeds) + b - a + 1 > MAX_SEEDS:
            raise ConfigError(f"--seeds: at most {MAX_SEEDS} seeds, got {text!r}")
        seeds.extend(range(a, b + 1))
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"--seeds names a seed twice: {text!r}")
    return seeds


def tier_scenario(tier: str, controller: str, policy: str | None = None,
                  sets: Sequence[str] = ()) -> Scenario | None:
    """The scenario of ``controller`` on ``tier`` (module docstring), ``sets`` (``--set KEY=VALUE``) applied; None when
    the tier has no such loop (``ekf`` without a shipped ``<scenario>_ekf``).

    Raises:
        ConfigError: an unknown tier or controller, or a policy that does not load, in one line naming it.
    """
    if tier not in TIERS:
        raise ConfigError(f"unknown tier {tier!r}; the tiers are {', '.join(TIERS)}")
    base = TIERS[tier]
    if controller == "law24":
        return load_scenario(base, sets=list(sets))
    if controller == "ekf":
        name = f"{base}_ekf"
        return load_scenario(name, sets=list(sets)) if name in shipped_scenarios() else None
    if controller == "predictive":
        return load_scenario(base, sets=["controller.kind=predictive", *sets])
    if controller == "policy":
        if not policy:
            raise ConfigError("the policy row needs --policy module:callable")
        load_policy(policy)  # a module that does not import, or no such callable: one line naming it
        return load_scenario(base, sets=["controller.kind=policy", f"controller.policy={policy}", *sets])
    raise ConfigError(f"unknown controller {controller!r}; the shipped ones are {', '.join(CONTROLLERS)} "
                      f"(a policy: --policy module:callable)")


def run_summary(scenario: Scenario, result: SimResult, goal_radius_m: float | None = None) -> dict[str, Any]:
    """One run's numbers (module docstring): ``success`` (bool), ``tracking_mean_m``, ``tracking_max_m``,
    ``outside_lumen_s``, ``energy_T2s_per_m2`` and ``status``; ``result`` must hold its time series."""
    ts, m = result.timeseries, result.metrics
    r_goal = RewardParams().goal_radius_m if goal_radius_m is None else float(goal_radius_m)
    dt = float(scenario.sim.dt_control_s)
    t = np.asarray(ts["t_s"], dtype=np.float64)
    p = np.asarray(ts["p_true"], dtype=np.float64)
    e = _norm(p - np.asarray(ts["p_ref"], dtype=np.float64))
    window = e[(t >= float(m["after_s"])) & np.isfinite(e)]
    outside = np.asarray(ts["delta_m"], dtype=np.float64) > float(scenario.physics.robot.radius_m)
    g = np.asarray(ts["g_applied"], dtype=np.float64)
    first_out = int(np.argmax(outside)) if outside.any() else t.size
    if getattr(scenario.reference, "route_outlet", ""):
        near = np.flatnonzero(_norm(p - route_end(scenario)) <= r_goal)
        reached = near.size > 0 and int(near[0]) < first_out
    else:
        last = _norm(p[-1:] - np.asarray(ts["p_ref"], dtype=np.float64)[-1:])[0]
        reached = first_out == t.size and bool(last <= r_goal)
    return {
        "success": bool(reached) and m["status"] != "diverged",
        "tracking_mean_m": float(np.mean(window)) if window.size else math.nan,
        "tracking_max_m": float(m["tracking_error_max_m"]),
        "outside_lumen_s": float(np.count_nonzero(outside) * dt),
        "energy_T2s_per_m2": float(np.sum(g * g) * dt),
        "status": str(m["status"]),
    }


def _norm(a: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    return np.sqrt(np.sum(a * a, axis=1))


def benchmark(tiers: Iterable[str], controllers: Iterable[str], seeds: Sequence[int], *, policy: str | None = None,
              sets: Sequence[str] = (), workers: int | None = None) -> tuple[list[BenchmarkRow], list[str]]:
    """The rows of ``controllers`` (names of :data:`CONTROLLERS`, or ``policy`` with ``policy``) on ``tiers`` over
    ``seeds``, tier by tier; and a note for each (tier, controller) that has no loop (no shipped ``_ekf``).

    Raises:
        ConfigError: an unknown tier or controller, no seeds, or a policy that does not load (before any run).
    """
    tiers, controllers, seeds = list(tiers), list(controllers), [int(s) for s in seeds]
    if not seeds:
        raise ConfigError("--seeds names no seed")
    plan: list[tuple[str, str, Scenario | None]] = [(t, c, tier_scenario(t, c, policy, sets))
                                                      for t in tiers for c in controllers]
    rows, notes = [], []
    for tier, ctrl, sc in plan:
        if sc is None:
            notes.append(f"{tier}: no {ctrl} loop (no shipped {TIERS[tier]}_{ctrl} scenario)")
            continue
        runs: list[dict[str, Any]] = []
        for at in range(0, len(seeds), CHUNK):
            for res in run_many(sc, seeds[at:at + CHUNK], workers=workers, keep_timeseries=True):
                runs.append(run_summary(sc, res))
        rows.append(BenchmarkRow(
            tier=tier, controller=ctrl if ctrl != "policy" else f"policy {policy}", scenario=sc.name, seeds=len(runs),
            success=sum(r["success"] for r in runs) / len(runs),
            tracking_mean_m=float(np.mean([r["tracking_mean_m"] for r in runs])),
            tracking_worst_m=float(np.max([r["tracking_max_m"] for r in runs])),
            outside_lumen_s=float(np.mean([r["outside_lumen_s"] for r in runs])),
            energy_T2s_per_m2=float(np.mean([r["energy_T2s_per_m2"] for r in runs])),
            not_ok=sum(r["status"] != "ok" for r in runs)))
    return rows, notes


_HEAD = ("tier", "controller", "scenario", "seeds", "success", "tracking mean (um)", "tracking worst (um)",
         "outside lumen (ms)", "energy (T^2 s/m^2)", "not ok")


def _cells(r: BenchmarkRow) -> tuple[str, ...]:
    return (r.tier, r.controller, r.scenario, str(r.seeds), f"{r.success * 100:.0f} %", _um(r.tracking_mean_m),
            _um(r.tracking_worst_m), f"{r.outside_lumen_s * 1e3:.1f}", f"{r.energy_T2s_per_m2:.4g}", str(r.not_ok))


def _um(v: float) -> str:
    return f"{v * 1e6:.1f}" if math.isfinite(v) else "-"


def format_table(rows: Sequence[BenchmarkRow]) -> str:
    """The rows as a plain-text table (what ``vesselbot benchmark`` prints)."""
    cells = [_HEAD, *(_cells(r) for r in rows)]
    widths = [max(len(c[i]) for c in cells) for i in range(len(_HEAD))]
    lines = ["  ".join(c[i].ljust(widths[i]) if i < 3 else c[i].rjust(widths[i]) for i in range(len(c)))
             for c in cells]
    return "\n".join(lines) + "\n"


def markdown_table(rows: Sequence[BenchmarkRow]) -> str:
    """The rows as a Markdown table (docs/gym.md's benchmark block)."""
    lines = ["| " + " | ".join(_HEAD) + " |", "|" + "---|" * len(_HEAD)]
    lines += ["| " + " | ".join(_cells(r)) + " |" for r in rows]
    return "\n".join(lines) + "\n"
