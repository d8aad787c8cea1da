"""The closed loop in a 3-D vessel tree as one compiled function.

:func:`loop3d_kernel` runs every tick of one run in numba, calling the compiled steps of the 3-D stages in the
per-tick runner's order (:mod:`vesselbot_ros.sim.closed_loop`)::

    plant output (forces3d_at) -> imager_frame | seq_imager_frame (scanner) -> observer_update (25)
    -> law3d_command (24) -> coil_apply | seq_coil_apply (scanner) -> plant step (integrate)

The imager, the observer, the coil and the integrator are the planar loop's, on three axes.  The stages' Python
classes (:class:`~vesselbot_ros.sim.plant.PlantSimulator`, :class:`~vesselbot_ros.control.imager_model.ImagerModel`,
:class:`~vesselbot_ros.control.high_gain_observer.HighGainObserver`,
:class:`~vesselbot_ros.control.loop3d_stages.Backstepping3D`, :class:`~vesselbot_ros.control.actuator_limits.CoilLimiter`)
call the very same compiled functions on the same state, so the two paths are bit-identical
(``test/unit/sim/test_compiled_loop.py`` checks every column, metric and statistic of the shipped 3-D scenarios).
The imager draws from the run's ``numpy.random.Generator`` in the documented order (six variates per acquired
frame).  A failure stops the kernel with a code and :func:`~vesselbot_ros.sim.compiled_loop.raise_for_code`
raises the per-tick loop's error word for word.  The kernel releases the GIL.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.actuator_limits import CoilLimiter, coil_apply, coil_out_size, coil_params
from vesselbot_ros.control.backstepping import FLOW_SCALE_INVALID
from vesselbot_ros.control.high_gain_observer import HISTORY_LEN, HighGainObserver, observer_update
from vesselbot_ros.control.imager_model import ImagerModel, imager_frame
from vesselbot_ros.control.loop3d_stages import Backstepping3D, law3d_command
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.integrator import OK, integrate, integrator_vector, new_workspace
from vesselbot_ros.physics.kernel import I_R
from vesselbot_ros.physics.plant3d import forces3d_at
from vesselbot_ros.scanner.stages import SequencedCoil, SequencedImager, seq_coil_apply, seq_imager_frame
from vesselbot_ros.sim.compiled_loop import (  # the planar loop's columns, stop codes and errors
    COLUMNS,
    FLOW_SCALE_FAILED,
    OBSERVER_FAILED,
    PLANT_FAILED,
    REFERENCE_NONFINITE,
    raise_for_code,
)
from vesselbot_ros.sim.kinds import REJECT_ESTIMATE, REJECT_NONFINITE, ROLES
from vesselbot_ros.sim.plant import PlantSimulator

__all__ = ["LoopInputs3D", "foreign_stages3d", "prepare3d", "loop3d_kernel", "run_kernel3d", "COLUMNS3D"]

#: (name, dtype, trailing shape) of the columns the kernel fills, in its argument order: the planar kernel's, on
#: three axes.
COLUMNS3D: tuple[tuple[str, Any, tuple[int, ...]], ...] = tuple((name, dt, (3,) if shape == (2,) else shape)
                                                                for name, dt, shape in COLUMNS)

_BUILT_IN: dict[str, tuple[type, ...]] = {"plant": (PlantSimulator,), "imager": (ImagerModel, SequencedImager),
                                          "observer": (HighGainObserver,), "controller": (Backstepping3D,),
                                          "coil": (CoilLimiter, SequencedCoil)}


def foreign_stages3d(stages: Any) -> list[str]:
    """The roles whose stage :func:`prepare3d` cannot read: not exactly a built-in 3-D class, or over a user's model."""
    bad = [role for role, cls in _BUILT_IN.items() if type(getattr(stages, role)) not in cls]
    im, co = stages.imager, stages.coil
    if "imager" not in bad and type(im) is SequencedImager and type(im.inner) is not ImagerModel:
        bad.append("imager")
    if "coil" not in bad and type(co) is SequencedCoil and type(co.inner) is not CoilLimiter:
        bad.append("coil")
    for role in ("observer", "controller"):
        if role not in bad and not getattr(getattr(stages, role), "_compiled", False):
            bad.append(role)
    for role in ROLES:  # the kernel's stages are on three axes (a stage that gives no axis count: its class decides)
        if role not in bad and getattr(getattr(stages, role), "dims", 3) != 3:
            bad.append(role)
    if not hasattr(stages.reference, "sample_many"):
        bad.append("reference")
    return bad


