"""Scanner study (issue 12, Section III-D in numbers): what multiplexing and latency cost, and what copes.

For every gradient hardware (:data:`~vesselbot_ros.scanner.hardware.PRESETS`
amplitude and slew), every sequence timing (propulsion window, hence duty
cycle and frame rate, with the tracking window and dead time of the preset),
every latency and every observer/controller pair, run the pure closed loop of
the base scenario over a few seeds and record the tracking and estimation
errors.  A cell where the loop cannot be run (the scenario is refused, e.g.
observer (25) unstable at that frame rate) is recorded with the reason.

Pairs:

* ``paper``: observer (25) and law (24) with Table III's gains, no compensation;
* ``ekf``: the extended Kalman observer (delay compensation, flow scale)
  with law (24), Table III's gains, flow and duty-cycle compensation;
* ``ekf_fast``: the same with k1, k2 = 20, 40.

Also computed per hardware: whether the bead can hold itself against its
apparent weight at all, ``duty * U_sat >= |F_weight| / m``: below that line no
controller can track.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import math
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.input_mapping import input_matrix
from vesselbot_ros.errors import VesselbotError
from vesselbot_ros.physics.apparent_weight import apparent_weight_z
from vesselbot_ros.scanner.hardware import PRESETS
from vesselbot_ros.scanner.sequence import duty_cycle
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import Scenario, scenario_from_mapping

__all__ = ["PAIRS", "StudyCell", "study_cells", "run_cell", "hold_margin"]

PAIRS: dict[str, dict[str, Any]] = {
    "paper": {"observer": {"kind": "high_gain"},
              "controller": {"gains": {"k1": 5.0, "k2": 10.0}, "flow_compensation": "none", "duty_compensation": "none"}},
    "ekf": {"observer": {"kind": "ekf"},
            "controller": {"gains": {"k1": 5.0, "k2": 10.0}, "flow_compensation": "estimate",
                           "duty_compensation": "sequence"}},
    "ekf_fast": {"observer": {"kind": "ekf"},
                 "controller": {"gains": {"k1": 20.0, "k2": 40.0}, "flow_compensation": "estimate",
                                "duty_compensation": "sequence"}},
}


@dataclasses.dataclass(frozen=True)
class StudyCell:
    """One point of the study grid."""

    hardware: str
    propulsion_window_s: float
    latency_s: float
    pair: str


def study_cells(hardware: Iterable[str], propulsion_windows_s: Iterable[float], latencies_s: Iterable[float],
                pairs: Iterable[str]) -> list[StudyCell]:
    """The grid, in a fixed order."""
    for h in hardware:
        if h not in PRESETS:
            raise ConfigError(f"hardware must be one of {sorted(PRESETS)}, got {h!r}")
    for p in pairs:
        if p not in PAIRS:
            raise ConfigError(f"pair must be one of {sorted(PAIRS)}, got {p!r}")
    return [StudyCell(*c) for c in itertools.product(hardware, propulsion_windows_s, latencies_s, pairs)]


def _deep_update(d: dict[str, Any], u: dict[str, Any]) -> None:
    for k, v in u.items():
        if isinstance(v, dict):
            _deep_update(d.setdefault(k, {}), v)
        else:
            d[k] = v


def cell_scenario(base: Scenario, cell: StudyCell) -> Scenario:
    """The base scenario with the cell's hardware, sequence and pair."""
    hw = PRESETS[cell.hardware]
    m = copy.deepcopy(base.to_mapping())
    seq = hw.sequence
    m["sequence"] = {"mode": "multiplexed", "tracking_window_s": seq.tracking_window_s if seq.mode == "multiplexed"
                     else 0.02, "dead_time_s": seq.dead_time_s, "propulsion_window_s": cell.propulsion_window_s,
                     "latency_s": cell.latency_s}
    m["coil"].update(saturation_T_per_m=hw.saturation_T_per_m, slew_rate="custom",
                     custom_slew_rate_T_per_m_per_s=hw.slew_T_per_m_per_s)
    m["imager"]["latency_s"] = 0.0
    _deep_update(m, copy.deepcopy(PAIRS[cell.pair]))
    return scenario_from_mapping(m)


def hold_margin(scenario: Scenario) -> float:
    """``duty * a_sat - |a_weight|`` (m/s^2): negative means the bead cannot hold against its weight."""
    ph = scenario.physics
    b = input_matrix(scenario.physics)
    a_sat = abs(float(b[1, 1])) * scenario.coil.saturation_T_per_m
    rb = ph.robot
    w = abs(apparent_weight_z(rb.volume_m3, rb.density_kg_per_m3, ph.blood.density_kg_per_m3, ph.vessel.gravity_m_per_s2))
    return duty_cycle(scenario.sequence) * a_sat - w / rb.mass_kg


def run_cell(args: tuple[Scenario, StudyCell, Sequence[int]]) -> dict[str, Any]:
    """Run one cell over its seeds; one table row (mean / worst tracking and estimation errors)."""
    base, cell, seeds = args
    row: dict[str, Any] = dataclasses.asdict(cell)
    try:
        sc = cell_scenario(base, cell)
    except ConfigError as exc:
        row.update(status=f"refused: {exc}")
        return row
    row.update(duty_cycle=duty_cycle(sc.sequence), frame_rate_Hz=1.0 / sc.sequence.period_s,
               hold_margin_m_per_s2=hold_margin(sc))
    tr, es = [], []
    for seed in seeds:
        try:
            m = run_closed_loop(sc, seed).metrics
        except VesselbotError as exc:
            row.update(status=f"failed (seed {seed}): {exc}")
            return row
        tr.append(m["tracking_error_max_m"])
        es.append(m["estimation_error_rms_m"])
    row.update(status="ok", tracking_max_mean_m=float(np.mean(tr)), tracking_max_worst_m=float(np.max(tr)),
               estimation_rms_mean_m=float(np.mean(es)), estimation_rms_worst_m=float(np.max(es)))
    return row


def run_study(base: Scenario, cells: Sequence[StudyCell], seeds: Sequence[int], workers: int = 1) -> list[dict[str, Any]]:
    """Run every cell (in parallel processes when ``workers > 1``); rows in the cells' order."""
    jobs = [(base, c, tuple(seeds)) for c in cells]
    if workers <= 1:
        return [run_cell(j) for j in jobs]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(run_cell, jobs))


def fmt_um(v: Any) -> str:
    """Micrometres for a table cell ('-' when missing)."""
    return "-" if not isinstance(v, float) or not math.isfinite(v) else f"{v * 1e6:.0f}"
