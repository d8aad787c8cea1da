"""ROS-free closed loop of Section III-C: plant -> imager -> observer -> controller -> coil.

The runner is nothing but the stages' per-tick methods, called in this order
at ``t_k = k / control_rate_Hz`` (``k = 0 .. n-1``)::

    truth = plant.output()                                   # ground truth at t_k
    meas  = imager.frame(t_k, truth.p)                       # Measurement | None
    est   = observer.update(t_k, meas, coil_prev.applied)    # Estimate
    ref   = reference.sample(t_k)                            # RefSample
    cmd   = controller.command(t_k, est, ref)                # ControlCommand
    coil  = coil_limiter.apply(t_k, cmd.gradient_T_per_m)    # CoilOutput
    plant.step(coil.applied)                                 # integrate [t_k, t_k+1]

A ROS node graph that calls the same methods with the same inputs reproduces
the same numbers: :func:`build_stages` is the one place where the stages are
constructed from a :class:`~vesselbot_ros.sim.scenario.Scenario`.  The only
liberty the runner takes is to evaluate the reference for all ticks at once
(:meth:`ReferenceTrajectory.sample_many`, bit-identical to ``sample``).

Two paths, the same numbers.  When every stage is built in,
:func:`run_closed_loop` runs the whole horizon in one compiled call
(:mod:`vesselbot_ros.sim.compiled_loop`, about ten times faster); when a
scenario plugs in a user's Python stage (``stages={"controller": obj}``, an
object with the built-in stage's method) it runs the per-tick loop above.  Both
are bit-identical on every column, metric and run statistic;
``SimResult.path`` says which one ran.  :func:`run_many` runs batches of runs
over seeds and scenario variants on several cores, each row equal to the
single run.

Time-series columns (``SimResult.timeseries``; vectors are (n, 2) over (x, z), or (n, 3) over (x, y, z) in a
3-D vessel tree (``Scenario.dims``; the same loop and the same compiled kernel on three axes)):

===================  =======  ==============================================
key                  unit     meaning
===================  =======  ==============================================
t_s                  s        tick time
p_true, v_true       m, m/s   true position / velocity at t_k
delta_m              m        signed distance to the nearest wall (>0 contact)
in_contact           bool     delta_m > 0
contact_phase        -        0 free, 1 loading, 2 unloading
p_ref, v_ref, a_ref  m, m/s,  reference and its derivatives
                     m/s^2
meas_p               m        measurement delivered at t_k (NaN if none)
meas_t_acq_s         s        its acquisition time (NaN if none)
meas_outlier         bool     injected aberrant frame (ground truth flag)
x_hat, z_hat         m, m/s   observer estimate after the update at t_k
flow_scale_hat       -        estimated blood-velocity scale s_hat: the observer's (EKF) or the adaptive
                              controller's after its update at this tick (1 if not estimated)
magnetization_scale_hat -     adaptive controller's magnetisation scale m_hat (1 if not estimated)
meas_used            bool     a measurement corrected the estimate
meas_rejected        bool     a measurement was rejected (non-finite, gate)
u_cmd                m/s^2    U of eq. (24)
g_cmd                T/m      commanded gradient
g_applied            T/m      gradient applied by the coil on [t_k, t_k+1]
k_scale              -        saturation factor k of Section III-C
saturated            bool     k > 1
slew_limited         bool     (n, 2) slew limit active per axis
cmd_status           -        0 ok, 1 stale (safe action), 2 non-finite (the law's safe action, or a rejected
                              command)
cmd_rejected         -        0 the command was taken; else why it was rejected (kinds.REJECT_REASONS: 1
                              non-finite, 2 non-finite estimate (controller not called), 3 the controller
                              raised, 4 not a command): the coil ramped towards zero at the slew limit
sequence_phase       -        scanner phase at t_k: 0 continuous, 1 tracking, 2 dead, 3 propulsion
forces               N        (n, 8, 2) force terms (only if record_forces)
===================  =======  ==============================================
"""

from __future__ import annotations

import dataclasses
import os
import threading
import weakref
from collections.abc import Generator, Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Literal, NamedTuple

import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.model import DynamicsModel
from vesselbot_ros.control.route import navigation_metrics
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.scanner.sequence import phase_codes, sequence_vector
from vesselbot_ros.sim import compiled_loop, kinds
from vesselbot_ros.sim.metrics import compute_metrics
from vesselbot_ros.sim.scenario import Scenario, short_copy