@dataclass
class LoopInputs3D:
    """What :func:`loop3d_kernel` reads for one scenario (shared by its runs; read-only)."""

    n: int
    dt: float
    ts: npt.NDArray[np.float64]
    p_ref: npt.NDArray[np.float64]
    v_ref: npt.NDArray[np.float64]
    a_ref: npt.NDArray[np.float64]
    plant_p: npt.NDArray[np.float64]
    model_p: npt.NDArray[np.float64]
    W: tuple[npt.NDArray[Any], ...]
    F: npt.NDArray[np.float32]
    fh: npt.NDArray[np.float64]
    ig: npt.NDArray[np.float64]
    obs_ig: npt.NDArray[np.float64]
    imager_prm: npt.NDArray[np.float64]
    outliers: npt.NDArray[np.float64]
    dropouts: npt.NDArray[np.float64]
    obs_prm: npt.NDArray[np.float64]
    ctrl_prm: npt.NDArray[np.float64]
    coil_prm: npt.NDArray[np.float64]
    seq_mode: int
    sv: npt.NDArray[np.float64]
    hold_s: float
    plant_y0: npt.NDArray[np.float64]
    obs_y0: npt.NDArray[np.float64]
    coil_state0: npt.NDArray[np.float64]
    record_forces: bool


def prepare3d(stages: Any, n: int, dt: float, record_forces: bool) -> LoopInputs3D:
    """Pack freshly built 3-D stages into kernel inputs (the parameters and initial state they hold).

    Raises:
        ModelInputError: a stage the compiled 3-D loop does not have (:func:`foreign_stages3d`).
    """
    bad = foreign_stages3d(stages)
    if bad:
        raise ModelInputError(f"compiled loop needs the built-in stages, got user stage(s) {bad}")
    ts = np.asarray(np.arange(n) * dt, dtype=np.float64)
    p_ref, v_ref, a_ref = stages.reference.sample_many(ts)
    plant, imager, observer, controller, coil = stages.plant, stages.imager, stages.observer, stages.controller, stages.coil
    seq = isinstance(coil, SequencedCoil) or isinstance(imager, SequencedImager)
    if seq and not (isinstance(coil, SequencedCoil) and isinstance(imager, SequencedImager)
                    and np.array_equal(coil.sv, imager.sv)):
        raise ModelInputError("compiled loop needs the scanner's imager and coil on the same sequence")
    k = plant.packed
    return LoopInputs3D(
        n=n, dt=dt, ts=ts, p_ref=np.ascontiguousarray(p_ref), v_ref=np.ascontiguousarray(v_ref),
        a_ref=np.ascontiguousarray(a_ref), plant_p=plant.p, model_p=observer.model.p, W=k.W, F=k.F, fh=k.fh,
        ig=integrator_vector(plant.integrator), obs_ig=integrator_vector(observer.model.integrator),
        imager_prm=imager.frame_arrays[0], outliers=imager.frame_arrays[1], dropouts=imager.frame_arrays[2],
        obs_prm=observer.params_vector, ctrl_prm=controller.params_vector,
        coil_prm=coil_params(coil.limits), seq_mode=1 if seq else 0, sv=coil.sv if seq else np.zeros(7),
        hold_s=coil.hold_s if seq else 0.0, plant_y0=plant.state, obs_y0=observer.state, coil_state0=coil.state,
        record_forces=record_forces)


_COIL_OUT_SIZE = coil_out_size(3)


