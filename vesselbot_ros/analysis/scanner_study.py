"""Scanner study (Section III-D in numbers): what multiplexing and latency cost, and what copes.

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
* ``ekf_k300``: the same with k1 = k2 = 150 (k1 + k2 near the drag rate, as
  ``sound_small_artery_ekf`` in continuous mode).

Two physical bounds per cell, computed from the true plant along the
reference, say where the loop can be feasible before any controller runs:

* ``hold_margin_m_per_s2 = duty * a_sat - max_t |Xdd_ref - F(t, X_ref, Xd_ref)|``:
  the acceleration the coil must supply to follow the reference (against the
  apparent weight, the drag of the flow and the wall forces), averaged over a
  period by the duty cycle, against what the saturated coil gives.  Negative:
  no controller can follow the reference.
* ``coast_floor_m = max_t |X_coast(t + T_c) - X_ref(t + T_c)| / 2``: with no
  propulsion for ``T_c`` = tracking window + 2 dead times, the bead released
  on the reference drifts with the flow and sinks; a controller that centres
  that drift on the reference still errs by half of it at one end of the coast.
  No controller does better than this floor, whatever its gains.

Each cell runs in its own process with a wall-clock budget (``cell_timeout_s``):
a cell whose plant integration crawls (the adaptive step collapsing while the
bead rests on the wall) is recorded as ``timeout`` instead of stalling the study.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import math
import multiprocessing
import multiprocessing.connection
import time
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.input_mapping import input_matrix
from vesselbot_ros.control.model import DynamicsModel
from vesselbot_ros.errors import VesselbotError
from vesselbot_ros.scanner.hardware import PRESETS
from vesselbot_ros.scanner.sequence import duty_cycle
from vesselbot_ros.sim.closed_loop import build_stages, run_closed_loop
from vesselbot_ros.sim.scenario import Scenario, scenario_from_mapping

__all__ = ["PAIRS", "StudyCell", "study_cells", "run_cell", "run_study", "hold_margin", "coast_floor", "feasibility"]

PAIRS: dict[str, dict[str, Any]] = {
    "paper": {"observer": {"kind": "high_gain"},
              "controller": {"gains": {"k1": 5.0, "k2": 10.0}, "flow_compensation": "none", "duty_compensation": "none"}},
    "ekf": {"observer": {"kind": "ekf"},
            "controller": {"gains": {"k1": 5.0, "k2": 10.0}, "flow_compensation": "estimate",
                           "duty_compensation": "sequence"}},
    "ekf_k300": {"observer": {"kind": "ekf"},
                 "controller": {"gains": {"k1": 150.0, "k2": 150.0}, "flow_compensation": "estimate",
                                "duty_compensation": "sequence"}},
}


@dataclasses.dataclass(frozen=True)
class StudyCell:
    """One point of the study grid."""

    hardware: str
    propulsion_window_s: float
    latency_s: float
    pair: str
    tracking_window_s: float | None = None  # None: the preset's


def study_cells(hardware: Iterable[str], propulsion_windows_s: Iterable[float], latencies_s: Iterable[float],
                pairs: Iterable[str], tracking_windows_s: Iterable[float | None] = (None,)) -> list[StudyCell]:
    """The grid, in a fixed order (hardware, tracking window, propulsion window, latency, pair)."""
    for h in hardware:
        if h not in PRESETS:
            raise ConfigError(f"hardware must be one of {sorted(PRESETS)}, got {h!r}")
    for p in pairs:
        if p not in PAIRS:
            raise ConfigError(f"pair must be one of {sorted(PAIRS)}, got {p!r}")
    return [StudyCell(h, pw, lat, pair, tw) for h, tw, pw, lat, pair
            in itertools.product(hardware, tracking_windows_s, propulsion_windows_s, latencies_s, pairs)]


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
    tracking = cell.tracking_window_s if cell.tracking_window_s is not None else (
        seq.tracking_window_s if seq.mode == "multiplexed" else 0.02)
    m["sequence"] = {"mode": "multiplexed", "tracking_window_s": tracking, "dead_time_s": seq.dead_time_s,
                     "propulsion_window_s": cell.propulsion_window_s, "latency_s": cell.latency_s}
    m["coil"].update(saturation_T_per_m=hw.saturation_T_per_m, slew_rate="custom",
                     custom_slew_rate_T_per_m_per_s=hw.slew_T_per_m_per_s)
    m["imager"]["latency_s"] = 0.0
    _deep_update(m, copy.deepcopy(PAIRS[cell.pair]))
    return scenario_from_mapping(m)


def _reference(scenario: Scenario, step_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    ts = np.arange(0.0, scenario.sim.duration_s + 0.5 * step_s, step_s)
    p, v, a = build_stages(scenario).reference.sample_many(ts)
    return ts, p, v, a


def required_accel(scenario: Scenario, step_s: float = 1e-3) -> float:
    """``max_t |Xdd_ref - F(t, X_ref, Xd_ref)|`` (m/s^2) with the true plant's ``F``, over the run."""
    plant = DynamicsModel(scenario.physics, scenario.sim.integrator)
    ts, p, v, a = _reference(scenario, step_s)
    need = [math.hypot(*(a[k] - plant.F(float(t), p[k], v[k]))) for k, t in enumerate(ts)]
    return float(max(need))


def hold_margin(scenario: Scenario) -> float:
    """``duty * a_sat - required_accel`` (m/s^2): negative means no controller can follow the reference."""
    b = input_matrix(scenario.physics)
    a_sat = abs(float(b[1, 1])) * scenario.coil.saturation_T_per_m
    return duty_cycle(scenario.sequence) * a_sat - required_accel(scenario)