__all__ = ["Stages", "SimResult", "build_stages", "build_stage", "warm_up", "run_closed_loop", "run_stages", "run_many", "STATUS_CODES",
           "PATHS", "REPLACEABLE", "frame_counts", "Tick", "per_tick_ticks"]

STATUS_CODES = {"ok": 0, "stale": 1, "nonfinite": 2}
#: ``SimResult.path``: ``compiled`` (one compiled call) or ``per_tick`` (Python loop over the stages' methods).
PATHS = ("compiled", "per_tick")


class Stages(NamedTuple):
    """The seven stages of the loop, each owning its state, built through their kinds (:mod:`vesselbot_ros.sim.kinds`);
    the tracker is None when the imager delivers positions.

    Each follows its role's protocol (:class:`~vesselbot_ros.sim.kinds.PlantStage` ...); the built-in kinds'
    classes are ``PlantSimulator``, ``ImagerModel``/``SequencedImager``, ``HighGainObserver``/
    ``ExtendedKalmanObserver``, ``ReferenceTrajectory``, ``BacksteppingController`` and ``CoilLimiter``/``SequencedCoil``.
    """

    plant: kinds.PlantStage
    imager: kinds.ImagerStage
    tracker: kinds.TrackerStage | None
    observer: kinds.ObserverStage
    reference: kinds.ReferenceStage
    controller: kinds.ControllerStage
    coil: kinds.CoilStage
    model: DynamicsModel


#: Stages a scenario may replace with a user's object (``stages=`` of :func:`run_closed_loop`):
#: every field of :class:`Stages` but the model.
REPLACEABLE = tuple(f for f in Stages._fields if f != "model")


@dataclasses.dataclass(frozen=True)
class SimResult:
    """Output of :func:`run_closed_loop`.

    Attributes:
        timeseries: Columns documented in the module docstring (empty for
            :func:`run_many` rows unless ``keep_timeseries``).
        metrics: :func:`~vesselbot_ros.sim.metrics.compute_metrics` output
            plus run statistics (``plant_steps``, ``plant_rejected_steps``,
            ``plant_rhs_evals``, ``plant_forced_steps``, ``observer_rhs_evals``).
        path: Which loop ran: ``compiled`` or ``per_tick`` (:data:`PATHS`).
    """

    timeseries: dict[str, npt.NDArray[Any]]
    metrics: dict[str, Any]
    path: str = "per_tick"


class _StageBuilder:
    """Builds the stages of one scenario through their kinds (:mod:`vesselbot_ros.sim.kinds`), each on first use.

    A node process needs one stage; building the reference (a spline fit, and
    scipy.interpolate's 0.7 s import) or the model for a stage that uses neither
    made every node start as slowly as the whole loop.
    """

    def __init__(self, scenario: Scenario, seed: int | None) -> None:
        self.s = scenario
        self.seed = scenario.seed if seed is None else int(seed)
        self._built: dict[str, Any] = {}

    def get(self, name: str) -> Any:
        if name not in self._built:
            if name == "model_physics":  # the model's own physics (blood-velocity error): the model and the reference
                self._built[name] = self.s.model_physics()
            elif name == "model":
                self._built[name] = DynamicsModel(self.get("model_physics"), self.s.sim.integrator,
                                                  self.s.model.input_mapping)
            else:
                self._built[name] = kinds.build(name, self)
        return self._built[name]


def build_stages(scenario: Scenario, seed: int | None = None) -> Stages:
    """Construct every stage of the loop for ``scenario``.

    Args:
        scenario: The scenario.
        seed: Imager seed; ``None`` uses ``scenario.seed``.
    """
    b = _StageBuilder(scenario, seed)
    return Stages(*(b.get(name) for name in Stages._fields))


def build_stage(scenario: Scenario, name: str, seed: int | None = None) -> Any:
    """Construct one stage of the loop (a field of :class:`Stages`), as :func:`build_stages` builds it.

    Only what that stage needs is built (the controller needs the model, the
    observer the model and the reference's start), so a node that runs one
    stage starts without paying for the others.

    Raises:
        ModelInputError: if ``name`` is not a stage.
    """
    _check_stage_names("build_stage", [name])
    return _StageBuilder(scenario, seed).get(name)