@numba.njit(cache=True, nogil=True)
def loop3d_kernel(n, dt, ts, p_ref, v_ref, a_ref, plant_p, model_p, W, F, fh, ig, obs_ig, rng,  # type: ignore[no-untyped-def]  # numba: types at compile time
                  imager_prm, outliers, dropouts, queue, obs_prm, ctrl_prm, coil_prm, seq_mode, sv, hold_s, y, contact,
                  obs_y, obs_contact,
                  obs_scal, coil_state, plant_stats, model_stats, record_forces, forces,
                  p_true, v_true, delta_m, in_contact, contact_phase, meas_p, meas_t_acq_s, meas_outlier, x_hat, z_hat,
                  flow_scale_hat, magnetization_scale_hat, meas_used, meas_rejected, u_cmd, g_cmd, g_applied, k_scale,
                  saturated, slew_limited, cmd_status, cmd_rejected, err):
    """Run ticks ``0 .. n-1``; returns ``(code, tick)`` (0 = every tick ran); state arrays updated in place,
    ``err`` (3,) the failure's ``[t0, t1, integrator code]`` (or the flow scale).  Scratch is allocated once."""
    work, fbuf, sc = new_workspace(3)
    obs_work, obs_fbuf, obs_sc = new_workspace(3)
    ctrl_fbuf = np.empty((8, 3))
    ctrl_sc = np.zeros((4, 3))
    ys = np.zeros(6)
    z3 = np.zeros(3)
    p_s = np.empty_like(model_p)
    free = np.zeros(4)
    g = np.zeros(3)
    gc = np.zeros(3)  # the tick's command (NaN: rejected)
    img_state = np.zeros(4)
    img_state[1] = -math.inf
    img_out = np.zeros(6)
    seq_st = np.zeros(9)
    seq_st[0] = -1.0
    acq = np.zeros(6)
    hist = np.empty((HISTORY_LEN, 4))
    hist_n = np.zeros(2, dtype=np.int64)
    obs_out = np.zeros(12)
    ctrl_last = np.zeros(3)
    ctrl_out = np.zeros(6)
    coil_out = np.zeros(_COIL_OUT_SIZE)
    fk = np.empty((8, 3))
    h = ig[5]
    for k in range(n):
        t = ts[k]
        # plant output at t_k (forces under the gradient applied over the last period)
        s_t = forces3d_at(t, y, g, contact, plant_p, W, F, fh, fk, sc)
        delta = plant_p[I_R] - s_t
        for c in range(3):
            p_true[k, c] = y[c]
            v_true[k, c] = y[3 + c]
        delta_m[k] = delta
        in_contact[k] = delta > 0.0
        contact_phase[k] = int(contact[0])
        if record_forces:
            for i in range(8):
                for c in range(3):
                    forces[k, i, c] = fk[i, c]
        # imager
        if seq_mode == 1:
            seq_imager_frame(sv, imager_prm, outliers, dropouts, rng, seq_st, queue, acq, t, y[:3], img_out)
        else:
            imager_frame(imager_prm, outliers, dropouts, img_state, queue, rng, t, y[:3], img_out)
        has_meas = img_out[0] > 0.5
        if has_meas:
            for c in range(3):
                meas_p[k, c] = img_out[2 + c]
            meas_t_acq_s[k] = img_out[1]
            meas_outlier[k] = img_out[5] > 0.5
        else:
            for c in range(3):
                meas_p[k, c] = np.nan
            meas_t_acq_s[k] = np.nan
        # observer (25)
        code = observer_update(obs_prm, obs_scal, obs_y, obs_contact, hist, hist_n, obs_ig, (model_p, W, F, fh),
                               model_stats, obs_work, obs_fbuf, obs_sc, t, g, has_meas, img_out[1], img_out[2:5], obs_out)
        if code != OK:
            err[0] = obs_scal[0]
            err[1] = t
            err[2] = code
            return OBSERVER_FAILED, k
        for c in range(3):
            x_hat[k, c] = obs_out[c]
            z_hat[k, c] = obs_out[3 + c]
        flow_scale_hat[k] = 1.0
        magnetization_scale_hat[k] = 1.0
        meas_used[k] = obs_out[10] > 0.5
        meas_rejected[k] = obs_out[11] > 0.5
        # law (24) (kinds.checked_command: a non-finite estimate or command is rejected; the coil ramps to zero)
        finite_estimate = True
        for c in range(6):
            if not math.isfinite(obs_out[c]):
                finite_estimate = False
        if not finite_estimate:
            status = 2
            why = REJECT_ESTIMATE
            for c in range(3):
                gc[c] = np.nan
                u_cmd[k, c] = np.nan
        else:
            for c in range(3):
                if not (math.isfinite(p_ref[k, c]) and math.isfinite(v_ref[k, c]) and math.isfinite(a_ref[k, c])):
                    return REFERENCE_NONFINITE, k
            status = law3d_command(ctrl_prm, ctrl_last, model_p, p_s, W, F, fh, free, ctrl_fbuf, ctrl_sc, ys, z3, t,
                                   obs_out[0], obs_out[1], obs_out[2], obs_out[3], obs_out[4], obs_out[5], obs_out[6],
                                   1.0, p_ref[k, 0], p_ref[k, 1], p_ref[k, 2], v_ref[k, 0], v_ref[k, 1], v_ref[k, 2],
                                   a_ref[k, 0], a_ref[k, 1], a_ref[k, 2], ctrl_out)
            if status == FLOW_SCALE_INVALID:
                err[0] = 1.0
                return FLOW_SCALE_FAILED, k
            why = 0
            for c in range(3):
                gc[c] = ctrl_out[c]
                u_cmd[k, c] = ctrl_out[3 + c]
                if not math.isfinite(gc[c]):
                    why = REJECT_NONFINITE
                    status = 2
        for c in range(3):
            g_cmd[k, c] = gc[c]
        cmd_status[k] = status
        cmd_rejected[k] = why
        # coil
        if seq_mode == 1:
            seq_coil_apply(coil_prm, sv, hold_s, coil_state, t, gc, coil_out)
        else:
            coil_apply(coil_prm, coil_state, t, gc, coil_out)
        for c in range(3):
            g[c] = coil_out[c]
            g_applied[k, c] = coil_out[c]
            slew_limited[k, c] = coil_out[5 + c] > 0.5
        k_scale[k] = coil_out[3]
        saturated[k] = coil_out[4] > 0.5
        # plant step over [t_k, t_k+1]
        t0 = 0.0 + k * dt
        t1 = 0.0 + (k + 1) * dt
        code, h = integrate(t0, t1, y, g, z3, contact, (plant_p, W, F, fh), h, ig, plant_stats, work, fbuf, sc)
        if code != OK:
            err[0] = t0
            err[1] = t1
            err[2] = code
            return PLANT_FAILED, k
    return OK, n


