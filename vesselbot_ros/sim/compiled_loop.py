"""The closed loop of :mod:`vesselbot_ros.sim.closed_loop` as one compiled function.

:func:`loop_kernel` runs every tick of one run in numba, calling the compiled
stages in the runner's order::

    plant output (wall_delta_xz, forces_into)
    -> imager_frame | seq_imager_frame (scanner)
    -> observer_update (25) | ekf_update (extended Kalman)
    -> the controller's compiled step, of any kind (control/compiled_stage.py: law (24), its adaptive form, ...)
    -> coil_apply | seq_coil_apply (scanner) -> plant step (the one integrator, physics.integrator.integrate)

over explicit state arrays that :func:`prepare` builds from the same
:class:`~vesselbot_ros.sim.closed_loop.Stages` as the per-tick loop, and it
writes every time-series column into arrays allocated once per run.  Each
stage does the same IEEE operations in the same order as its Python class
(the classes of the coil and the law call the very same functions), so the
two paths are bit-identical; ``test/unit/sim/test_compiled_loop.py`` checks
every column, metric and run statistic.

Random draws: the imager's ``numpy.random.Generator`` is passed into the
kernel and drawn from in the documented order (two standard normals, two
uniforms per acquired frame), so one seed gives one stream in both paths.

Bad input inside the loop (a non-finite state, a failing integrator, a flow
scale the law cannot use) stops the kernel at that tick with a code;
:func:`raise_for_code` raises the per-tick loop's
:class:`~vesselbot_ros.errors.ModelInputError`, word for word.

The kernel releases the GIL (``nogil``), so :func:`~vesselbot_ros.sim.closed_loop.run_many`
runs several in threads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.actuator_limits import COIL_OUT_SIZE, CoilLimiter, coil_apply, coil_params
from vesselbot_ros.control.backstepping import BacksteppingController, flow_scale_message
from vesselbot_ros.control.compiled_stage import CONTROLLER_OUT_SIZE, STEP_FLOW_SCALE_INVALID, CompiledController
from vesselbot_ros.control.ekf_observer import EKF_OUT_SIZE, EkfState, ExtendedKalmanObserver, ekf_failure_message, ekf_update
from vesselbot_ros.control.high_gain_observer import (
    HISTORY_LEN,
    HighGainObserver,
    integrator_vector,
    observer_params,
    observer_update,
)
from vesselbot_ros.control.imager_model import ImagerModel, imager_frame
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.integrator import OK, failure_message, integrate, new_workspace
from vesselbot_ros.physics.kernel import forces_into, wall_delta_xz
from vesselbot_ros.scanner.stages import SequencedCoil, SequencedImager, seq_coil_apply, seq_imager_frame
from vesselbot_ros.sim import kinds
from vesselbot_ros.sim.kinds import REJECT_ESTIMATE, REJECT_MALFORMED, REJECT_NONFINITE

__all__ = ["LoopInputs", "prepare", "foreign_stages", "loop_kernel", "run_kernel", "raise_for_code", "COLUMNS", "OBS_HIGH_GAIN", "OBS_EKF"]

# codes of loop_kernel (besides OK): where the loop stopped
PLANT_FAILED = 1  # plant integration failed (non-finite state)
OBSERVER_FAILED = 2  # the observer's model integration failed
ESTIMATE_NONFINITE = 3  # (no longer a stop: a non-finite estimate is a rejected command, kinds.checked_command)
REFERENCE_NONFINITE = 4  # the controller got a non-finite reference sample
EKF_FAILED = 5  # the extended Kalman filter's prediction failed
FLOW_SCALE_FAILED = 6  # the compensating law got a flow scale it cannot use

#: (name, dtype, trailing shape) of the columns the kernel fills, in its argument order.
COLUMNS: tuple[tuple[str, Any, tuple[int, ...]], ...] = (
    ("p_true", np.float64, (2,)),
    ("v_true", np.float64, (2,)),
    ("delta_m", np.float64, ()),
    ("in_contact", np.bool_, ()),
    ("contact_phase", np.int8, ()),
    ("meas_p", np.float64, (2,)),
    ("meas_t_acq_s", np.float64, ()),
    ("meas_outlier", np.bool_, ()),
    ("x_hat", np.float64, (2,)),
    ("z_hat", np.float64, (2,)),
    ("flow_scale_hat", np.float64, ()),
    ("magnetization_scale_hat", np.float64, ()),
    ("meas_used", np.bool_, ()),
    ("meas_rejected", np.bool_, ()),
    ("u_cmd", np.float64, (2,)),
    ("g_cmd", np.float64, (2,)),
    ("g_applied", np.float64, (2,)),
    ("k_scale", np.float64, ()),
    ("saturated", np.bool_, ()),
    ("slew_limited", np.bool_, (2,)),
    ("cmd_status", np.int8, ()),
    ("cmd_rejected", np.int8, ()),
)


@dataclass
class LoopInputs:
    """Everything :func:`loop_kernel` reads for one scenario (shared by the runs of a batch; read-only).

    Built by :func:`prepare` from freshly built stages; the per-run state is
    created by :func:`run_kernel` (copies of the initial state held here).
    """

    n: int
    dt: float
    ts: npt.NDArray[np.float64]
    p_ref: npt.NDArray[np.float64]
    v_ref: npt.NDArray[np.float64]
    a_ref: npt.NDArray[np.float64]
    plant_p: npt.NDArray[np.float64]
    model_p: npt.NDArray[np.float64]
    ig: npt.NDArray[np.float64]
    obs_ig: npt.NDArray[np.float64]
    imager_prm: npt.NDArray[np.float64]
    outliers: npt.NDArray[np.float64]
    dropouts: npt.NDArray[np.float64]
    obs_kind: int
    obs_prm: npt.NDArray[np.float64]
    ekf: EkfState | None
    ctrl: CompiledController
    coil_prm: npt.NDArray[np.float64]
    seq_mode: int
    sv: npt.NDArray[np.float64]
    hold_s: float
    plant_y0: npt.NDArray[np.float64]
    obs_y0: npt.NDArray[np.float64]
    coil_state0: npt.NDArray[np.float64]
    record_forces: bool


#: observer kinds of :func:`loop_kernel`
OBS_HIGH_GAIN, OBS_EKF = 0, 1


def foreign_stages(stages: Any) -> list[str]:
    """The stages :func:`prepare` cannot read, by name: of a kind the compiled loop does not run (a user's
    object; :attr:`~vesselbot_ros.sim.kinds.StageKind.compiled`), or a built-in one over a user's part."""
    bad = [role for role in kinds.ROLES
           if not getattr(kinds.kind_of(role, getattr(stages, role)), "compiled", False)
           or getattr(getattr(stages, role), "dims", 2) != 2]  # the kernel's stages are planar
    im, ob, co = stages.imager, stages.observer, stages.coil
    if type(im) is SequencedImager and type(im.inner) is not ImagerModel:
        bad.append("imager")
    if type(ob) is HighGainObserver and not getattr(ob, "_compiled", False):
        bad.append("observer")
    if type(stages.controller) is BacksteppingController and stages.controller.model_params is None:
        bad.append("controller")
    if type(co) is SequencedCoil and type(co.inner) is not CoilLimiter:
        bad.append("coil")
    return [role for role in kinds.ROLES if role in bad]