def _check_stage_names(caller: str, names: Iterable[str]) -> None:
    unknown = sorted(set(names) - set(Stages._fields))
    if unknown:
        raise ModelInputError(f"{caller}: unknown stage(s) {unknown}; stages: {list(Stages._fields)}")


#: Ticks a warm-up runs: the first calls load numba's cache and allocate; three settle every branch taken at start.
WARM_TICKS = 3


def warm_up(scenario: Scenario, stages: Iterable[str] | None = None) -> None:
    """Call the per-tick methods of ``scenario``'s stages a few times on throwaway copies, for their first-call costs.

    Loading compiled code from numba's cache, first-time allocations and lazy
    imports happen on a stage's first call (tens of ms).  A node calls this
    before its run starts, so its first ticks are on time; nothing of the run's
    own stages (state, noise stream) is touched.

    Args:
        scenario: The scenario.
        stages: Names of the stages to warm (fields of :class:`Stages`); ``None``
            runs a few ticks of the whole per-tick loop.  A node warms its own.
    """
    short = short_copy(scenario, WARM_TICKS / scenario.sim.control_rate_Hz)  # a multiplexed sequence fits its ticks
    if stages is None:
        run_closed_loop(short, path="per_tick")
        return
    names = list(stages)
    _check_stage_names("warm_up", names)
    b = _StageBuilder(short, None)
    dt = short.sim.dt_control_s
    ts = [k * dt for k in range(short.sim.n_ticks)]  # WARM_TICKS, or the copy's one MR acquisition window
    p0 = np.asarray(short.initial.p0_m, dtype=np.float64)
    v0 = np.asarray(short.initial.v0_m_per_s, dtype=np.float64)
    zero = np.zeros(short.dims)
    for name in names:
        stage = b.get(name)
        if name == "plant":
            for _ in ts:
                stage.output(True)
                stage.output(False)
                stage.step(zero)
        elif name == "imager":
            for t in ts:
                stage.frame(t, p0)
        elif name == "tracker":
            if stage is not None:  # an imager of MR frames: track what it delivers
                imager = b.get("imager")
                for t in ts:
                    frame = imager.frame(t, p0)
                    if frame is not None:
                        stage.track(t, frame)
        elif name == "observer":
            imager, tracker = b.get("imager"), b.get("tracker")  # its frames feed the observer
            for t in ts:
                meas = imager.frame(t, p0)
                if tracker is not None and meas is not None:
                    meas = tracker.track(t, meas)
                stage.update(t, meas, zero)
        elif name == "reference":
            stage.sample_many(np.asarray(ts))
            stage.sample(0.0)
        elif name == "controller":
            for t in ts:
                kinds.call_controller(stage, t, p0, v0, 0.0, 1.0, p0, zero, zero)
        elif name == "coil":
            for t in ts:
                stage.apply(t, zero)
        # the model has no per-tick method of its own: the observer and controller call it


def run_closed_loop(
    scenario: Scenario,
    seed: int | None = None,
    *,
    stages: Mapping[str, Any] | None = None,
    path: Literal["auto", "compiled", "per_tick"] = "auto",
) -> SimResult:
    """Run the closed loop of ``scenario`` and compute its metrics.

    Args:
        scenario: The scenario.
        seed: Imager seed; ``None`` uses ``scenario.seed``.  The same seed
            gives bit-identical results.
        stages: Stages to replace with your own objects, by name
            (:data:`REPLACEABLE`): each needs the built-in stage's per-tick
            method (``controller.command(t, estimate, ref)`` or
            ``command_arrays``; ``observer.update``; ``imager.frame``;
            ``coil.apply``; ``plant.output``/``step``; ``reference.sample_many``).
            Build on :func:`build_stages` to reuse the model.  A replaced stage
            runs the per-tick loop.
        path: ``auto`` (compiled unless a stage is replaced), or force
            ``compiled`` / ``per_tick`` (both give the same numbers).

    Returns:
        The :class:`SimResult`; ``path`` says which loop ran.

    Raises:
        ModelInputError: if an integration fails (reported with the state), or
            ``path="compiled"`` with a user stage.
    """
    user = dict(stages or {})
    unknown = sorted(set(user) - set(REPLACEABLE))
    if unknown:
        raise ModelInputError(f"stages: unknown stage name(s) {unknown}; replaceable: {list(REPLACEABLE)}")
    if path not in ("auto", "compiled", "per_tick"):
        raise ModelInputError(f"path must be 'auto', 'compiled' or 'per_tick', got {path!r}")
    if not user and path != "per_tick":
        inp = prepared(scenario)  # built-in stages: prepared once per scenario, the imager's seed per run
        if inp is not None:
            return _compiled_result(scenario, seed, inp, np.random.default_rng(scenario.seed if seed is None else int(seed)))
    st = build_stages(scenario, seed)
    return run_stages(scenario, st._replace(**user), seed, path=path)


