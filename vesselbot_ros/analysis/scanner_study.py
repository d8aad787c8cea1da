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
* ``ekf``: the extended Kalman observer (delay compensation, flow scale, the
  wall as a constraint: ``wall_projection: lumen``, a lost track restarted
  after 30 ms of rejected frames: ``max_rejection_s``) with law (24), Table
  III's gains, flow and duty-cycle compensation;
* ``ekf_k300``: the same with k1 = k2 = 150 (k1 + k2 near the drag rate, as
  ``sound_small_artery_ekf`` in continuous mode);
* ``ekf_predictive``: the extended Kalman observer with the predictive
  controller built for the sequence (:mod:`vesselbot_ros.control.predictive`).

Four physical bounds per cell, computed from the true plant along the
reference, say where the loop can be feasible before any controller runs
(on the vessel's axes: a straight vessel, a planar network or a 3-D tree):

* ``hold_margin_m_per_s2 = duty * a_sat - max_t |Xdd_ref - F(t, X_ref, Xd_ref)|``:
  the acceleration the coil must supply to follow the reference (against the
  apparent weight, the drag of the flow and the wall forces), averaged over a
  period by the duty cycle, against what the saturated coil gives.  Negative:
  no controller can follow the reference.
* ``gradient_to_fly_T_per_m = max_t |Xdd_ref - F| / (duty * a_unit)``: the
  smallest gradient amplitude that makes the hold margin zero at the cell's
  duty cycle (``a_unit``: the acceleration of 1 T/m), the design answer where
  the margin is negative.
* ``coast_floor_m = max_t |X_coast(t + T_c) - X_ref(t + T_c)| / 2``: with no
  propulsion for ``T_c`` = tracking window + 2 dead times, the bead released
  on the reference drifts with the flow and sinks; a controller that centres
  that drift on the reference still errs by half of it at one end of the coast.
  No controller does better than this floor, whatever its gains.
* ``estimation_floor_m``: the least rms position error any estimator holds
  on the reference with the cell's imager (its noise, frame times and
  latency), the true model known but for the blood's velocity scale (5 %
  uncertain, the paper's error) and no process noise: the Kalman
  filter of the true plant linearised along the reference
  (:func:`estimation_floor`).  The reference is known, so the tracking
  error's mean square is at least the best estimate's error's: no
  controller that holds the bead on the reference has a smaller tracking
  rms (an estimate's own rms can be smaller where the bead strays to where
  the plant is less unstable).  Where the plant is
  unstable across the lumen (the image-charge attraction pulls the bead to
  the nearer wall, a growth rate ``lambda`` of 5-20 1/s at the paper's
  height) the floor stays near ``sigma sqrt(1 - exp(-2 lambda T))`` per
  unstable mode for frames ``T`` apart; where it is stable or neutral,
  averaging frames lowers it over the run.

``estimation_floor_m`` is the bound on the reference, before any loop flies.
The bound of the loops as they flew is ``estimation_bound_m``
(:func:`bound_columns`, :mod:`vesselbot_ros.analysis.estimation_bound`): the
posterior Cramer-Rao bound of every causal estimator fed each seed's own
frames (its schedule, latency and aberrant frames, the latter known and
dropped), linearised along the seed's true trajectory, on the metrics window
away from the walls, beside the pair's observer's rms on the same window.  It
holds for every estimator, so for every loop's tracking rms too (the
reference is one causal estimator of the bead): a target below it, or a
negative hold margin, is what makes a cell infeasible.