def _read_only(a: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """A read-only view (the controller step's signature takes the packed model read-only)."""
    v = np.ascontiguousarray(a).view()
    v.flags.writeable = False
    return v


def prepare(stages: Any, n: int, dt: float, record_forces: bool) -> LoopInputs:
    """Pack freshly built :class:`~vesselbot_ros.sim.closed_loop.Stages` into kernel inputs.

    Takes the parameters and the initial state the stage objects hold (so
    both paths read the same numbers) and the reference sampled at every tick
    (``sample_many``, as the per-tick runner does).

    Raises:
        ModelInputError: a stage the compiled loop does not have (:func:`foreign_stages`).
    """
    bad = foreign_stages(stages)
    if bad:
        raise ModelInputError(f"compiled loop needs the built-in stages, got user stage(s) {bad}")
    ts = np.asarray(np.arange(n) * dt, dtype=np.float64)  # float64 already; the dtype types it for LoopInputs
    p_ref, v_ref, a_ref = stages.reference.sample_many(ts)
    plant, observer, controller, coil, model = stages.plant, stages.observer, stages.controller, stages.coil, stages.model
    imager = stages.imager.inner if isinstance(stages.imager, SequencedImager) else stages.imager
    limiter = coil.inner if isinstance(coil, SequencedCoil) else coil
    seq = isinstance(coil, SequencedCoil) or isinstance(stages.imager, SequencedImager)
    if seq and not (isinstance(coil, SequencedCoil) and isinstance(stages.imager, SequencedImager)
                    and np.array_equal(coil.sv, stages.imager.sv)):
        raise ModelInputError("compiled loop needs the scanner's imager and coil on the same sequence")
    if isinstance(observer, ExtendedKalmanObserver):
        obs_kind, obs_prm, ekf, obs_y0 = OBS_EKF, np.zeros(11), observer.ekf.copy(), np.zeros(4)
    else:
        obs_kind, obs_prm, ekf, obs_y0 = OBS_HIGH_GAIN, observer_params(observer.params, model.input_matrix), None, observer.state
    return LoopInputs(
        n=n, dt=dt, ts=ts,
        p_ref=np.ascontiguousarray(p_ref), v_ref=np.ascontiguousarray(v_ref), a_ref=np.ascontiguousarray(a_ref),
        plant_p=plant.p, model_p=_read_only(model.p), ig=integrator_vector(plant.integrator),
        obs_ig=integrator_vector(model.integrator),
        imager_prm=imager.frame_arrays[0], outliers=imager.frame_arrays[1], dropouts=imager.frame_arrays[2],
        obs_kind=obs_kind, obs_prm=obs_prm, ekf=ekf,
        ctrl=kinds.compiled_controller(controller),
        coil_prm=coil_params(limiter.limits),
        seq_mode=1 if seq else 0, sv=coil.sv if seq else np.zeros(7), hold_s=coil.hold_s if seq else 0.0,
        plant_y0=plant.state, obs_y0=obs_y0, coil_state0=limiter.state,
        record_forces=record_forces,
    )


@numba.njit(cache=True, nogil=True)
def loop_kernel(n, dt, ts, p_ref, v_ref, a_ref, plant_p, model_p, ig, obs_ig, rng,  # type: ignore[no-untyped-def]  # numba: types at compile time
                imager_prm, outliers, dropouts, obs_kind, obs_prm, ctrl_step, ctrl_prm, ctrl_state, ctrl_work, coil_prm, seq_mode, sv,
                hold_s, y, contact, obs_y, obs_contact, obs_scal, coil_state,
                e_prm, e_scal, e_ist, e_y, e_P, e_hist_t, e_hist_y, e_hist_P, e_hist_u, e_free, e_p, e_p_s, e_work, e_fbuf,
                e_vec, e_mat,
                plant_stats, model_stats, record_forces, forces,
                p_true, v_true, delta_m, in_contact, contact_phase, meas_p, meas_t_acq_s, meas_outlier,
                x_hat, z_hat, flow_scale_hat, magnetization_scale_hat, meas_used, meas_rejected, u_cmd, g_cmd, g_applied, k_scale,
                saturated, slew_limited, cmd_status, cmd_rejected, err):
    """Run ticks ``0 .. n-1``; returns ``(code, tick)`` (``code`` 0 = every tick ran).

    State arrays (``y``, ``contact``, ``obs_*``, the filter's ``e_*``,
    ``coil_state``, stats) are updated in place; ``err`` (8,) receives the
    failure's details (``[t0, t1, integrator code, state...]``, or the flow
    scale).  ``obs_kind`` selects observer (25) (:data:`OBS_HIGH_GAIN`, the
    ``obs_*`` arrays) or the extended Kalman filter (:data:`OBS_EKF`, the
    ``e_*`` arrays); ``seq_mode`` 1 runs the scanner's imager and coil on the
    sequence ``sv``.  The controller is ``ctrl_step``, a compiled step of any
    kind (:mod:`vesselbot_ros.control.compiled_stage`) on ``ctrl_prm``, its state
    ``ctrl_state`` and scratch ``ctrl_work``.
    All scratch is allocated once, before the first tick.
    """
    work, fbuf, sc = new_workspace(2)
    obs_work, obs_fbuf, obs_sc = new_workspace(2)
    ctrl_fbuf = np.empty((8, 2))
    queue = np.empty((n + 1, 5))
    img_state = np.zeros(4)
    img_state[1] = -math.inf
    seq_state = np.zeros(8)
    seq_state[0] = -1.0
    acq = np.zeros(5)
    img_out = np.zeros(5)
    hist = np.empty((HISTORY_LEN, 3))
    hist_n = np.zeros(2, dtype=np.int64)
    obs_out = np.zeros(EKF_OUT_SIZE)
    obs_out[9] = 1.0  # observer (25) does not estimate the flow scale
    ctrl_out = np.zeros(CONTROLLER_OUT_SIZE)
    coil_out = np.zeros(COIL_OUT_SIZE)
    gc = np.zeros(2)  # the tick's command (NaN: rejected)
    ga = np.zeros(2)  # the gradient applied over the last period: the plant's and, next tick, the models'
    z2 = np.zeros(2)
    h = ig[5]
    for k in range(n):
        t = ts[k]
        # plant output at t_k
        delta, _wall = wall_delta_xz(t, y[0], y[1], plant_p)
        p_true[k, 0] = y[0]
        p_true[k, 1] = y[1]
        v_true[k, 0] = y[2]
        v_true[k, 1] = y[3]
        delta_m[k] = delta
        in_contact[k] = delta > 0.0
        contact_phase[k] = int(contact[0])
        if record_forces:
            forces_into(t, y[0], y[1], y[2], y[3], ga[0], ga[1], contact, plant_p, forces[k])
        # imager (the plant state is finite: the integrator checked it)
        if seq_mode == 1:
            seq_imager_frame(sv, imager_prm, outliers, dropouts, rng, seq_state, queue, acq, t, y[:2], img_out)
        else:
            imager_frame(imager_prm, outliers, dropouts, img_state, queue, rng, t, y[:2], img_out)
        has_meas = img_out[0] > 0.5
        if has_meas:
            meas_p[k, 0] = img_out[2]
            meas_p[k, 1] = img_out[3]
            meas_t_acq_s[k] = img_out[1]
            meas_outlier[k] = img_out[4] > 0.5
        else:
            meas_p[k, 0] = np.nan
            meas_p[k, 1] = np.nan
            meas_t_acq_s[k] = np.nan
        # observer
        if obs_kind == OBS_EKF:
            code = ekf_update(e_prm, e_scal, e_ist, e_y, e_P, e_hist_t, e_hist_y, e_hist_P, e_hist_u, e_free, e_p,
                              e_p_s, e_work, e_fbuf, e_vec, e_mat, model_stats, t, ga[0], ga[1], has_meas,
                              img_out[1], img_out[2], img_out[3], obs_out, err)
            if code != OK:
                return EKF_FAILED, k
        else:
            code = observer_update(obs_prm, obs_scal, obs_y, obs_contact, hist, hist_n, obs_ig, model_p, model_stats,
                                   obs_work, obs_fbuf, obs_sc, t, ga, has_meas, img_out[1], img_out[2:4], obs_out)
            if code != OK:
                err[0] = obs_scal[0]
                err[1] = t
                err[2] = code
                return OBSERVER_FAILED, k
        x_hat[k, 0] = obs_out[0]
        x_hat[k, 1] = obs_out[1]
        z_hat[k, 0] = obs_out[2]
        z_hat[k, 1] = obs_out[3]
        meas_used[k] = obs_out[7] > 0.5
        meas_rejected[k] = obs_out[8] > 0.5
        # controller (kinds.checked_command: a non-finite estimate is not given to it, a non-finite command is
        # rejected; either reaches the coil as NaN, which ramps it towards zero at the slew limit)
        if not (math.isfinite(obs_out[0]) and math.isfinite(obs_out[1]) and math.isfinite(obs_out[2])
                and math.isfinite(obs_out[3])):
            status = 2
            why = REJECT_ESTIMATE
            gx_cmd = np.nan
            gz_cmd = np.nan
            u_cmd[k, 0] = np.nan
            u_cmd[k, 1] = np.nan
            flow_scale_hat[k] = obs_out[9]
            magnetization_scale_hat[k] = 1.0
        else:
            if not (math.isfinite(p_ref[k, 0]) and math.isfinite(p_ref[k, 1]) and math.isfinite(v_ref[k, 0])
                    and math.isfinite(v_ref[k, 1]) and math.isfinite(a_ref[k, 0]) and math.isfinite(a_ref[k, 1])):
                return REFERENCE_NONFINITE, k
            status = ctrl_step(ctrl_prm, ctrl_state, model_p, ctrl_work, ctrl_fbuf, t, obs_out[0], obs_out[1],
                               obs_out[2], obs_out[3], obs_out[4], obs_out[9], p_ref[k, 0], p_ref[k, 1], v_ref[k, 0],
                               v_ref[k, 1], a_ref[k, 0], a_ref[k, 1], ctrl_out)
            flow_scale_hat[k] = ctrl_out[4]  # the scales the controller worked with (the observer's, or adapted)
            magnetization_scale_hat[k] = ctrl_out[5]
            if status == STEP_FLOW_SCALE_INVALID:
                err[0] = ctrl_out[4]
                return FLOW_SCALE_FAILED, k
            gx_cmd = ctrl_out[0]
            gz_cmd = ctrl_out[1]
            u_cmd[k, 0] = ctrl_out[2]
            u_cmd[k, 1] = ctrl_out[3]
            why = 0
            if not (math.isfinite(gx_cmd) and math.isfinite(gz_cmd)):
                why = REJECT_NONFINITE
                status = 2
            elif status < 0 or status > 2:  # not a status of a command
                why = REJECT_MALFORMED
                status = 2
                gx_cmd = np.nan
                gz_cmd = np.nan
        g_cmd[k, 0] = gx_cmd
        g_cmd[k, 1] = gz_cmd
        cmd_status[k] = status
        cmd_rejected[k] = why
        # coil
        gc[0] = gx_cmd
        gc[1] = gz_cmd
        if seq_mode == 1:
            seq_coil_apply(coil_prm, sv, hold_s, coil_state, t, gc, coil_out)
        else:
            coil_apply(coil_prm, coil_state, t, gc, coil_out)
        ga[0] = coil_out[0]
        ga[1] = coil_out[1]
        g_applied[k, 0] = ga[0]
        g_applied[k, 1] = ga[1]
        k_scale[k] = coil_out[2]
        saturated[k] = coil_out[3] > 0.5
        slew_limited[k, 0] = coil_out[4] > 0.5
        slew_limited[k, 1] = coil_out[5] > 0.5
        # plant step over [t_k, t_k+1] (tick times k * dt, as PlantSimulator)
        t0 = 0.0 + k * dt
        t1 = 0.0 + (k + 1) * dt
        code, h = integrate(t0, t1, y, ga, z2, contact, plant_p, h, ig, plant_stats, work, fbuf, sc)
        if code != OK:
            err[0] = t0
            err[1] = t1
            err[2] = code
            return PLANT_FAILED, k
    return OK, n


_NO_EKF: tuple[npt.NDArray[Any], ...] = (
    np.zeros(27), np.zeros(4), np.zeros(6, dtype=np.int64), np.zeros(5), np.zeros((5, 5)), np.zeros(1), np.zeros((1, 5)),
    np.zeros((1, 5, 5)), np.zeros((1, 2)), np.zeros(4), np.zeros(1), np.zeros(1), np.zeros((12, 4)), np.zeros((8, 2)),
    np.zeros((8, 5)), np.zeros((6, 5, 5)),
)


def run_kernel(
    inp: LoopInputs, rng: np.random.Generator
) -> tuple[dict[str, npt.NDArray[Any]], npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """One run of :func:`loop_kernel` with fresh state; returns ``(columns, plant stats, model stats)``.

    Raises:
        ModelInputError: as the per-tick loop would (:func:`raise_for_code`).
    """
    n = inp.n
    cols = {name: (np.zeros if dt is np.bool_ else np.empty)((n, *shape), dtype=dt) for name, dt, shape in COLUMNS}
    forces = np.empty((n, 8, 2)) if inp.record_forces else np.empty((0, 8, 2))
    y = inp.plant_y0.copy()
    contact = np.zeros(4)
    obs_y = inp.obs_y0.copy()
    obs_contact = np.zeros(4)
    obs_scal = np.array([0.0, -math.inf, 0.0, inp.obs_ig[5]])
    coil_state = inp.coil_state0.copy()
    plant_stats = np.zeros(4, dtype=np.int64)
    model_stats = np.zeros(4, dtype=np.int64)
    err = np.zeros(8)
    if inp.ekf is not None:
        e = inp.ekf.copy()
        ekf_arrays: tuple[npt.NDArray[Any], ...] = (e.prm, e.scal, e.ist, e.y, e.P, e.hist_t, e.hist_y, e.hist_P, e.hist_u, e.free,
                                                    e.p, e.p_s, e.work, e.fbuf, e.vec, e.mat)
    else:
        ekf_arrays = _NO_EKF
    code, tick = loop_kernel(  # type: ignore[call-arg]  # *ekf_arrays is 16 long: numba's Dispatcher stub cannot count it
        n, inp.dt, inp.ts, inp.p_ref, inp.v_ref, inp.a_ref, inp.plant_p, inp.model_p, inp.ig, inp.obs_ig, rng,
        inp.imager_prm, inp.outliers, inp.dropouts, inp.obs_kind, inp.obs_prm, inp.ctrl.step, inp.ctrl.prm,
        inp.ctrl.state0.copy(), np.empty(inp.ctrl.work_size), inp.coil_prm,
        inp.seq_mode, inp.sv, inp.hold_s,
        y, contact, obs_y, obs_contact, obs_scal, coil_state, *ekf_arrays, plant_stats, model_stats,
        inp.record_forces, forces, *(cols[name] for name, _dt, _shape in COLUMNS), err,
    )
    if code != OK:
        raise_for_code(code, tick, y, ekf_arrays[3][:4].copy() if inp.ekf is not None else obs_y, err)
    if inp.record_forces:
        cols["forces"] = forces
    return cols, plant_stats, model_stats


def raise_for_code(code: int, tick: int, y: npt.NDArray[np.float64], obs_y: npt.NDArray[np.float64],
                   err: npt.NDArray[np.float64], axes: int = 2) -> None:
    """Raise the per-tick loop's error for a kernel (planar, or on ``axes`` = 3) that stopped at ``tick`` with ``code``.

    ``y`` is the plant's state, ``obs_y`` the observer's ``(X, Z)`` when the kernel stopped.
    """
    if code == PLANT_FAILED:
        raise ModelInputError(failure_message(f"tick {tick}: plant", float(err[0]), float(err[1]), int(err[2]), y.tolist()))
    if code == OBSERVER_FAILED:
        raise ModelInputError(failure_message("observer model", float(err[0]), float(err[1]), int(err[2]), obs_y.tolist()))
    if code == EKF_FAILED:
        raise ModelInputError(ekf_failure_message(err))
    if code == ESTIMATE_NONFINITE:
        raise ModelInputError(f"controller: non-finite estimate x_hat={obs_y[:axes].copy()!r}, "
                              f"z_hat={obs_y[axes:2 * axes].copy()!r}")
    if code == REFERENCE_NONFINITE:
        raise ModelInputError("controller: non-finite reference sample")
    if code == FLOW_SCALE_FAILED:
        raise ModelInputError(flow_scale_message(float(err[0])))
    raise ModelInputError(f"compiled loop stopped at tick {tick} with code {code}")