def run_stages(
    scenario: Scenario,
    stages: Stages,
    seed: int | None = None,
    *,
    path: Literal["auto", "compiled", "per_tick"] = "auto",
) -> SimResult:
    """Run the loop over stages you built (:func:`build_stages`, then modified or replaced).

    The compiled loop runs when every stage is an unmodified type of the
    built-in ones (it reads their parameters and initial state); otherwise the
    per-tick loop calls their methods.  ``seed`` only labels the metrics: the
    imager's generator is the one in ``stages``.  See :func:`run_closed_loop`.
    """
    if path not in ("auto", "compiled", "per_tick"):
        raise ModelInputError(f"path must be 'auto', 'compiled' or 'per_tick', got {path!r}")
    if path != "per_tick":
        inp, foreign = _prepare(scenario, stages)
        if path == "compiled" and foreign:
            raise ModelInputError(f"path='compiled' needs the built-in stages, got user stage(s) {foreign}")
        if inp is not None:
            imager: Any = stages.imager  # a built-in imager (not foreign): it holds the run's generator
            return _compiled_result(scenario, seed, inp, imager.rng)
    return _run_per_tick(scenario, seed, stages)


# Prepared kernel inputs per scenario object (a frozen Scenario: the same object is the same scenario), so that
# repeated runs of one scenario over seeds build the stages and sample the reference once.  Keyed on id() and
# checked through a weak reference (the dict never keeps a scenario alive, and a recycled id is detected).
Inputs = compiled_loop.LoopInputs
_PREPARED: dict[int, tuple[weakref.ref[Scenario], Inputs | None]] = {}
_PREPARED_LOCK = threading.Lock()
_PREPARED_MAX = 64


def prepared(scenario: Scenario) -> Inputs | None:
    """The compiled loop's inputs for ``scenario`` (None if its stages are not all built in), cached per object."""
    key = id(scenario)
    with _PREPARED_LOCK:
        hit = _PREPARED.get(key)
        if hit is not None and hit[0]() is scenario:
            return hit[1]
    st = build_stages(scenario, None)
    inp = _prepare(scenario, st)[0]
    with _PREPARED_LOCK:
        if len(_PREPARED) >= _PREPARED_MAX:
            _PREPARED.clear()
        _PREPARED[key] = (weakref.ref(scenario), inp)
    return inp


def _prepare(scenario: Scenario, stages: Stages) -> tuple[Inputs | None, list[str]]:
    """The compiled loop's inputs of ``stages``, or None and the roles it cannot run."""
    sim = scenario.sim
    return compiled_loop.try_prepare(stages, sim.n_ticks, sim.dt_control_s, sim.record_forces)


def _compiled_result(scenario: Scenario, seed: int | None, inp: Inputs, rng: np.random.Generator,
                     keep_timeseries: bool = True) -> SimResult:
    cols, plant_stats, model_stats = compiled_loop.run_kernel(inp, rng)
    # copies: the prepared inputs are shared by every run of the scenario and must not be written through a result
    series: dict[str, npt.NDArray[Any]] = {"t_s": inp.ts.copy(), "p_ref": inp.p_ref.copy(), "v_ref": inp.v_ref.copy(),
                                           "a_ref": inp.a_ref.copy()}
    series.update(cols)
    series["sequence_phase"] = _sequence_phase(scenario, series["t_s"])
    metrics = _metrics(scenario, seed, series, plant_stats, model_stats)
    return SimResult(series if keep_timeseries else {}, metrics, "compiled")


def _sequence_phase(scenario: Scenario, ts: npt.NDArray[np.float64]) -> npt.NDArray[np.int8]:
    """The scanner's phase code at every tick (``sequence_phase`` column; compiled :func:`phase_codes`)."""
    return phase_codes(sequence_vector(scenario.sequence), ts)


