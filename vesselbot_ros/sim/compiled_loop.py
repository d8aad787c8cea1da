"""The closed loop of :mod:`vesselbot_ros.sim.closed_loop` as one compiled function, on the vessel's axes.

:func:`loop_kernel` runs every tick of one run in numba, calling the compiled stages in the runner's order::

    plant output (physics.integrator.wall_and_forces)
    -> imager_frame | seq_imager_frame (scanner)
    -> the observer's compiled step, of any kind (control/compiled_stage.py: observer (25), the extended Kalman filter)
    -> the controller's compiled step, of any kind (law (24), its adaptive form, the predictive controller, ...)
    -> coil_apply | seq_coil_apply (scanner) -> plant step (the one integrator, physics.integrator.integrate)

over explicit state arrays that :func:`prepare` builds from the compiled form each role's kind gives of the same
:class:`~vesselbot_ros.sim.closed_loop.Stages` as the per-tick loop's (:attr:`~vesselbot_ros.sim.kinds.StageKind.compile`:
the plant's vessel and state, the reference's samples at the tick times, the imager's and the coil's arrays, the
observer's and the controller's steps), and it writes every time-series column into arrays allocated once per run.  One kernel serves
the plane (a straight vessel or a planar network: d = 2 axes, x and z) and a 3-D tree (d = 3): the axis count is
the plant state's, and the vessel is the ``geom`` argument of the integrator's geometry edge, so numba compiles
the kernel once per geometry type.  Each stage does the same IEEE operations in the same order as its Python class
(the classes call the very same functions), so the two paths are bit-identical;
``test/unit/sim/test_compiled_loop.py`` checks every column, metric and run statistic.

One tick body, two drivers.  A tick is three compiled functions over explicit state: :func:`sense` (plant output,
imager, observer), :func:`command` (the controller's step, or an external command through :func:`take_command`)
and :func:`actuate` (coil, plant step).  :func:`loop_kernel` calls them for ticks ``0 .. n-1`` of one run (the
controller commands, or ``g_ext`` replays given commands); :func:`step_copies` calls the same functions to advance N
copies of the loop by one tick each, the command coming from outside (the Gymnasium environments of
:mod:`vesselbot_ros.envs`: the agent's action sits where the controller's command was, between the observer's
update and the coil).  No second copy of the tick body exists, so a copy stepped by a sequence of commands and
``loop_kernel`` replaying them give the same bits.  The three are inlined (numba ``inline="always"``) into
:func:`tick_loop` and :func:`step_copies`, which run without numba's runtime (no reference counts on the tick's
arrays): the loop costs what it cost as one function.  They take their arrays grouped in tuples, as a call of more
than 30 arguments is a ``*args`` call in Python's bytecode, which numba does not inline.

Random draws: the imager's ``numpy.random.Generator`` is passed into the kernel and drawn from in the documented
order (d standard normals, then d uniforms per acquired frame), so one seed gives one stream in both paths.

Bad input inside the loop (a non-finite state, a failing integrator, a flow scale the law cannot use) stops the
kernel at that tick with a code; :func:`raise_for_code` raises the per-tick loop's
:class:`~vesselbot_ros.errors.ModelInputError`, word for word.

The kernel releases the GIL (``nogil``), so :func:`~vesselbot_ros.sim.closed_loop.run_many` runs several in threads.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.backstepping import flow_scale_message
from vesselbot_ros.control.compiled_stage import (
    STEP_FLOW_SCALE_INVALID,
    CompiledController,
    CompiledObserver,
    observer_step_at,
)
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.integrator import (
    OK,
    axes_of,
    failure_message,
    integrate,
    new_workspace,
    wall_and_forces,
)
from vesselbot_ros.scanner.actuator_limits import coil_apply
from vesselbot_ros.scanner.imager_model import imager_frame, queue_columns
from vesselbot_ros.scanner.stages import new_seq_imager_state, seq_coil_apply, seq_imager_frame
from vesselbot_ros.sim import kinds
from vesselbot_ros.sim.kinds import REJECT_ESTIMATE, REJECT_MALFORMED, REJECT_NONFINITE

__all__ = ["LoopInputs", "prepare", "try_prepare", "compiled_forms", "loop_kernel", "tick_loop", "sense", "command",
           "take_command", "actuate", "step_copies", "step_scratch", "OP_STEP", "OP_RESET", "OP_SKIP", "run_kernel",
           "raise_for_code", "columns", "COLUMNS"]

# codes of loop_kernel (besides OK): where the loop stopped
PLANT_FAILED = 1  # plant integration failed (non-finite state)
OBSERVER_FAILED = 2  # the observer's step failed (its err says how: CompiledObserver.message)
REFERENCE_NONFINITE = 4  # the controller got a non-finite reference sample
FLOW_SCALE_FAILED = 6  # the compensating law got a flow scale it cannot use

#: (name, dtype, trailing shape) of the columns the kernel fills, in its argument order; ``"d"`` is the axis count.
_COLUMN_SPEC: tuple[tuple[str, Any, tuple[Any, ...]], ...] = (
    ("p_true", np.float64, ("d",)),
    ("v_true", np.float64, ("d",)),
    ("delta_m", np.float64, ()),
    ("in_contact", np.bool_, ()),
    ("contact_phase", np.int8, ()),
    ("meas_p", np.float64, ("d",)),
    ("meas_t_acq_s", np.float64, ()),
    ("meas_outlier", np.bool_, ()),
    ("x_hat", np.float64, ("d",)),
    ("z_hat", np.float64, ("d",)),
    ("flow_scale_hat", np.float64, ()),
    ("magnetization_scale_hat", np.float64, ()),
    ("meas_used", np.bool_, ()),
    ("meas_rejected", np.bool_, ()),
    ("u_cmd", np.float64, ("d",)),
    ("g_cmd", np.float64, ("d",)),
    ("g_applied", np.float64, ("d",)),
    ("k_scale", np.float64, ()),
    ("saturated", np.bool_, ()),
    ("slew_limited", np.bool_, ("d",)),
    ("cmd_status", np.int8, ()),
    ("cmd_rejected", np.int8, ()),
)


@functools.cache  # the same tuple every run (run_kernel asks it per run)
def columns(dims: int) -> tuple[tuple[str, Any, tuple[int, ...]], ...]:
    """(name, dtype, trailing shape) of the kernel's columns on ``dims`` axes, in its argument order."""
    return tuple((name, dt, tuple(dims if a == "d" else a for a in shape)) for name, dt, shape in _COLUMN_SPEC)