def run_kernel3d(inp: LoopInputs3D, rng: np.random.Generator
                 ) -> tuple[dict[str, npt.NDArray[Any]], npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """One run of :func:`loop3d_kernel` with fresh state; returns ``(columns, plant stats, model stats)``.

    Raises:
        ModelInputError: as the per-tick loop would.
    """
    n = inp.n
    cols = {name: (np.zeros if dt is np.bool_ else np.empty)((n, *shape), dtype=dt) for name, dt, shape in COLUMNS3D}
    forces = np.empty((n, 8, 3)) if inp.record_forces else np.empty((0, 8, 3))
    y = inp.plant_y0.copy()
    contact = np.zeros(4)
    obs_y = inp.obs_y0.copy()
    obs_contact = np.zeros(4)
    obs_scal = np.array([0.0, -math.inf, 0.0, inp.obs_ig[5]])
    coil_state = inp.coil_state0.copy()
    plant_stats = np.zeros(4, dtype=np.int64)
    model_stats = np.zeros(4, dtype=np.int64)
    err = np.zeros(3)
    code, tick = loop3d_kernel(  # type: ignore[call-arg]  # *columns is 21 long: numba's Dispatcher stub cannot count it
        n, inp.dt, inp.ts, inp.p_ref, inp.v_ref, inp.a_ref, inp.plant_p, inp.model_p, inp.W, inp.F, inp.fh, inp.ig,
        inp.obs_ig, rng, inp.imager_prm, inp.outliers, inp.dropouts, np.zeros((n + 1, 6)), inp.obs_prm,
        inp.ctrl_prm, inp.coil_prm, inp.seq_mode, inp.sv, inp.hold_s, y, contact, obs_y, obs_contact, obs_scal, coil_state,
        plant_stats, model_stats,
        inp.record_forces, forces, *(cols[name] for name, _dt, _shape in COLUMNS3D), err)
    if code != OK:
        raise_for_code(code, tick, y, obs_y, err, axes=3)
    if inp.record_forces:
        cols["forces"] = forces
    return cols, plant_stats, model_stats