def _metrics(scenario: Scenario, seed: int | None, series: Mapping[str, npt.NDArray[Any]],
             plant_stats: npt.NDArray[np.int64], model_stats: npt.NDArray[np.int64]) -> dict[str, Any]:
    # every tick is computed here: a NaN position or estimate is a divergence, not a missing sample
    metrics: dict[str, Any] = dict(compute_metrics(series, scenario.sim.metrics_after_s,
                                                   vessel_diameter_m=scenario.physics.vessel.diameter_m,
                                                   nonfinite_diverges=True))
    metrics.update(
        scenario=scenario.name,
        seed=scenario.seed if seed is None else int(seed),
        plant_steps=int(plant_stats[0]),
        plant_rejected_steps=int(plant_stats[1]),
        plant_rhs_evals=int(plant_stats[2]),
        plant_forced_steps=int(plant_stats[3]),
        observer_rhs_evals=int(model_stats[2]),
        measurements_used=int(np.count_nonzero(series["meas_used"])),
        measurements_rejected=int(np.count_nonzero(series["meas_rejected"])),
        outlier_frames=int(np.count_nonzero(series["meas_outlier"])),
    )
    codes = np.unique(series["cmd_rejected"])
    reasons = [kinds.REJECT_REASONS[int(c)] for c in codes if int(c) in kinds.REJECT_REASONS]
    if reasons:  # the words of the warning line (kinds.rejection_warning)
        metrics["rejected_command_reasons"] = ", ".join(reasons)
    if scenario.physics.vessel.network:
        metrics.update(navigation_metrics(scenario, series["t_s"], series["p_true"]))
    return metrics


def frame_counts(imager: Any, tracker: Any) -> dict[str, Any]:
    """The run's MR frame counts: delivered within the run (``imager_frames``), dropped (``imager_frames_rejected``:
    superseded by a newer frame, or rejected by the tracker) and why (``imager_rejected_reasons``; a user's stages
    may count less)."""
    reasons: dict[str, int] = dict(getattr(tracker, "rejected", {}) or {})
    superseded = int(getattr(imager, "superseded", 0))
    if superseded:
        reasons["superseded"] = superseded
    out: dict[str, Any] = {"imager_frames": int(getattr(tracker, "frames", 0)) + superseded,
                           "imager_frames_rejected": int(sum(reasons.values()))}
    if reasons:
        out["imager_rejected_reasons"] = ", ".join(f"{k}: {v}" for k, v in sorted(reasons.items()))
    return out


class Tick(NamedTuple):
    """What :func:`per_tick_ticks` yields at tick ``k``, after the observer's update: the plant's output, the
    estimate, the reference at ``t_k`` and the gradient the coil applied over the last period (zero at tick 0)."""

    k: int
    t_s: float
    truth: Any
    estimate: Any
    p_ref: npt.NDArray[np.float64]
    v_ref: npt.NDArray[np.float64]
    a_ref: npt.NDArray[np.float64]
    g_applied: npt.NDArray[np.float64]