#: The planar loop's columns (:func:`columns` of 2 axes).
COLUMNS = columns(2)


@dataclass
class LoopInputs:
    """Everything :func:`loop_kernel` reads for one scenario (shared by the runs of a batch; read-only).

    Built by :func:`prepare` from freshly built stages; the per-run state is
    created by :func:`run_kernel` (copies of the initial state held here).
    """

    n: int
    dt: float
    dims: int
    ts: npt.NDArray[np.float64]
    p_ref: npt.NDArray[np.float64]
    v_ref: npt.NDArray[np.float64]
    a_ref: npt.NDArray[np.float64]
    plant_geom: Any
    model_geom: Any
    ig: npt.NDArray[np.float64]
    imager_prm: npt.NDArray[np.float64]
    outliers: npt.NDArray[np.float64]
    dropouts: npt.NDArray[np.float64]
    obs: CompiledObserver
    ctrl: CompiledController
    obs_step: Any  # obs.step and ctrl.step for the models' geometry types, looked up once (not per run)
    ctrl_step: Any
    coil_prm: npt.NDArray[np.float64]
    seq_mode: int
    sv: npt.NDArray[np.float64]
    hold_s: float
    plant_y0: npt.NDArray[np.float64]
    coil_state0: npt.NDArray[np.float64]
    record_forces: bool


def compiled_forms(stages: Any) -> tuple[dict[str, Any], list[str]]:
    """The compiled form of each role's stage, through its kind, and the roles whose stage the compiled loop
    cannot run: of a kind it does not run (a user's object; :attr:`~vesselbot_ros.sim.kinds.StageKind.compiled`),
    that its kind cannot compile (a built-in kind over a user's part), or on other axes than the plant's."""
    d = getattr(stages.plant, "dims", 2)
    forms: dict[str, Any] = {}
    bad = []
    for role in kinds.ROLES:
        stage = getattr(stages, role)
        if role == "tracker" and stage is None:  # an imager that delivers positions: no frame to track
            continue
        if not getattr(kinds.kind_of(role, stage), "compiled", False) or getattr(stage, "dims", d) != d:
            bad.append(role)
        else:
            try:
                forms[role] = kinds.compiled_stage(role, stage)
            except ModelInputError:
                bad.append(role)
    return forms, bad