def coast_floor(scenario: Scenario, every_s: float = 0.01, step_s: float = 2.5e-4) -> float:
    """Half the largest drift from the reference over one coast (m): the floor of any controller's error.

    From every ``every_s`` along the reference, the true plant is released on the
    reference (position and velocity) with no gradient for ``T_c`` = tracking
    window + 2 dead times (RK4, ``step_s``), and the distance to the reference
    at the end of the coast is taken.
    """
    seq = scenario.sequence
    t_coast = seq.tracking_window_s + 2.0 * seq.dead_time_s
    plant = DynamicsModel(scenario.physics, scenario.sim.integrator)
    ref = build_stages(scenario).reference
    worst = 0.0
    n = max(1, int(round(t_coast / step_s)))
    h = t_coast / n
    for t0 in np.arange(scenario.sim.metrics_after_s, scenario.sim.duration_s - t_coast, every_s):
        s0 = ref.sample(float(t0))
        x, z = np.array(s0.p, dtype=float), np.array(s0.v, dtype=float)
        t = float(t0)
        for _ in range(n):  # RK4 on X' = Z, Z' = F(t, X, Z)
            k1x, k1z = z, plant.F(t, x, z)
            k2x, k2z = z + 0.5 * h * k1z, plant.F(t + 0.5 * h, x + 0.5 * h * k1x, z + 0.5 * h * k1z)
            k3x, k3z = z + 0.5 * h * k2z, plant.F(t + 0.5 * h, x + 0.5 * h * k2x, z + 0.5 * h * k2z)
            k4x, k4z = z + h * k3z, plant.F(t + h, x + h * k3x, z + h * k3z)
            x = x + h / 6.0 * (k1x + 2 * k2x + 2 * k3x + k4x)
            z = z + h / 6.0 * (k1z + 2 * k2z + 2 * k3z + k4z)
            t += h
        worst = max(worst, float(np.hypot(*(x - ref.sample(t).p))))
    return 0.5 * worst


def feasibility(scenario: Scenario) -> dict[str, float]:
    """The cell's physical bounds: ``hold_margin_m_per_s2``, ``coast_floor_m`` (module docstring)."""
    return {"hold_margin_m_per_s2": hold_margin(scenario), "coast_floor_m": coast_floor(scenario)}


def run_cell(args: tuple[Scenario, StudyCell, Sequence[int]]) -> dict[str, Any]:
    """Run one cell over its seeds; one table row (mean / worst tracking and estimation errors)."""
    base, cell, seeds = args
    row: dict[str, Any] = dataclasses.asdict(cell)
    try:
        sc = cell_scenario(base, cell)
    except ConfigError as exc:
        row.update(status=f"refused: {exc}")
        return row
    row.update(tracking_window_s=sc.sequence.tracking_window_s, duty_cycle=duty_cycle(sc.sequence),
               frame_rate_Hz=1.0 / sc.sequence.period_s, **feasibility(sc))
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


def _cell_process(job: tuple[Scenario, StudyCell, Sequence[int]], conn: Any) -> None:
    try:
        conn.send(run_cell(job))
    except BaseException as exc:  # noqa: BLE001 - reported as the cell's status, never lost
        conn.send({**dataclasses.asdict(job[1]), "status": f"failed: {type(exc).__name__}: {exc}"})
    finally:
        conn.close()


def run_study(base: Scenario, cells: Sequence[StudyCell], seeds: Sequence[int], workers: int = 1,
              cell_timeout_s: float = 300.0) -> list[dict[str, Any]]:
    """Run every cell in its own process, at most ``workers`` at a time; rows in the cells' order.

    A cell that takes more than ``cell_timeout_s`` of wall time is killed and
    recorded with status ``timeout``; the other cells go on.  (Processes are
    forked from this one, so the compiled kernels are not loaded again.)
    """
    if not (math.isfinite(cell_timeout_s) and cell_timeout_s > 0):
        raise ConfigError(f"cell_timeout_s must be > 0, got {cell_timeout_s!r}")
    ctx = multiprocessing.get_context("fork")
    rows: dict[int, dict[str, Any]] = {}
    pending = list(range(len(cells)))
    running: dict[int, tuple[Any, Any, float]] = {}  # cell -> (process, parent end, start)
    try:
        while pending or running:
            while pending and len(running) < max(1, workers):
                i = pending.pop(0)
                parent, child = ctx.Pipe(duplex=False)
                proc = ctx.Process(target=_cell_process, args=((base, cells[i], tuple(seeds)), child), daemon=True)
                proc.start()
                child.close()
                running[i] = (proc, parent, time.monotonic())
            multiprocessing.connection.wait([r[1] for r in running.values()], timeout=0.5)
            now = time.monotonic()
            for i, (proc, conn, t0) in list(running.items()):
                if conn.poll():
                    try:
                        rows[i] = conn.recv()
                    except EOFError:
                        rows[i] = {**dataclasses.asdict(cells[i]), "status": f"failed: worker exited ({proc.exitcode})"}
                elif not proc.is_alive():
                    rows[i] = {**dataclasses.asdict(cells[i]), "status": f"failed: worker exited ({proc.exitcode})"}
                elif now - t0 > cell_timeout_s:
                    proc.kill()
                    rows[i] = {**dataclasses.asdict(cells[i]),
                               "status": f"timeout: over {cell_timeout_s:g} s of wall time (plant integration crawling)"}
                else:
                    continue
                proc.join(1.0)
                conn.close()
                del running[i]
    finally:
        for proc, conn, _ in running.values():
            proc.kill()
            proc.join(1.0)
            conn.close()
    return [rows[i] for i in range(len(cells))]


def fmt_um(v: Any) -> str:
    """Micrometres for a table cell ('-' when missing)."""
    return "-" if not isinstance(v, float) or not math.isfinite(v) else f"{v * 1e6:.0f}"