def per_tick_ticks(scenario: Scenario, st: Stages, n: int
                   ) -> Generator[Tick, tuple[Any, int], tuple[dict[str, npt.NDArray[Any]], dict[str, Any]]]:
    """The per-tick loop (module docstring) over ``n`` ticks, one at a time: yields a :class:`Tick` after the
    observer's update at tick k and takes that tick's ``(command, rejection code)`` back (``send``; a rejected
    command's gradient is NaN: the coil ramps to zero), then runs the coil and the plant to tick k + 1.  Returns
    ``(series, metrics)`` after the last tick.  :func:`_run_per_tick` sends the controller's commands; the
    image-based environment (:mod:`vesselbot_ros.envs.stage_env`) an agent's."""
    dt = scenario.sim.dt_control_s
    ts = np.asarray(np.arange(n) * dt, dtype=np.float64)  # float64 already; the dtype types it
    p_ref, v_ref, a_ref = st.reference.sample_many(ts)
    rec_forces = scenario.sim.record_forces

    d = scenario.dims
    f2 = {k: np.empty((n, d)) for k in ("p_true", "v_true", "meas_p", "x_hat", "z_hat", "u_cmd", "g_cmd", "g_applied")}
    f1 = {k: np.empty(n) for k in ("delta_m", "meas_t_acq_s", "k_scale", "flow_scale_hat",
                                      "magnetization_scale_hat")}
    b1 = {k: np.zeros(n, dtype=bool) for k in ("in_contact", "meas_outlier", "meas_used", "meas_rejected", "saturated")}
    slew = np.zeros((n, d), dtype=bool)
    phase = np.zeros(n, dtype=np.int8)
    seq_phase = _sequence_phase(scenario, ts)
    status = np.zeros(n, dtype=np.int8)
    rejected = np.zeros(n, dtype=np.int8)
    forces = np.empty((n, 8, d)) if rec_forces else None

    plant, imager, observer, controller, coil = st.plant, st.imager, st.observer, st.controller, st.coil
    tracker = st.tracker if kinds.delivers_frames(scenario) else None
    adapted = getattr(controller, "adapted", None)  # an adaptive law's scales (flow_scale, magnetization_scale)
    g_prev = np.zeros(d)
    nan2 = np.full(d, np.nan)
    for k in range(n):
        t = float(ts[k])
        truth = plant.output(rec_forces)
        meas = imager.frame(t, truth.p)
        if tracker is not None and meas is not None:  # an MR frame: the tracker's position, or None (rejected)
            meas = tracker.track(t, meas)
        est = observer.update(t, meas, g_prev)
        cmd, why = yield Tick(k, t, truth, est, p_ref[k], v_ref[k], a_ref[k], g_prev)
        if why:
            rejected[k] = why
        out = coil.apply(t, cmd.gradient_T_per_m if not why else nan2)
        plant.step(out.applied)
        g_prev = out.applied

        f2["p_true"][k] = truth.p
        f2["v_true"][k] = truth.v
        f1["delta_m"][k] = truth.delta_m
        b1["in_contact"][k] = truth.in_contact
        phase[k] = truth.contact_phase
        if meas is None:
            f2["meas_p"][k] = nan2
            f1["meas_t_acq_s"][k] = np.nan
        else:
            f2["meas_p"][k] = meas.p
            f1["meas_t_acq_s"][k] = meas.t_acq_s
            b1["meas_outlier"][k] = meas.outlier
        f2["x_hat"][k] = est.x_hat
        f2["z_hat"][k] = est.z_hat
        if adapted is None or why == kinds.REJECT_ESTIMATE:  # (the controller did not run on a non-finite estimate)
            f1["flow_scale_hat"][k] = getattr(est, "flow_scale", 1.0)
            f1["magnetization_scale_hat"][k] = 1.0
        else:
            adapted = getattr(controller, "adapted")  # noqa: B009 - reset() replaces it; not every controller has it
            f1["flow_scale_hat"][k] = adapted.flow_scale
            f1["magnetization_scale_hat"][k] = adapted.magnetization_scale
        b1["meas_used"][k] = est.used_measurement
        b1["meas_rejected"][k] = est.rejected
        f2["u_cmd"][k] = cmd.u_m_per_s2
        f2["g_cmd"][k] = cmd.gradient_T_per_m
        status[k] = STATUS_CODES[cmd.status]
        f2["g_applied"][k] = out.applied
        f1["k_scale"][k] = out.k_scale
        b1["saturated"][k] = out.saturated
        slew[k] = out.slew_limited
        if forces is not None and truth.forces is not None:
            forces[k] = truth.forces

    series: dict[str, npt.NDArray[Any]] = {"t_s": ts, "p_ref": p_ref, "v_ref": v_ref, "a_ref": a_ref}
    series.update(f2)
    series.update(f1)
    series.update(b1)
    series["slew_limited"] = slew
    series["contact_phase"] = phase
    series["sequence_phase"] = seq_phase
    series["cmd_status"] = status
    series["cmd_rejected"] = rejected
    if forces is not None:
        series["forces"] = forces
    observer_stats = getattr(getattr(observer, "model", None), "stats", np.zeros(4, dtype=np.int64))
    plant_stats = getattr(plant, "stats", np.zeros(4, dtype=np.int64))  # a user's plant may count nothing
    return series, {"plant_stats": plant_stats, "observer_stats": observer_stats}