def _read_only(a: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """A read-only view (the controller step's signature takes the packed model read-only)."""
    v = np.ascontiguousarray(a).view()
    v.flags.writeable = False
    return v


def _model_geom(geom: Any) -> Any:
    """The model's geometry as the controller steps take it: its packed parameters read-only."""
    if isinstance(geom, np.ndarray):
        return _read_only(geom)
    p, *rest = geom
    return (_read_only(p), *rest)


def prepare(stages: Any, n: int, dt: float, record_forces: bool) -> LoopInputs:
    """Pack freshly built :class:`~vesselbot_ros.sim.closed_loop.Stages` into kernel inputs (:func:`try_prepare`).

    Raises:
        ModelInputError: a stage the compiled loop does not have (:func:`compiled_forms`).
    """
    inputs, bad = try_prepare(stages, n, dt, record_forces)
    if inputs is None:
        raise ModelInputError(f"compiled loop needs the built-in stages, got user stage(s) {bad}")
    return inputs


def try_prepare(stages: Any, n: int, dt: float, record_forces: bool) -> tuple[LoopInputs | None, list[str]]:
    """The kernel inputs of freshly built stages, each compiled form made once, or None and the roles whose stage
    the compiled loop cannot run (:func:`compiled_forms`).

    Takes the parameters and the initial state the stage objects hold (so
    both paths read the same numbers) and the reference sampled at every tick
    (``sample_many``, as the per-tick runner does).

    Raises:
        ModelInputError: the scanner's imager and coil on different sequences.
    """
    forms, bad = compiled_forms(stages)
    if bad:
        return None, bad
    imager, coil = forms["imager"], forms["coil"]
    seq = coil.sv is not None
    if seq != (imager.sv is not None) or (seq and not np.array_equal(coil.sv, imager.sv)):
        raise ModelInputError("compiled loop needs the scanner's imager and coil on the same sequence")
    ts = np.asarray(np.arange(n) * dt, dtype=np.float64)  # float64 already; the dtype types it for LoopInputs
    p_ref, v_ref, a_ref = forms["reference"].at_ticks(ts)  # sampled at every tick, as the per-tick runner does
    plant, model = forms["plant"], stages.model
    obs, ctrl, model_geom = forms["observer"], forms["controller"], _model_geom(model.geom)
    return LoopInputs(
        n=n, dt=dt, dims=len(plant.state0) // 2, ts=ts, p_ref=p_ref, v_ref=v_ref, a_ref=a_ref,
        plant_geom=plant.geom, model_geom=model_geom, ig=plant.ig,
        imager_prm=imager.prm, outliers=imager.outliers, dropouts=imager.dropouts,
        obs=obs, ctrl=ctrl, obs_step=obs.step(numba.typeof(obs.geom)), ctrl_step=ctrl.step(numba.typeof(model_geom)),
        coil_prm=coil.prm,
        seq_mode=1 if seq else 0, sv=coil.sv if seq else np.zeros(7), hold_s=coil.hold_s,
        plant_y0=plant.state0, coil_state0=coil.state0,
        record_forces=record_forces,
    ), []


@numba.njit(cache=True, nogil=True, inline="always")  # in the caller's body: no call per tick
def sense(r, t, plant_geom, rng, img, obs_step, obs, y, contact, ga, scratch, err, record_forces, forces, cols):  # type: ignore[no-untyped-def]  # numba: types at compile time
    """The first half of a tick at ``t``: the plant's output, the imager's frame and the observer's update, written to
    row ``r`` of the columns ``cols`` (:data:`COLUMNS`' order); returns ``(code, finite estimate)`` (``code``
    :data:`OBSERVER_FAILED` or OK).

    ``img`` is the imager's ``(prm, outliers, dropouts, queue, seq_state, img_state, seq_mode, sv)``, ``obs`` the
    observer's ``(prm, state, istate, geom, work, model stats)`` (its step ``obs_step``); ``ga`` the gradient the
    coil applied over the last period (the plant's forces and the observer's input); ``scratch`` is ``(fk, sc, acq,
    img_out, obs_out)`` (``obs_out`` holds the estimate for :func:`command`).  The state arrays are
    :func:`loop_kernel`'s.  (Tuples: a call of more than 30 arguments is a ``*args`` call, which numba does not inline.)
    """
    d = axes_of(plant_geom)  # the axes, a constant at compile time (the loops unroll)
    imager_prm, outliers, dropouts, queue, seq_state, img_state, seq_mode, sv = img
    obs_prm, obs_state, obs_istate, obs_geom, obs_work, model_stats = obs
    fk, sc, acq, img_out, obs_out = scratch
    p_true = cols[0]  # one name per line (actuate says why)
    v_true = cols[1]
    delta_m = cols[2]
    in_contact = cols[3]
    contact_phase = cols[4]
    meas_p = cols[5]
    meas_t_acq_s = cols[6]
    meas_outlier = cols[7]
    x_hat = cols[8]
    z_hat = cols[9]
    meas_used = cols[12]
    meas_rejected = cols[13]
    # plant output at t_k (the forces under the gradient applied over the last period)
    delta, _wall = wall_and_forces(t, y, ga, contact, plant_geom, fk, sc, record_forces)
    for c in range(d):
        p_true[r, c] = y[c]
        v_true[r, c] = y[d + c]
    delta_m[r] = delta
    in_contact[r] = delta > 0.0
    contact_phase[r] = int(contact[0])
    if record_forces:
        for i in range(8):
            for c in range(d):
                forces[r, i, c] = fk[i, c]
    # imager (the plant state is finite: the integrator checked it)
    if seq_mode == 1:
        seq_imager_frame(sv, imager_prm, outliers, dropouts, rng, seq_state, queue, acq, t, y[:d], img_out)
    else:
        imager_frame(imager_prm, outliers, dropouts, img_state, queue, rng, t, y[:d], img_out)
    has_meas = img_out[0] > 0.5
    if has_meas:
        for c in range(d):
            meas_p[r, c] = img_out[2 + c]
        meas_t_acq_s[r] = img_out[1]
        meas_outlier[r] = img_out[2 + d] > 0.5
    else:
        for c in range(d):
            meas_p[r, c] = np.nan
        meas_t_acq_s[r] = np.nan
        meas_outlier[r] = False
    # observer
    code = obs_step(obs_prm, obs_state, obs_istate, obs_geom, obs_work, model_stats, t, ga, has_meas, img_out[1],
                    img_out[2:2 + d], obs_out, err)
    if code != OK:
        return OBSERVER_FAILED, False
    finite_estimate = True
    for c in range(d):
        x_hat[r, c] = obs_out[c]
        z_hat[r, c] = obs_out[d + c]
        if not (math.isfinite(obs_out[c]) and math.isfinite(obs_out[d + c])):
            finite_estimate = False
    meas_used[r] = obs_out[3 * d + 1] > 0.5
    meas_rejected[r] = obs_out[3 * d + 2] > 0.5
    return OK, finite_estimate


@numba.njit(cache=True, nogil=True, inline="always")  # in the caller's body: no call per tick
def take_command(r, finite_estimate, g_ext, ge_row, obs_out, gc, cols):  # type: ignore[no-untyped-def]  # numba: types at compile time
    """The tick's command into ``gc`` (d,) without the controller: NaN for a non-finite estimate (rejected,
    :data:`~vesselbot_ros.sim.kinds.REJECT_ESTIMATE`), else the external command ``g_ext[ge_row]`` (T/m), rejected if
    not finite (:data:`~vesselbot_ros.sim.kinds.REJECT_NONFINITE`); returns ``(status, rejection)``.  Row ``r`` of
    ``u_cmd`` is NaN (a bare gradient asks for no acceleration), the scales the observer's (and 1)."""
    d = gc.shape[0]
    u_cmd = cols[14]  # one name per line (actuate says why)
    flow_scale_hat = cols[10]
    magnetization_scale_hat = cols[11]
    n_obs = 3 * d + 3  # observer_step_out_size(d) - 1: the blood-velocity scale's index
    why = REJECT_ESTIMATE if not finite_estimate else 0
    for c in range(d):
        gc[c] = g_ext[ge_row, c] if finite_estimate else np.nan
        u_cmd[r, c] = np.nan
        if why == 0 and not math.isfinite(gc[c]):
            why = REJECT_NONFINITE
    flow_scale_hat[r] = obs_out[n_obs]
    magnetization_scale_hat[r] = 1.0
    return (2 if why != 0 else 0), why


@numba.njit(cache=True, nogil=True, inline="always")  # in the caller's body: no call per tick
def command(r, k, t, finite_estimate, g_ext, ge_row, ref, ctrl_step, ctrl, obs_out, est, ctrl_out, gc, err, cols):  # type: ignore[no-untyped-def]  # numba: types at compile time
    """The tick's command into ``gc`` (d,), from the controller's step or, when ``ge_row >= 0``, the external command
    ``g_ext[ge_row]`` (T/m: an agent's action, a replayed one); returns ``(code, status, rejection)``.

    The rules of :func:`~vesselbot_ros.sim.kinds.checked_command` for both sources: a non-finite estimate is not
    given to the controller (nor an external command taken): the command is NaN, rejected
    (:data:`~vesselbot_ros.sim.kinds.REJECT_ESTIMATE`); a non-finite command is rejected
    (:data:`~vesselbot_ros.sim.kinds.REJECT_NONFINITE`); either reaches the coil as NaN, which ramps it towards zero
    at the slew limit.  An external command is a bare gradient (``u_cmd`` NaN, status ok), as the per-tick loop
    takes a bare array from a controller.  ``code`` is :data:`REFERENCE_NONFINITE` or :data:`FLOW_SCALE_FAILED`
    when the controller cannot run (OK otherwise).  ``ref`` is ``(p_ref, v_ref, a_ref)`` (every tick), ``ctrl`` the
    controller's ``(prm, state, model geometry, work, fbuf, sc)`` (its step ``ctrl_step``).
    """
    d = gc.shape[0]
    if ge_row >= 0 or not finite_estimate:
        status, why = take_command(r, finite_estimate, g_ext, ge_row, obs_out, gc, cols)
        return OK, status, why
    p_ref, v_ref, a_ref = ref
    ctrl_prm, ctrl_state, model_geom, ctrl_work, ctrl_fbuf, ctrl_sc = ctrl
    u_cmd = cols[14]  # one name per line (actuate says why)
    flow_scale_hat = cols[10]
    magnetization_scale_hat = cols[11]
    n_obs = 3 * d + 3  # observer_step_out_size(d) - 1: the blood-velocity scale's index
    for c in range(d):
        if not (math.isfinite(p_ref[k, c]) and math.isfinite(v_ref[k, c]) and math.isfinite(a_ref[k, c])):
            return REFERENCE_NONFINITE, 0, 0
    for c in range(2 * d + 1):
        est[c] = obs_out[c]
    est[2 * d + 1] = obs_out[n_obs]
    status = ctrl_step(ctrl_prm, ctrl_state, model_geom, ctrl_work, ctrl_fbuf, ctrl_sc, t, est, p_ref[k],
                       v_ref[k], a_ref[k], ctrl_out)
    flow_scale_hat[r] = ctrl_out[2 * d]  # the scales the controller worked with (the observer's, or adapted)
    magnetization_scale_hat[r] = ctrl_out[2 * d + 1]
    if status == STEP_FLOW_SCALE_INVALID:
        err[0] = ctrl_out[2 * d]
        return FLOW_SCALE_FAILED, 0, 0
    why = 0
    for c in range(d):
        gc[c] = ctrl_out[c]
        u_cmd[r, c] = ctrl_out[d + c]
        if not math.isfinite(gc[c]):
            why = REJECT_NONFINITE
    if why != 0:
        status = 2
    elif status < 0 or status > 2:  # not a status of a command
        why = REJECT_MALFORMED
        status = 2
        for c in range(d):
            gc[c] = np.nan
    return OK, status, why


@numba.njit(cache=True, nogil=True, inline="always")  # in the caller's body: no call per tick
def actuate(r, k, t, dt, gc, status, why, coil, coil_out, ga, zd, y, contact, plant_geom, h, ig, plant_stats, work,  # type: ignore[no-untyped-def]  # numba: types at compile time
            fbuf, sc, err, cols):
    """The second half of tick ``k`` (at ``t``): the command ``gc`` (its ``status`` and rejection ``why``) through
    the coil, then the plant integrated over ``[t_k, t_k+1]`` under the gradient applied (left in ``ga``), written
    to row ``r`` of the columns; returns ``(code, h)`` (``code`` :data:`PLANT_FAILED` or OK, ``h`` the integrator's
    step to propose next).  ``coil`` is ``(prm, seq_mode, sv, hold_s, state)``."""
    d = gc.shape[0]
    coil_prm, seq_mode, sv, hold_s, coil_state = coil
    g_cmd = cols[15]  # one name per line: numba's inlining bound one name of a 7-tuple unpacked here to another array
    g_applied = cols[16]
    k_scale = cols[17]
    saturated = cols[18]
    slew_limited = cols[19]
    cmd_status = cols[20]
    cmd_rejected = cols[21]
    for c in range(d):
        g_cmd[r, c] = gc[c]
    cmd_status[r] = status
    cmd_rejected[r] = why
    # coil
    if seq_mode == 1:
        seq_coil_apply(coil_prm, sv, hold_s, coil_state, t, gc, coil_out)
    else:
        coil_apply(coil_prm, coil_state, t, gc, coil_out)
    for c in range(d):
        ga[c] = coil_out[c]
        g_applied[r, c] = coil_out[c]
        slew_limited[r, c] = coil_out[d + 2 + c] > 0.5
    k_scale[r] = coil_out[d]
    saturated[r] = coil_out[d + 1] > 0.5
    # plant step over [t_k, t_k+1] (tick times k * dt, as PlantSimulator)
    t0 = 0.0 + k * dt
    t1 = 0.0 + (k + 1) * dt
    code, h = integrate(t0, t1, y, ga, zd, contact, plant_geom, h, ig, plant_stats, work, fbuf, sc)
    if code != OK:
        err[0] = t0
        err[1] = t1
        err[2] = code
        return PLANT_FAILED, h
    return OK, h


@numba.njit(cache=True, nogil=True)
def loop_kernel(n, dt, ts, p_ref, v_ref, a_ref, plant_geom, model_geom, ig, rng,  # type: ignore[no-untyped-def]  # numba: types at compile time
                imager_prm, outliers, dropouts, queue, seq_state, obs_step, obs_prm, obs_state, obs_istate, obs_geom,
                obs_work, ctrl_step, ctrl_prm, ctrl_state, ctrl_work, coil_prm, seq_mode, sv, hold_s, y, contact,
                coil_state, plant_stats, model_stats, record_forces, forces, g_ext,
                p_true, v_true, delta_m, in_contact, contact_phase, meas_p, meas_t_acq_s, meas_outlier,
                x_hat, z_hat, flow_scale_hat, magnetization_scale_hat, meas_used, meas_rejected, u_cmd, g_cmd, g_applied, k_scale,
                saturated, slew_limited, cmd_status, cmd_rejected, err):
    """Run ticks ``0 .. n-1`` on the d = ``len(y) / 2`` axes of the vessel ``plant_geom``; returns ``(code, tick)``
    (``code`` 0 = every tick ran).

    Each tick is :func:`sense`, :func:`command` and :func:`actuate`, the functions the stepping form
    (:func:`step_copies`) calls too.  State arrays (``y``, ``contact``, ``queue``, ``seq_state``, the observer's
    and the controller's, ``coil_state``, stats) are updated in place; ``err`` (3 + 2 d + 1,) receives the
    failure's details (``[t0, t1, integrator code, state...]``, or the flow scale).  The observer is ``obs_step``
    and the controller ``ctrl_step``, compiled steps of any kind (:mod:`vesselbot_ros.control.compiled_stage`) on
    their parameters, state and scratch, over their models ``obs_geom`` and ``model_geom``; ``seq_mode`` 1 runs the
    scanner's imager and coil on the sequence ``sv``.  ``g_ext`` (n, d) replaces the controller with external
    commands, one per tick (an agent's actions replayed); (0, d): the controller commands.
    All scratch is allocated once, before the first tick.
    """
    d = axes_of(plant_geom)  # the axes, a constant at compile time (the loops unroll)
    work, fbuf, sc = new_workspace(d)
    ctrl_fbuf = np.empty((8, d))
    ctrl_sc = np.zeros((4, d))
    fk = np.empty((8, d))
    img_state = np.zeros(4)
    img_state[1] = -math.inf
    acq = np.zeros(3 + d)
    img_out = np.zeros(3 + d)
    obs_out = np.zeros(3 * d + 4)  # observer_step_out_size(d)
    est = np.zeros(2 * d + 2)
    ctrl_out = np.zeros(2 * d + 2)
    coil_out = np.zeros(2 * d + 3)  # coil_out_size(d)
    gc = np.zeros(d)  # the tick's command (NaN: rejected)
    ga = np.zeros(d)  # the gradient applied over the last period: the plant's and, next tick, the models'
    zd = np.zeros(d)
    cols = (p_true, v_true, delta_m, in_contact, contact_phase, meas_p, meas_t_acq_s, meas_outlier, x_hat, z_hat,
            flow_scale_hat, magnetization_scale_hat, meas_used, meas_rejected, u_cmd, g_cmd, g_applied, k_scale,
            saturated, slew_limited, cmd_status, cmd_rejected)  # COLUMNS' order
    img = (imager_prm, outliers, dropouts, queue, seq_state, img_state, seq_mode, sv)
    obs = (obs_prm, obs_state, obs_istate, obs_geom, obs_work, model_stats)
    scratch = (fk, sc, acq, img_out, obs_out)
    ref = (p_ref, v_ref, a_ref)
    ctrl = (ctrl_prm, ctrl_state, model_geom, ctrl_work, ctrl_fbuf, ctrl_sc)
    coil = (coil_prm, seq_mode, sv, hold_s, coil_state)
    return tick_loop(n, dt, ts, rng, g_ext, plant_geom, ig, plant_stats, y, contact, ga, gc, zd, est, ctrl_out, coil_out,
                     (work, fbuf, sc), err, record_forces, forces, obs_step, ctrl_step, cols, img, obs, scratch, ref, ctrl,
                     coil)


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on the tick's ~50 arrays
def tick_loop(n, dt, ts, rng, g_ext, plant_geom, ig, plant_stats, y, contact, ga, gc, zd, est, ctrl_out, coil_out, ws,  # type: ignore[no-untyped-def]  # numba: types at compile time
              err, record_forces, forces, obs_step, ctrl_step, cols, img, obs, scratch, ref, ctrl, coil):
    """:func:`loop_kernel`'s ticks over the state and scratch it made (the tuples of :func:`sense`, :func:`command`
    and :func:`actuate`, ``ws`` the integrator's ``(work, fbuf, sc)``), the three inlined into one loop."""
    work, fbuf, sc = ws
    obs_out = scratch[4]
    h = ig[5]
    external = g_ext.shape[0] > 0
    for k in range(n):
        t = ts[k]
        code, finite_estimate = sense(k, t, plant_geom, rng, img, obs_step, obs, y, contact, ga, scratch, err,
                                      record_forces, forces, cols)
        if code != OK:
            return code, k
        code, status, why = command(k, k, t, finite_estimate, g_ext, k if external else -1, ref, ctrl_step, ctrl,
                                    obs_out, est, ctrl_out, gc, err, cols)
        if code != OK:
            return code, k
        code, h = actuate(k, k, t, dt, gc, status, why, coil, coil_out, ga, zd, y, contact, plant_geom, h, ig,
                          plant_stats, work, fbuf, sc, err, cols)
        if code != OK:
            return code, k
    return OK, n


#: :func:`step_copies`' operation per copy: one tick under the copy's command, a fresh run to its tick 0, nothing.
OP_STEP, OP_RESET, OP_SKIP = 0, 1, 2


@numba.njit(cache=True, nogil=True)
def step_scratch(dims):  # type: ignore[no-untyped-def]  # numba: types at compile time
    """The scratch of :func:`step_copies` on ``dims`` axes (allocated once per call; shared by the copies)."""
    work, fbuf, sc = new_workspace(dims)
    return (work, fbuf, sc, np.empty((8, dims)), np.zeros(3 + dims), np.zeros(3 + dims), np.zeros(2 * dims + 3),
            np.zeros(dims), np.zeros(dims), np.empty((0, 8, dims)))


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on the tick's ~50 arrays
def step_copies(lo, hi, ops, ticks, actions, dt, ts, plant_geom, ig, variates, imager_prm, outliers, dropouts, queue,  # type: ignore[no-untyped-def]  # numba: types at compile time
                seq_state, img_state, obs_step_address, obs_prm, obs_state, obs_istate, obs_geom, obs_work, obs_state0,
                obs_istate0, obs_work0, coil_prm, seq_mode, sv, hold_s, y, contact, coil_state, plant_stats,
                model_stats, h, ga, y0, coil_state0, p_true, v_true, delta_m, in_contact, contact_phase, meas_p,
                meas_t_acq_s, meas_outlier, x_hat, z_hat, flow_scale_hat, magnetization_scale_hat, meas_used,
                meas_rejected, u_cmd, g_cmd, g_applied, k_scale, saturated, slew_limited, cmd_status, cmd_rejected,
                obs_out, err, codes, scratch):
    """The stepping form of :func:`loop_kernel`: N copies of one scenario's loop, each advanced by ``ops[i]`` in one
    call, the controller's place taken by the commands ``actions`` (N, d) (T/m): copies ``lo .. hi-1`` (the others
    are not touched, so threads may step disjoint ranges at once: the kernel releases the GIL).

    * :data:`OP_STEP`: copy ``i`` stands after the observer's update at tick ``k = ticks[i]``: its command
      ``actions[i]`` (:func:`take_command`), then :func:`actuate` (coil, plant over ``[t_k, t_k+1]``), then
      :func:`sense` at tick ``k + 1`` (plant output, imager, observer); ``ticks[i]`` becomes ``k + 1``;
    * :data:`OP_RESET`: fresh state (the prepared initial state, the stats zeroed), then :func:`sense` at tick 0;
    * :data:`OP_SKIP`: nothing.

    The same functions, in the same order, as :func:`loop_kernel`'s ticks: copy ``i`` driven by a sequence of
    commands gives the run's bits.  Every per-copy array has the copy on its first axis: the state (``y``,
    ``contact``, ``queue``, ``seq_state``, ``img_state``, the observer's, ``coil_state``, stats, ``h`` the
    integrator's next step, ``ga`` the gradient applied over the last period), ``variates`` (a
    :class:`~vesselbot_ros.scanner.imager_model.VariateBuffer` array per copy, holding at least one acquisition's
    draws), the columns (row ``i``: copy ``i``'s latest tick), ``obs_out`` (the observer's last output) and ``err``;
    ``codes[i]`` is OK or where the copy stopped (:func:`raise_for_code`).  ``ts`` must hold the tick times up to
    the last ``k + 1`` asked for.  The observer's step is given by its ``cfunc``'s address, ``obs_step_address``
    (:func:`~vesselbot_ros.control.compiled_stage.observer_step_at`: a call per step costs no typing of a function);
    ``scratch`` is :func:`step_scratch`'s.
    """
    d = axes_of(plant_geom)  # the axes, a constant at compile time (the loops unroll)
    obs_step = observer_step_at(obs_step_address, obs_geom)  # type: ignore[call-arg, var-annotated]  # the intrinsic takes the typing context itself
    work, fbuf, sc, fk, acq, img_out, coil_out, gc, zd, forces = scratch
    cols = (p_true, v_true, delta_m, in_contact, contact_phase, meas_p, meas_t_acq_s, meas_outlier, x_hat, z_hat,
            flow_scale_hat, magnetization_scale_hat, meas_used, meas_rejected, u_cmd, g_cmd, g_applied, k_scale,
            saturated, slew_limited, cmd_status, cmd_rejected)  # COLUMNS' order
    for i in range(lo, hi):
        op = ops[i]
        codes[i] = OK
        if op == OP_SKIP:
            continue
        if op == OP_RESET:
            k = 0
            for c in range(2 * d):
                y[i, c] = y0[c]
            for c in range(contact.shape[1]):
                contact[i, c] = 0.0
            for c in range(coil_state.shape[1]):
                coil_state[i, c] = coil_state0[c]
            for c in range(obs_state.shape[1]):
                obs_state[i, c] = obs_state0[c]
            for c in range(obs_istate.shape[1]):
                obs_istate[i, c] = obs_istate0[c]
            for c in range(obs_work.shape[1]):
                obs_work[i, c] = obs_work0[c]
            for c in range(4):
                plant_stats[i, c] = 0
                model_stats[i, c] = 0
            queue[i, :, :] = 0.0
            seq_state[i, :] = 0.0
            seq_state[i, 0] = -1.0  # new_seq_imager_state: no window open
            img_state[i, :] = 0.0
            img_state[i, 1] = -math.inf  # loop_kernel's fresh imager state
            for c in range(d):
                ga[i, c] = 0.0
            h[i] = ig[5]
        else:
            k = ticks[i]
            finite_estimate = True
            for c in range(d):
                if not (math.isfinite(x_hat[i, c]) and math.isfinite(z_hat[i, c])):
                    finite_estimate = False
            status, why = take_command(i, finite_estimate, actions, i, obs_out[i], gc, cols)
            code, h[i] = actuate(i, k, ts[k], dt, gc, status, why, (coil_prm, seq_mode, sv, hold_s, coil_state[i]),
                                 coil_out, ga[i], zd, y[i], contact[i], plant_geom, h[i], ig, plant_stats[i], work, fbuf,
                                 sc, err[i], cols)
            if code != OK:
                codes[i] = code
                continue
            k += 1
        ticks[i] = k
        code, _finite = sense(
            i, ts[k], plant_geom, variates[i], (imager_prm, outliers, dropouts, queue[i], seq_state[i], img_state[i],
                                                 seq_mode, sv),
            obs_step, (obs_prm, obs_state[i], obs_istate[i], obs_geom, obs_work[i], model_stats[i]), y[i], contact[i],
            ga[i], (fk, sc, acq, img_out, obs_out[i]), err[i], False, forces, cols)
        codes[i] = code


def run_kernel(
    inp: LoopInputs, rng: np.random.Generator, commands: npt.NDArray[np.float64] | None = None
) -> tuple[dict[str, npt.NDArray[Any]], npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """One run of :func:`loop_kernel` with fresh state; returns ``(columns, plant stats, model stats)``.

    ``commands`` (n, d) (T/m), if given, are the ticks' gradient commands in the controller's place (an episode's
    actions replayed: the coil takes them as the environment's step does, :mod:`vesselbot_ros.envs`).

    Raises:
        ModelInputError: as the per-tick loop would (:func:`raise_for_code`), or ``commands`` not of shape (n, d).
    """
    n, d = inp.n, inp.dims
    if commands is not None:
        commands = np.ascontiguousarray(commands, dtype=np.float64)
        if commands.shape != (n, d):
            raise ModelInputError(f"commands: shape {commands.shape}, expected ({n}, {d}) (one gradient per tick)")
    spec = columns(d)
    cols = {name: (np.zeros if dt is np.bool_ else np.empty)((n, *shape), dtype=dt) for name, dt, shape in spec}
    forces = np.empty((n, 8, d)) if inp.record_forces else np.empty((0, 8, d))
    y = inp.plant_y0.copy()
    contact = np.zeros(4)
    coil_state = inp.coil_state0.copy()
    plant_stats = np.zeros(4, dtype=np.int64)
    model_stats = np.zeros(4, dtype=np.int64)
    err = np.zeros(3 + 2 * d + 1)
    obs, ctrl = inp.obs, inp.ctrl
    code, tick = loop_kernel(  # type: ignore[call-arg]  # *columns: numba's Dispatcher stub cannot count it
        n, inp.dt, inp.ts, inp.p_ref, inp.v_ref, inp.a_ref, inp.plant_geom, inp.model_geom, inp.ig, rng,
        inp.imager_prm, inp.outliers, inp.dropouts, np.zeros((n + 1, queue_columns(d))), new_seq_imager_state(d),
        inp.obs_step, obs.prm, obs.state0.copy(), obs.istate0.copy(), obs.geom, obs.work0.copy(),
        inp.ctrl_step, ctrl.prm, ctrl.state0.copy(), np.zeros(ctrl.work_size), inp.coil_prm,
        inp.seq_mode, inp.sv, inp.hold_s, y, contact, coil_state, plant_stats, model_stats,
        inp.record_forces, forces, np.zeros((0, d)) if commands is None else commands,
        *(cols[name] for name, _dt, _shape in spec), err,
    )
    if code != OK:
        raise_for_code(code, tick, y, err, obs.message)
    if inp.record_forces:
        cols["forces"] = forces
    return cols, plant_stats, model_stats


def raise_for_code(code: int, tick: int, y: npt.NDArray[np.float64], err: npt.NDArray[np.float64],
                   observer_message: Any) -> None:
    """Raise the per-tick loop's error for a kernel that stopped at ``tick`` with ``code``: ``y`` the plant's state,
    ``err`` the failure's details, ``observer_message(err)`` the observer's words for its own failure."""
    if code == PLANT_FAILED:
        raise ModelInputError(failure_message(f"tick {tick}: plant", float(err[0]), float(err[1]), int(err[2]), y.tolist()))
    if code == OBSERVER_FAILED:
        raise ModelInputError(observer_message(err))
    if code == REFERENCE_NONFINITE:
        raise ModelInputError("controller: non-finite reference sample")
    if code == FLOW_SCALE_FAILED:
        raise ModelInputError(flow_scale_message(float(err[0])))
    raise ModelInputError(f"compiled loop stopped at tick {tick} with code {code}")