Beside them, per seed, a reference strategy (:func:`tracking_floor`,
``strategy_tracking_m``), **not a floor**: the coast floor played with the
linearised filter's error on the seed's own frame noise, the worst a loop
that straddles each coast with that estimate errs.  Loops come in under it
(0.52-0.96x of it in docs/reproduction.md's tables), so it never makes a
target infeasible: a target a loop misses stays "missed", with its ratio.

The runs go through the campaign engine (:mod:`vesselbot_ros.campaign`): the
grid is a :class:`~vesselbot_ros.campaign.spec.CampaignSpec` with one variant
per cell (its hardware, sequence and pair as dotted scenario keys,
:func:`cell_changes`) over the seeds, run on Dask (a local cluster by default,
any scheduler on request) with the engine's wall-clock budget per run
(``run_timeout_s``): a run whose plant integration crawls (the adaptive step
collapsing while the bead rests on the wall) is stopped and its cell recorded
as ``timeout`` instead of stalling the study.  The physical bounds of each cell
are computed on the same cluster, beside the runs.  Every run is stored in a
campaign folder (``results.parquet``), and the per-cell table is aggregated
from it; a study run again into the same folder reuses its finished runs.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import math
import tempfile
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
import yaml

from vesselbot_ros.analysis.estimation_bound import expm_batch, jacobians, run_bound
from vesselbot_ros.analysis.plan import (
    Plan,
    PlanInfeasible,
    available_accel,
    coil_gain,
    flying_changes,
    make_plan,
    need,
    reachable,
)
from vesselbot_ros.campaign.engine import Progress, dask_client, execute, pending, prepare
from vesselbot_ros.campaign.spec import campaign_spec_from_mapping
from vesselbot_ros.campaign.store import CampaignStore
from vesselbot_ros.config import ConfigError, check_choice, flatten, to_mapping
from vesselbot_ros.control.model import BLOOD_VELOCITY_ERROR, DynamicsModel
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.kernel import diameter_at
from vesselbot_ros.resources import require_fits
from vesselbot_ros.scanner.hardware import PRESETS, preset_changes
from vesselbot_ros.scanner.sequence import PHASE_CODES, SequenceParams, duty_cycle, phase_codes, sequence_vector
from vesselbot_ros.sim.closed_loop import build_stage, build_stages, run_closed_loop
from vesselbot_ros.sim.scenario import Scenario, scenario_with

__all__ = ["PAIRS", "StudyCell", "study_cells", "preset_changes", "cell_changes", "planned_changes", "plan_bounds",
           "cell_scenario", "cell_name", "study_spec", "cell_row",
           "run_study", "hold_margin", "gradient_to_fly", "coast_floor", "estimation_floor", "tracking_floor", "floors",
           "feasibility", "bound_columns"]

#: The EKF pairs' filter: the wall as a constraint, and a lost track restarted once 30 ms of frames were rejected in a
#: row (the count rule's 50 frames are 0.8 s at 62.5 frames/s; the base scenario's aberrant burst lasts 20 ms).
_EKF: dict[str, Any] = {"wall_projection": "lumen", "max_rejection_s": 0.03}

PAIRS: dict[str, dict[str, Any]] = {
    "paper": {"observer": {"kind": "high_gain"},
              "controller": {"gains": {"k1": 5.0, "k2": 10.0}, "flow_compensation": "none", "duty_compensation": "none"}},
    "ekf": {"observer": {"kind": "ekf", "ekf": _EKF},
            "controller": {"gains": {"k1": 5.0, "k2": 10.0}, "flow_compensation": "estimate",
                           "duty_compensation": "sequence"}},
    "ekf_k300": {"observer": {"kind": "ekf", "ekf": _EKF},
                 "controller": {"gains": {"k1": 150.0, "k2": 150.0}, "flow_compensation": "estimate",
                                "duty_compensation": "sequence"}},
    "ekf_predictive": {"observer": {"kind": "ekf", "ekf": _EKF},
                       "controller": {"kind": "predictive"}},
}


@dataclasses.dataclass(frozen=True)
class StudyCell:
    """One point of the study grid."""

    hardware: str
    propulsion_window_s: float
    latency_s: float
    pair: str
    tracking_window_s: float | None = None  # None: the preset's


#: What one cell of the study holds (its row, its runs' records; bytes, rounded up).
CELL_BYTES = 64 * 1024


def study_cells(hardware: Iterable[str], propulsion_windows_s: Iterable[float], latencies_s: Iterable[float],
                pairs: Iterable[str], tracking_windows_s: Iterable[float | None] = (None,)) -> list[StudyCell]:
    """The grid, in a fixed order (hardware, tracking window, propulsion window, latency, pair).

    Raises:
        ConfigError: an unknown preset or pair, or a grid whose cells (and their runs' results) would not fit in
            memory (one line naming the options and the estimate; :func:`vesselbot_ros.resources.require_fits`).
    """
    hardware, propulsion_windows_s, latencies_s = list(hardware), list(propulsion_windows_s), list(latencies_s)
    pairs, tracking_windows_s = list(pairs), list(tracking_windows_s)
    n = len(hardware) * len(tracking_windows_s) * len(propulsion_windows_s) * len(latencies_s) * len(pairs)
    require_fits("--hardware x --tracking-windows x --propulsion-windows x --latencies x --pairs", f"{n} cells",
                 CELL_BYTES * n, what="the study's cells and their results", hint="shorten the lists")
    for h in hardware:
        if h not in PRESETS:
            raise ConfigError(f"hardware must be one of {sorted(PRESETS)}, got {h!r}")
    for p in pairs:
        if p not in PAIRS:
            raise ConfigError(f"pair must be one of {sorted(PAIRS)}, got {p!r}")
    return [StudyCell(h, pw, lat, pair, tw) for h, tw, pw, lat, pair
            in itertools.product(hardware, tracking_windows_s, propulsion_windows_s, latencies_s, pairs)]


def cell_changes(cell: StudyCell) -> dict[str, Any]:
    """The cell's changes to the base scenario as dotted keys (a campaign variant).

    The whole sequence (the keys the cell does not set take their defaults), the
    coil's saturation and slew, no imager latency (the sequence's latency is the
    cell's), and the pair's observer and controller keys.
    """
    seq = PRESETS[cell.hardware].sequence
    tracking = cell.tracking_window_s if cell.tracking_window_s is not None else (
        seq.tracking_window_s if seq.mode == "multiplexed" else 0.02)
    defaults = {f.name: f.default for f in dataclasses.fields(SequenceParams)}
    return {**preset_changes(cell.hardware, **{**defaults, "mode": "multiplexed", "tracking_window_s": tracking,
                                               "dead_time_s": seq.dead_time_s,
                                               "propulsion_window_s": cell.propulsion_window_s,
                                               "latency_s": cell.latency_s}),
            **flatten(PAIRS[cell.pair])}


def cell_scenario(base: Scenario, cell: StudyCell) -> Scenario:
    """The base scenario with the cell's hardware, sequence and pair (:func:`cell_changes`).

    Raises:
        ConfigError: the scenario refuses the cell (e.g. observer (25) unstable at its frame rate).
    """
    # a pair of another controller kind (predictive) drops the base's keys of law (24), as a campaign variant does
    return scenario_with(base, cell_changes(cell))


def _reference(scenario: Scenario, step_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    ts = np.arange(0.0, scenario.sim.duration_s + 0.5 * step_s, step_s)
    p, v, a = build_stages(scenario).reference.sample_many(ts)
    return ts, p, v, a


def required_accel(scenario: Scenario, step_s: float = 1e-3) -> float:
    """``max_t |Xdd_ref - F(t, X_ref, Xd_ref)|`` (m/s^2) with the true plant's ``F``, over the run (no wall carries
    it: :func:`~vesselbot_ros.analysis.plan.need` without a resting height)."""
    plant = DynamicsModel(scenario.physics, scenario.sim.integrator)
    ts, p, v, a = _reference(scenario, step_s)
    return float(np.max(need(plant, ts, p, v, a)))


def hold_margin(scenario: Scenario, need_m_per_s2: float | None = None) -> float:
    """``duty * a_sat - required_accel`` (m/s^2): negative means no controller can follow the reference.

    ``need_m_per_s2``: :func:`required_accel` if already computed.
    """
    a_avail, _, _ = available_accel(scenario)
    return a_avail - (required_accel(scenario) if need_m_per_s2 is None else need_m_per_s2)


def gradient_to_fly(scenario: Scenario, need_m_per_s2: float | None = None) -> float:
    """The smallest gradient amplitude (T/m) whose duty-averaged acceleration covers :func:`required_accel`.

    The design answer for a cell whose hold margin is negative: the saturation the
    coil would need at the cell's duty cycle (the bead and the sequence unchanged).
    """
    req = required_accel(scenario) if need_m_per_s2 is None else need_m_per_s2
    return req / (duty_cycle(scenario.sequence) * coil_gain(scenario.physics))


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
        worst = max(worst, float(np.linalg.norm(x - ref.sample(t).p)))
    return 0.5 * worst


#: The prior of :func:`estimation_floor`'s unknown flow scale: the paper's 5 % blood-velocity error.
FLOW_SCALE_SIGMA = BLOOD_VELOCITY_ERROR


class _Linearised(NamedTuple):
    """The true plant linearised along a scenario's reference, tick by tick, and its imager's frame schedule."""

    ts: npt.NDArray[np.float64]  # (n,) control ticks (s)
    p_ref: npt.NDArray[np.float64]  # (n, d)
    v_ref: npt.NDArray[np.float64]  # (n, d)
    phi: npt.NDArray[np.float64]  # (n, 2d+1, 2d+1) transition from tick k to k + 1 of (X, Z, s)
    frames: list[tuple[int, int]]  # (delivery tick, acquisition tick) of every frame, in delivery order


def _linearise(scenario: Scenario) -> _Linearised:
    imager = build_stage(scenario, "imager")  # its frame times (the noise is R below)
    plant = DynamicsModel(scenario.physics, scenario.sim.integrator)
    dt = scenario.sim.dt_control_s
    n = int(round(scenario.sim.duration_s / dt))
    ts = np.arange(n, dtype=np.float64) * dt
    p_ref, v_ref, _ = build_stage(scenario, "reference").sample_many(ts)
    # the transition over each tick from the Jacobian at its start, on the vessel's d axes
    phi = expm_batch(jacobians(plant, ts, p_ref, v_ref) * dt)
    frames = []
    for k, t in enumerate(ts):
        frame = imager.frame(float(t), p_ref[k])
        if frame is not None:
            frames.append((k, int(round(frame.t_acq_s / dt))))
    return _Linearised(ts, p_ref, v_ref, phi, frames)


def _filter(scenario: Scenario, lin: _Linearised, flow_scale_sigma: float,
            noise: Sequence[npt.NDArray[np.float64] | None] | None = None,
            e0: npt.NDArray[np.float64] | None = None) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The linearised Kalman filter over the run: (n,) trace of its position covariance at every tick (given the frames
    delivered by then) and, with ``noise`` (each frame's (2,) noise, None: a frame no estimator would use) and the
    start error ``e0``, (n, 5) its error ``true - estimate`` at every tick (zeros without)."""
    ts, phi = lin.ts, lin.phi
    m = phi.shape[1]
    d = (m - 1) // 2
    r = scenario.imager.noise_sigma_m ** 2 * np.eye(d)
    h = np.hstack([np.eye(d), np.zeros((d, d + 1))])
    p_acq = _prior(d, flow_scale_sigma)  # before the first frame: 1 mm, 10 mm/s
    e_acq = np.zeros(m) if e0 is None else np.array(e0, dtype=np.float64)
    k_acq = 0
    p_now, e_now = p_acq.copy(), e_acq.copy()
    trace = np.empty(len(ts))
    err = np.zeros((len(ts), m))
    fi = 0
    for k in range(len(ts)):
        while fi < len(lin.frames) and lin.frames[fi][0] == k:  # fuse at its acquisition tick, then bring it to now
            j = min(k, max(k_acq, lin.frames[fi][1]))
            v = None if noise is None else noise[fi]
            fi += 1
            for i in range(k_acq, j):
                p_acq = phi[i] @ p_acq @ phi[i].T
                e_acq = phi[i] @ e_acq
            k_acq = j
            if noise is None or v is not None:
                gain = p_acq @ h.T @ np.linalg.inv(h @ p_acq @ h.T + r)
                ikh = np.eye(m) - gain @ h
                p_acq = ikh @ p_acq @ ikh.T + gain @ r @ gain.T  # Joseph form: symmetric and positive
                if v is not None:
                    e_acq = e_acq - gain @ (h @ e_acq + v)
            p_now, e_now = p_acq.copy(), e_acq.copy()
            for i in range(j, k):
                p_now = phi[i] @ p_now @ phi[i].T
                e_now = phi[i] @ e_now
        trace[k] = float(np.trace(p_now[:d, :d]))
        err[k] = e_now
        p_now = phi[k] @ p_now @ phi[k].T  # to the next tick
        e_now = phi[k] @ e_now
    return trace, err


def _prior(d: int, flow_scale_sigma: float) -> npt.NDArray[np.float64]:
    """The linearised filter's prior covariance of ``(X, Z, s)`` on ``d`` axes: 1 mm, 10 mm/s, ``flow_scale_sigma``."""
    return np.diag([1e-6] * d + [1e-4] * d + [flow_scale_sigma ** 2])


def estimation_floor(scenario: Scenario, flow_scale_sigma: float = FLOW_SCALE_SIGMA) -> float:
    """The least rms position error (m) any estimator holds on the reference after ``sim.metrics_after_s``.

    The Kalman filter of the true plant linearised along the reference (each
    tick's transition ``exp(J dt)``), fed frames at the cell's imager's
    acquisition and delivery times (its sequence and latency) with its noise,
    and no process noise: the covariance at every tick given the frames
    delivered by then, its position part's trace averaged over the metrics
    window.  The model is the true one but for the blood's velocity scale
    ``s``, a constant no estimator knows better than ``flow_scale_sigma`` at
    the start (the paper's 5 % blood-velocity error; 0: known exactly).  No
    estimator of this plant and imager errs less in the mean square (the
    linear-Gaussian filter is the optimal one; for the nonlinear plant this
    is its linearised bound), and a controller that holds the bead on the
    (known) reference tracks with no smaller rms (module docstring).
    """
    return _estimation_floor(scenario, _linearise(scenario), flow_scale_sigma)


def _estimation_floor(scenario: Scenario, lin: _Linearised, flow_scale_sigma: float) -> float:
    trace, _ = _filter(scenario, lin, flow_scale_sigma)
    return float(math.sqrt(np.mean(trace[lin.ts >= scenario.sim.metrics_after_s])))


def _frame_noise(scenario: Scenario, lin: _Linearised, seed: int) -> list[npt.NDArray[np.float64] | None]:
    """Each frame's noise in the run of ``seed`` (the imager fed a bead at rest at the origin delivers exactly its
    noise); None for an aberrant frame (the floor lets the estimator know it, and drop it)."""
    imager = build_stage(scenario, "imager", seed)
    out: list[npt.NDArray[np.float64] | None] = []
    zero = np.zeros(lin.p_ref.shape[1])
    for t in lin.ts:
        frame = imager.frame(float(t), zero)
        if frame is not None:
            out.append(None if frame.outlier else np.array(frame.p, dtype=np.float64))
    return out


def tracking_floor(scenario: Scenario, seeds: Iterable[int],
                   flow_scale_sigma: float = FLOW_SCALE_SIGMA) -> list[float]:
    """A reference strategy's worst tracking error (m) after ``sim.metrics_after_s`` of each seed's run: the coast
    floor played with the linearised filter's estimate error.  A strategy, **not a lower bound**: loops that do not
    straddle the coasts this way come in under it.

    The linearised Kalman filter of :func:`estimation_floor` is fed the very
    noise the seed's imager draws (an aberrant frame dropped, as if known),
    from a start error drawn from its prior (the seed's own generator), and
    its error ``e = true - estimate`` is kept at every tick.  A controller can
    at best hold its estimate on the reference: in a propulsion window the
    bead is then ``e`` away.  Over each coast (propulsion window's end to the
    next one's start, ``T_c``), no gradient: released on the (reachable)
    reference the bead drifts by ``D`` (the plant's own integrator, the walls
    included; :func:`coast_floor`'s drift), so a controller that starts the
    coast half a drift behind (the coast floor's straddle) leaves the bead at
    ``-D/2 + e(t0)`` at its start and ``D/2 + (Phi e(t0))`` at its end
    (``Phi`` the coast's linearised transition; the frames during the coast
    correct the estimate, not the bead).  The floor is the largest of these
    over the run, each deviation cut where it would take the bead's centre
    through the straight vessel's wall (the wall stops the bead; the
    linearisation does not know it).  Like the coast floor it assumes the
    straddle; like the estimation floor it is the linearised, Gaussian bound
    (no outliers).  Continuous propulsion has no coast: the estimate's error
    alone.
    """
    return _tracking_floor(scenario, _linearise(scenario), seeds, flow_scale_sigma)


def floors(scenario: Scenario, seeds: Iterable[int], flow_scale_sigma: float = FLOW_SCALE_SIGMA
           ) -> tuple[float, list[float]]:
    """:func:`estimation_floor` and :func:`tracking_floor` of ``seeds`` on one linearisation of the plant."""
    lin = _linearise(scenario)
    return (_estimation_floor(scenario, lin, flow_scale_sigma),
            _tracking_floor(scenario, lin, seeds, flow_scale_sigma))


def _tracking_floor(scenario: Scenario, lin: _Linearised, seeds: Iterable[int],
                    flow_scale_sigma: float) -> list[float]:
    seq = scenario.sequence
    dt = scenario.sim.dt_control_s
    after = lin.ts >= scenario.sim.metrics_after_s
    coasts: list[tuple[int, npt.NDArray[np.float64], npt.NDArray[np.float64]]] = []
    m = 0
    if seq.mode == "multiplexed":
        plant = DynamicsModel(scenario.physics, scenario.sim.integrator)
        m = int(round((seq.tracking_window_s + 2.0 * seq.dead_time_s) / dt))  # ticks of a coast
        codes = phase_codes(sequence_vector(seq), lin.ts)
        ends = np.flatnonzero((codes[:-1] == PHASE_CODES["propulsion"]) & (codes[1:] != PHASE_CODES["propulsion"])) + 1
        for ke in ends:
            if not after[ke] or ke + m >= len(lin.ts):
                continue
            t0, t1 = float(lin.ts[ke]), float(lin.ts[ke + m])
            p0, v0 = reachable(scenario, t0, lin.p_ref[ke], lin.v_ref[ke])
            y = np.concatenate([p0, v0]).astype(np.float64)
            d = len(p0)
            plant.propagate(t0, t1, y, np.zeros(d), plant.new_contact_state())
            p1, _ = reachable(scenario, t1, lin.p_ref[ke + m], lin.v_ref[ke + m])
            phi_c = np.eye(lin.phi.shape[1])
            for i in range(ke, ke + m):
                phi_c = lin.phi[i] @ phi_c
            coasts.append((int(ke), y[:d] - p1, phi_c))
    if scenario.physics.vessel.network:
        half = np.full(len(lin.ts), np.inf)
    else:  # the straight vessel's walls, where the bead's centre stops
        p = build_stage(scenario, "plant").p
        half = np.array([0.5 * diameter_at(float(t), p) for t in lin.ts]) - scenario.physics.robot.radius_m

    def off(k: int, dev: npt.NDArray[np.float64]) -> float:  # the bead's distance from the reference, in the lumen
        dev = dev[:lin.p_ref.shape[1]]
        if not math.isfinite(half[k]):  # a network or a tree: no wall stops the linearised deviation here
            return float(np.linalg.norm(dev))
        z = min(max(float(lin.p_ref[k, 1] + dev[1]), -half[k]), half[k])
        return float(np.hypot(dev[0], z - lin.p_ref[k, 1]))

    p_prior = _prior(lin.p_ref.shape[1], flow_scale_sigma)
    out = []
    for seed in seeds:
        e0 = np.random.default_rng(seed).multivariate_normal(np.zeros(len(p_prior)), p_prior)
        _, err = _filter(scenario, lin, flow_scale_sigma, _frame_noise(scenario, lin, seed), e0)
        worst = max((off(int(k), err[k]) for k in np.flatnonzero(after)), default=0.0)
        for k0, drift, phi_c in coasts:
            e_end = phi_c @ err[k0]
            nd = len(drift)
            worst = max(worst, off(k0, err[k0, :nd] - 0.5 * drift), off(k0 + m, e_end[:nd] + 0.5 * drift))
        out.append(worst)
    return out


def feasibility(scenario: Scenario, seeds: Iterable[int] = ()) -> dict[str, float]:
    """The cell's physical bounds: ``hold_margin_m_per_s2``, ``coast_floor_m``, ``estimation_floor_m`` (module
    docstring), the gradient that would fly it, ``gradient_to_fly_T_per_m`` (:func:`gradient_to_fly`), and with
    ``seeds`` the worst of their reference strategy's tracking errors, ``strategy_tracking_m``
    (:func:`tracking_floor`: a strategy, not a floor).  The estimation bound of the runs (:func:`bound_columns`)
    is :func:`run_study`'s, for the cells whose runs all finished within the budget (it flies them again)."""
    req = required_accel(scenario)
    out = {"hold_margin_m_per_s2": hold_margin(scenario, req), "coast_floor_m": coast_floor(scenario),
           "gradient_to_fly_T_per_m": gradient_to_fly(scenario, req)}
    seeds = list(seeds)
    if seeds:
        out.update(_flown_floors(scenario, seeds))
    else:
        out["estimation_floor_m"] = estimation_floor(scenario)
    return out


def _flown_floors(scenario: Scenario, seeds: Sequence[int]) -> dict[str, float]:
    """A flown cell's estimation floor, worst reference-strategy tracking error and estimation bound over ``seeds``."""
    est, track = floors(scenario, seeds)
    return {"estimation_floor_m": est, "strategy_tracking_m": max(track)}


def bound_columns(scenario: Scenario, seeds: Sequence[int], run: Any = None) -> dict[str, float]:
    """The cell's estimation bound over ``seeds`` (:mod:`vesselbot_ros.analysis.estimation_bound`): each seed's run
    flown again with its time series, and the posterior Cramer-Rao bound of every causal estimator fed its frames.

    ``estimation_bound_m``: the bound's rms over the seeds' comparison windows (the metrics window away from the
    walls); ``estimation_bound_observer_rms_m``: the pair's observer's rms on the same windows (it can never be
    below the bound in expectation); ``estimation_bound_excluded``: the share of the metrics window left out for
    the walls (1: the bead at a wall all through the window, and no bound); ``estimation_bound_seeds``: the seeds
    whose run completed (a run that fails has no bound).
    """
    run = run_closed_loop if run is None else run  # ``run``: the loop to fly each seed with (a test's stand-in)
    b, o, ex = [], [], []
    for seed in seeds:
        try:
            ts = run(scenario, int(seed)).timeseries
        except (ModelInputError, ConfigError):
            continue
        rb = run_bound(scenario, ts)
        ex.append(rb.excluded_fraction)
        if math.isfinite(rb.bound_rms_m):  # not with the whole window at a wall
            b.append(rb.bound_rms_m)
            o.append(rb.observer_rms_m)
    return {"estimation_bound_m": math.sqrt(float(np.mean(np.square(b)))) if b else math.nan,
            "estimation_bound_observer_rms_m": math.sqrt(float(np.mean(np.square(o)))) if o else math.nan,
            "estimation_bound_excluded": float(np.mean(ex)) if ex else math.nan, "estimation_bound_seeds": len(ex)}


def cell_name(index: int, cell: StudyCell) -> str:
    """The cell's variant name in the campaign (its position first, so names never repeat)."""
    tw = "preset" if cell.tracking_window_s is None else f"{cell.tracking_window_s:g}"
    return (f"{index:03d}-{cell.hardware}-tw{tw}-pw{cell.propulsion_window_s:g}-lat{cell.latency_s:g}-{cell.pair}")


def study_spec(cells: Sequence[StudyCell], runnable: Sequence[int], seeds: Sequence[int],
               run_timeout_s: float | None, extra: dict[int, dict[str, Any]] | None = None) -> dict[str, Any]:
    """The campaign spec mapping of the study: one variant per runnable cell (:func:`cell_changes`, then the cell's
    ``extra`` changes: its planned reference) x ``seeds``."""
    extra = extra or {}
    return {"name": "scanner_study", "base": "-", "seeds": [int(s) for s in seeds],
            "variants": {cell_name(i, cells[i]): {**cell_changes(cells[i]), **extra.get(i, {})} for i in runnable},
            "run_timeout_s": run_timeout_s}


def planned_changes(scenario: Scenario, plan: Plan) -> dict[str, Any]:
    """A cell's changes that fly ``plan`` instead of its reference: the planned reference, the run until it ends,
    and the loop's options for a plan on the wall (:func:`~vesselbot_ros.analysis.plan.flying_changes`)."""
    return {**flatten(to_mapping(plan.reference), "reference."), "sim.duration_s": float(plan.end_s),
            **flying_changes(scenario, plan)}


def plan_bounds(plan: Plan) -> dict[str, float]:
    """A planned cell's bounds: the plan's own margin and coast floor (:mod:`vesselbot_ros.analysis.plan`); its
    estimation and tracking floors are the flown scenario's (:func:`estimation_floor`, :func:`tracking_floor`)."""
    return {"hold_margin_m_per_s2": plan.margin_m_per_s2, "coast_floor_m": plan.coast_floor_m,
            "gradient_to_fly_T_per_m": math.nan}


def cell_row(cell: StudyCell, scenario: Scenario, bounds: dict[str, float], records: Sequence[dict[str, Any]],
             run_timeout_s: float | None) -> dict[str, Any]:
    """One table row from the cell's run records (in seed order): mean / worst tracking and estimation errors.

    The first run that did not finish (in seed order) gives the cell's status:
    ``timeout: ...`` (over the run budget), ``failed (seed N): Type: message``, or
    a run that completed with a status other than ``ok``
    (:func:`~vesselbot_ros.sim.metrics.run_status`): ``diverged (seed N): what
    left the vessel`` or ``rejected_commands (seed N): ...``; then the cell has
    no error columns, as none are over all its seeds.
    """
    row: dict[str, Any] = dataclasses.asdict(cell)
    row.update(tracking_window_s=scenario.sequence.tracking_window_s, duty_cycle=duty_cycle(scenario.sequence),
               frame_rate_Hz=1.0 / scenario.sequence.period_s, **bounds)
    for r in records:
        if r.get("status") == "timeout":
            row.update(status=f"timeout: seed {r['seed']} over {run_timeout_s:g} s of wall time "
                              f"(plant integration crawling)")
            return row
        if r.get("status") not in ("ok", "error", None):  # completed, not a result: diverged, rejected commands
            row.update(status=f"{r['status']} (seed {r['seed']}): {r.get('error')}")
            return row
        if r.get("status") != "ok":
            row.update(status=f"failed (seed {r['seed']}): {r.get('error')}")
            return row
    tr = [float(r["tracking_error_max_m"]) for r in records]
    es = [float(r["estimation_error_rms_m"]) for r in records]
    rms = [float(r["tracking_error_rms_m"]) for r in records]
    row.update(status="ok", tracking_max_mean_m=float(np.mean(tr)), tracking_max_worst_m=float(np.max(tr)),
               tracking_rms_mean_m=float(np.mean(rms)),
               estimation_rms_mean_m=float(np.mean(es)), estimation_rms_worst_m=float(np.max(es)))
    return row


@contextlib.contextmanager
def _folder(runs_dir: str | Path | None) -> Iterator[Path]:
    if runs_dir is not None:
        yield Path(runs_dir)
        return
    with tempfile.TemporaryDirectory(prefix="vesselbot-scanner-study-") as tmp:
        yield Path(tmp)


def run_study(base: Scenario, cells: Sequence[StudyCell], seeds: Sequence[int], workers: int | None = None,
              run_timeout_s: float | None = 300.0, *, scheduler: str | None = None,
              runs_dir: str | Path | None = None, progress: bool = False,
              reference: str = "scenario") -> list[dict[str, Any]]:
    """Run every cell over ``seeds`` on the campaign engine; one row per cell, in the cells' order.

    Args:
        base: The base scenario.
        cells: The grid (:func:`study_cells`).
        seeds: Imager seeds of every cell.
        workers: Parallel runs of the local cluster (default: one per usable core); not with ``scheduler``.
        run_timeout_s: Wall-clock budget of each run (s), None = none; a run over it is stopped and
            its cell recorded as ``timeout``, the other cells go on.
        scheduler: ``tcp://HOST:PORT`` of a Dask scheduler to run on instead of a local cluster.
        runs_dir: The campaign folder of the runs (``results.parquet``, ...); finished runs found
            there are not run again.  None: a temporary folder.
        progress: Draw the engine's progress bar on stderr.
        reference: ``scenario``: every cell flies the base scenario's reference.  ``planned``: every cell
            flies the plan of its own hardware and sequence (``vesselbot plan``; one plan per hardware
            and windows, shared by the pairs and latencies), and its bounds are the plan's margin and
            coast floor; a cell with no feasible plan is recorded with the planner's line.

    Raises:
        ConfigError: a budget that is not > 0, or ``workers`` with ``scheduler``.
        RunError: the cluster cannot be started or reached.
    """
    if run_timeout_s is not None and not (math.isfinite(run_timeout_s) and run_timeout_s > 0):
        raise ConfigError(f"run_timeout_s must be > 0, got {run_timeout_s!r}")
    if scheduler and workers is not None:
        raise ConfigError("workers sizes the local cluster; it does not apply with a scheduler")
    check_choice("reference", reference, ("scenario", "planned"))
    seeds = [int(s) for s in seeds]
    rows: dict[int, dict[str, Any]] = {}
    scenarios: dict[int, Scenario] = {}
    for i, cell in enumerate(cells):
        try:
            scenarios[i] = cell_scenario(base, cell)
        except ConfigError as exc:
            rows[i] = {**dataclasses.asdict(cell), "status": f"refused: {exc}"}
    plans: dict[int, Plan] = {}
    if reference == "planned":
        by_key: dict[tuple[str, float | None, float], Plan | PlanInfeasible] = {}
        for i, sc in list(scenarios.items()):
            key = (cells[i].hardware, cells[i].tracking_window_s, cells[i].propulsion_window_s)
            if key not in by_key:
                try:
                    by_key[key] = make_plan(sc)
                except PlanInfeasible as exc:
                    by_key[key] = exc
            got = by_key[key]
            if isinstance(got, PlanInfeasible):
                rows[i] = {**dataclasses.asdict(cells[i]), "status": str(got)}
                del scenarios[i]
            else:
                plans[i] = got
    if scenarios:
        extra = {i: planned_changes(scenarios[i], plans[i]) for i in plans}
        spec_mapping = study_spec(cells, list(scenarios), seeds, run_timeout_s, extra)
        spec = campaign_spec_from_mapping(spec_mapping)
        prep = prepare(spec, base.to_mapping())
        with _folder(runs_dir) as root:
            store = CampaignStore(root)
            n_runs = len({t.run_id for t in prep.tasks})
            meta = {"name": spec.name, "n_runs": n_runs, "n_seeds": len(seeds),
                    "grid_keys": ["variant"], "varied_keys": ["variant"], "run_timeout_s": run_timeout_s,
                    "code_version": prep.code}
            store.write_manifest(prep.manifest, meta, _yaml(spec_mapping))
            todo = pending(prep.tasks, store, retry_failed=True)  # runs that finished ok are kept
            with dask_client(scheduler, workers) as client:
                # the bounds (pure Python, a second or so per cell) run on the cluster beside the runs
                bounds_futures = {i: client.submit(feasibility, sc, list(seeds), pure=False)
                                  for i, sc in scenarios.items() if i not in plans}
                floor_futures = {i: client.submit(_flown_floors, scenario_with(scenarios[i], extra[i]), list(seeds),
                                                  pure=False) for i in plans}
                bar = Progress("scanner study", n_runs, n_runs - len(todo), enabled=progress)
                execute(todo, store, client, prep.code, progress=bar, run_timeout_s=run_timeout_s)
                bounds = {i: f.result() for i, f in bounds_futures.items()} | {
                    i: {**plan_bounds(p), **floor_futures[i].result()} for i, p in plans.items()}
                results = {r["run_id"]: r for r in store.assemble().to_pylist()}
                by_cell: dict[str, list[dict[str, Any]]] = {}
                for task, entry in zip(prep.tasks, prep.manifest):
                    by_cell.setdefault(entry["variant"], []).append({**results[task.run_id], "seed": task.seed})
                # the estimation bound flies each run again with its time series: only cells whose runs all finished
                # (a run over the budget would stall it), on the cluster
                bound_futures = {i: client.submit(bound_columns, scenario_with(sc, extra[i]) if i in extra else sc,
                                                  list(seeds), pure=False)
                                 for i, sc in scenarios.items()
                                 if all(r.get("status") == "ok" for r in by_cell[cell_name(i, cells[i])])}
                for i, f in bound_futures.items():
                    bounds[i] = {**bounds[i], **f.result()}
        for i, sc in scenarios.items():
            rows[i] = cell_row(cells[i], sc, bounds[i], by_cell[cell_name(i, cells[i])], run_timeout_s)
    return [rows[i] for i in range(len(cells))]


def _yaml(mapping: dict[str, Any]) -> str:
    return str(yaml.safe_dump(to_mapping(mapping), sort_keys=False))


def fmt_um(v: Any) -> str:
    """Micrometres for a table cell ('-' when missing)."""
    return "-" if not isinstance(v, float) or not math.isfinite(v) else f"{v * 1e6:.0f}"