def _run_per_tick(scenario: Scenario, seed: int | None, st: Stages) -> SimResult:
    """The per-tick loop over the stages' methods (module docstring): :func:`per_tick_ticks` driven by the
    controller."""
    d = scenario.dims
    controller = st.controller
    reject_details: dict[int, str] = {}
    ticks = per_tick_ticks(scenario, st, scenario.sim.n_ticks)
    try:
        tick = next(ticks)
        while True:
            est = tick.estimate
            # the controller gets what the graph carries between the nodes (kinds.call_controller: the same
            # numbers); a bad command (non-finite, raised, not a command) is rejected: the coil ramps to zero
            cmd, why, detail = kinds.checked_command(controller, tick.t_s, est.x_hat, est.z_hat,
                                                     est.time_since_measurement_s, getattr(est, "flow_scale", 1.0),
                                                     tick.p_ref, tick.v_ref, tick.a_ref, d)
            if why and why not in reject_details:
                reject_details[why] = detail
            tick = ticks.send((cmd, why))
    except StopIteration as stop:
        series, stats = stop.value
    metrics = _metrics(scenario, seed, series, stats["plant_stats"], stats["observer_stats"])
    if kinds.REJECT_RAISED in reject_details:  # what the controller raised first (only a Python stage can)
        metrics["rejected_command_error"] = reject_details[kinds.REJECT_RAISED]
    if kinds.REJECT_MALFORMED in reject_details:
        metrics["rejected_command_malformed"] = reject_details[kinds.REJECT_MALFORMED]
    tracker = st.tracker if kinds.delivers_frames(scenario) else None
    if tracker is not None:
        metrics.update(frame_counts(st.imager, tracker))
    return SimResult(series, metrics, "per_tick")


def run_many(
    scenarios: Scenario | Sequence[Scenario],
    seeds: Iterable[int] | None = None,
    *,
    workers: int | None = None,
    keep_timeseries: bool = False,
) -> list[SimResult]:
    """A batch of compiled runs over scenario variants and seeds, parallel over cores.

    This is the unit of work of a campaign: hand each worker (e.g. a Dask
    task) a chunk, ``run_many(variants, seeds)`` with tens to hundreds of runs,
    so the per-call overhead (stage construction once per variant, the
    thread pool) stays small against ~15 ms per run.

    Args:
        scenarios: One scenario or a sequence of variants (e.g. built with
            ``dataclasses.replace`` or ``scenario_from_mapping``).  Each is
            prepared once (stages, reference samples) and shared by its seeds.
        seeds: Imager seeds run for every scenario; ``None`` runs each
            scenario once with its own ``seed``.
        workers: Threads (the compiled loop releases the GIL); ``None`` uses
            every core this process may run on, ``1`` runs in the caller's thread
            (use 1 inside a task of an engine that already runs one task per
            core, e.g. a Dask worker with ``nthreads`` = cores).
        keep_timeseries: Keep every run's time series (memory: ~0.5 MB per
            2000-tick run); by default rows carry metrics only.

    Returns:
        One :class:`SimResult` per run, in order ``for scenario in scenarios:
        for seed in seeds``; each equal, metric for metric (and column for
        column with ``keep_timeseries``), to ``run_closed_loop(scenario, seed)``.
        ``metrics["scenario"]`` and ``metrics["seed"]`` name the run.

    Raises:
        ModelInputError: the first failing run's error (as
            :func:`run_closed_loop` raises it); the other runs still finish.
    """
    variants = [scenarios] if isinstance(scenarios, Scenario) else list(scenarios)
    seed_list = None if seeds is None else [int(x) for x in seeds]
    jobs: list[tuple[Scenario, int | None, Inputs | None]] = []
    for sc in variants:
        # a variant with stages the compiled loop does not have runs the per-tick loop
        inp = prepared(sc)
        for seed in seed_list if seed_list is not None else [None]:
            jobs.append((sc, seed, inp))

    def one(job: tuple[Scenario, int | None, Inputs | None]) -> SimResult:
        sc, seed, inp = job
        if inp is None:
            res = _run_per_tick(sc, seed, build_stages(sc, seed))
            return res if keep_timeseries else SimResult({}, res.metrics, res.path)
        rng = np.random.default_rng(sc.seed if seed is None else seed)
        return _compiled_result(sc, seed, inp, rng, keep_timeseries)

    n_workers = workers if workers is not None else len(os.sched_getaffinity(0))
    if n_workers < 1:
        raise ModelInputError(f"workers must be >= 1, got {workers!r}")
    if n_workers == 1 or len(jobs) <= 1:
        return [one(j) for j in jobs]
    with ThreadPoolExecutor(max_workers=min(n_workers, len(jobs))) as pool:
        return list(pool.map(one, jobs))
