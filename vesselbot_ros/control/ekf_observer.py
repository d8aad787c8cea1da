"""Extended Kalman filter with a blood-velocity scale factor, a chi-square gate and delay compensation.

Why.  The paper's observer (25) has fixed gains: its stationary error under
100 um noise at 1 kHz is 14-18 um sigma per axis, it is unstable when sampled
at MRI frame rates (25 frames/s: the sampled error map's spectral radius
exceeds 1), and it cannot see the 5 % blood-velocity model error that
dominates the tracking error of law (24) (docs/reproduction.md).  This filter
weighs each frame by the noise it knows, estimates the error it cannot model,
refuses aberrant frames, and handles frames that arrive late.

State (5,), frame W::

    y = (x, z, vx, vz, s)        # position (m), velocity (m/s), flow scale (-)

``s`` multiplies the model's centreline blood velocity ``V_f``: the model
believes ``V_f``, the truth is ``s V_f``.  Dynamics (eq. (23) with the model's
forces)::

    Xd = Z,   Zd = F(t, X, Z; s V_f) + B G,   sd = w_s

Prediction over one tick ``[t0, t1]`` under the held input ``B G``: the mean by
the model's integrator (the same adaptive Dormand-Prince as the plant and as
observer (25), with ``V_f`` scaled by ``s``); the covariance by the
linearisation ``Phi = I + A h + (A h)^2 / 2`` with ``A = df/dy`` by forward
differences at the start of the tick, ``P <- Phi P Phi^T + Q h`` (when
``||A h|| > 0.5``, near a wall, ``Phi`` is that formula for ``A h / 2^s``
squared ``s`` times).
``Q = diag(0, 0, q_a^2, q_a^2, q_s^2)``: white acceleration noise of density
``q_a`` (the unmodelled force) and a random walk of ``s``.

Correction with a frame ``Y`` (position, 2,) and ``R = sigma^2 I``:
innovation ``nu = Y - X_hat``, ``S = P_xx + R``, ``K = P_{:,x} S^-1``, Joseph
form ``P <- (I - K H) P (I - K H)^T + K R K^T``.  The chi-square gate rejects
the frame when ``nu^T S^-1 nu > gate_chi2`` (13.82 = 99.9 % for 2 degrees of
freedom): an aberrant frame (Section III-C, t = 0.5 s) is refused instead of
pulling the estimate by a millimetre.  After ``max_consecutive_rejections``
rejected frames in a row the filter restarts its track on the next frame, and
once the frames rejected in a row span ``max_rejection_s`` on the next frame
the gate refuses too (position from the frame at its acquisition time,
re-predicted to now like the first frame, prior covariance): it must not lock
itself out when the robot really is elsewhere.  A covariance that became non-finite or
larger than 1 m is reset to the prior (counted in ``covariance_resets``).

Delay compensation.  A frame acquired at ``t_a`` and delivered at
``t_a + latency`` corrects the state *at* ``t_a``: the filter keeps, for every
tick of the last ``history_s``, the predicted state and covariance and the
input applied over the tick; it corrects the stored state at ``t_a`` and
re-predicts to now with the inputs actually applied since.  Without it (or
with a frame older than the history) the frame corrects the current state.

Arithmetic.  Every product here is written out in scalar loops in a fixed
order (no BLAS; :mod:`vesselbot_ros.blas_free`), so a run gives the same bits
on every CPU.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.blas_free import mat2
from vesselbot_ros.control.ekf_params import CHI2_2DOF_999, EkfParams
from vesselbot_ros.control.estimate import Estimate, measurement_scalars
from vesselbot_ros.control.high_gain_observer import write_estimate
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.integrator import G_ROW, OK, U_ROW, integrate, new_workspace
from vesselbot_ros.physics.kernel import I_BRUSH_L0, I_MASS, I_R, I_V_F, forces_tc, onto_lumen, wall_delta_xz

__all__ = ["EkfParams", "ExtendedKalmanObserver", "CHI2_2DOF_999", "EkfState", "ekf_update", "ekf_params", "ekf_failure_message",
           "EKF_OUT_SIZE", "PREDICTION_FAILED"]

N = 5


@numba.njit(cache=True, nogil=True)
def _scaled(p, s, p_s):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Copy ``p`` into ``p_s`` with V_f multiplied by ``s``."""
    for i in range(p.shape[0]):
        p_s[i] = p[i]
    p_s[I_V_F] = p[I_V_F] * s


#: ``wall_projection: lumen``: how near a wall (in bead radii) an estimate pressed towards it rests on it
#: (:func:`_resting`): within a radius the surface forces and the wall's reaction set the motion across the lumen.
CONSTRAINT_ZONE_RADII = 1.0


@numba.njit(cache=True, nogil=True)
def _resting(t, y, uz, p_s, fbuf):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Whether the estimate rests on a wall: within :data:`CONSTRAINT_ZONE_RADII` bead radii of it, and the forces
    but the wall's (drag, apparent weight, image charge) and the control press it there."""
    delta, wall = wall_delta_xz(t, y[0], y[1], p_s)
    if not delta > -CONSTRAINT_ZONE_RADII * p_s[I_R]:
        return False
    return wall * ((fbuf[1, 1] + fbuf[2, 1] + fbuf[5, 1]) / p_s[I_MASS] + uz) > 0.0


@numba.njit(cache=True, nogil=True)
def _f(t, y, ux, uz, free, p, p_s, out, fbuf, tc, constrained):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Continuous dynamics f(t, y) (5,) into ``out`` (``fbuf`` (8, 2) scratch: the kernel's accel_no_motive, same doubles).

    ``tc`` memoises the force model's time-only terms (:func:`~vesselbot_ros.physics.kernel.time_terms_into`),
    which do not depend on ``V_f``, the only parameter ``s`` scales.  ``constrained`` (``wall_projection:
    lumen``): where the estimate rests on a wall (:func:`_resting`), the drag and the apparent weight only, the
    wall being a constraint (its stiff contact and surface forces would give the covariance a Jacobian of
    microsecond modes); elsewhere every force, as without the option.  Near a wall that does not hold the bead
    (the weight pulls it away from the upper one) the image-charge attraction, about 5 m/s^2 a bead radius from
    the wall, is no constraint's: left out of the covariance there, it biased a noise-free estimate by 300-500 um.
    """
    _scaled(p, y[4], p_s)
    forces_tc(t, y[0], y[1], y[2], y[3], 0.0, 0.0, free, p_s, fbuf, tc)
    out[0] = y[2]
    out[1] = y[3]
    if constrained and _resting(t, y, uz, p_s, fbuf):
        out[2] = (fbuf[1, 0] + fbuf[2, 0]) / p_s[I_MASS] + ux
        out[3] = (fbuf[1, 1] + fbuf[2, 1]) / p_s[I_MASS] + uz
    else:
        out[2] = fbuf[7, 0] / p_s[I_MASS] + ux
        out[3] = fbuf[7, 1] / p_s[I_MASS] + uz
    out[4] = 0.0


@numba.njit(cache=True, nogil=True)
def _predict_cov(t, h, y, P, ux, uz, qa2, qs2, free, p, p_s, f0, f1, yp, A, Phi, T, fbuf, tc, constrained):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``P <- Phi P Phi^T + Q h`` with ``Phi ~ exp(A h)``, ``A = df/dy`` at (t, y); returns the squarings."""
    tc[0] = np.nan  # p (the model) may differ from the last call's
    _f(t, y, ux, uz, free, p, p_s, f0, fbuf, tc, constrained)
    for j in range(N):
        d = 1e-7 * max(abs(y[j]), 1e-3) if j < 2 else (1e-7 * max(abs(y[j]), 1e-2) if j < 4 else 1e-7)
        for i in range(N):
            yp[i] = y[i]
        yp[j] = y[j] + d
        _f(t, yp, ux, uz, free, p, p_s, f1, fbuf, tc, constrained)
        for i in range(N):
            A[i, j] = (f1[i] - f0[i]) / d
    # Phi = exp(A h) by scaling and squaring: Phi_s = I + M + M^2/2 with M = A h / 2^s, ||M||_inf <= 0.5,
    # then squared s times.  In free flow ||A h|| ~ 0.3 (drag rate 300 1/s, h = 1 ms): s = 0.  Near a
    # wall the Hertz contact makes A stiff; squaring keeps that to at most ~60 matrix products.
    norm = 0.0
    for i in range(N):
        row = 0.0
        for j in range(N):
            row += abs(A[i, j])
        norm = max(norm, row)
    n_sq = 0
    scale = h
    while norm * scale > 0.5 and n_sq < 60:
        scale *= 0.5
        n_sq += 1
    for i in range(N):  # Phi = I + M + M^2 / 2, M = A scale
        for j in range(N):
            acc = 0.0
            for k in range(N):
                acc += A[i, k] * A[k, j]
            Phi[i, j] = (1.0 if i == j else 0.0) + A[i, j] * scale + 0.5 * acc * scale * scale
    for _ in range(n_sq):  # Phi <- Phi Phi (T as scratch)
        for i in range(N):
            for j in range(N):
                acc = 0.0
                for k in range(N):
                    acc += Phi[i, k] * Phi[k, j]
                T[i, j] = acc
        for i in range(N):
            for j in range(N):
                Phi[i, j] = T[i, j]
    for i in range(N):  # T = Phi P
        for j in range(N):
            acc = 0.0
            for k in range(N):
                acc += Phi[i, k] * P[k, j]
            T[i, j] = acc
    for i in range(N):  # P = T Phi^T + Q h, symmetrised
        for j in range(i, N):
            acc = 0.0
            for k in range(N):
                acc += T[i, k] * Phi[j, k]
            P[i, j] = acc
            P[j, i] = acc
    P[2, 2] += qa2 * h
    P[3, 3] += qa2 * h
    P[4, 4] += qs2 * h
    return n_sq


@numba.njit(cache=True, nogil=True)
def _correct(y, P, mx, mz, r2, gate, KK, T):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Kalman correction with a position frame; returns (accepted, nu_x, nu_z, d2)."""
    nx = mx - y[0]
    nz = mz - y[1]
    s00 = P[0, 0] + r2
    s01 = P[0, 1]
    s11 = P[1, 1] + r2
    det = s00 * s11 - s01 * s01
    i00 = s11 / det
    i01 = -s01 / det
    i11 = s00 / det
    d2 = nx * (i00 * nx + i01 * nz) + nz * (i01 * nx + i11 * nz)
    if gate > 0.0 and d2 > gate:
        return False, nx, nz, d2
    for i in range(N):  # K = P[:, :2] S^-1
        KK[i, 0] = P[i, 0] * i00 + P[i, 1] * i01
        KK[i, 1] = P[i, 0] * i01 + P[i, 1] * i11
    for i in range(N):
        y[i] += KK[i, 0] * nx + KK[i, 1] * nz
    # Joseph form: P = (I - K H) P (I - K H)^T + K R K^T, H = [I2 0]
    for i in range(N):  # T = (I - K H) P
        for j in range(N):
            T[i, j] = P[i, j] - KK[i, 0] * P[0, j] - KK[i, 1] * P[1, j]
    for i in range(N):
        for j in range(i, N):
            # (T (I - K H)^T)[i, j] = T[i, j] - T[i, 0] K[j, 0] - T[i, 1] K[j, 1]
            v = T[i, j] - T[i, 0] * KK[j, 0] - T[i, 1] * KK[j, 1] + r2 * (KK[i, 0] * KK[j, 0] + KK[i, 1] * KK[j, 1])
            P[i, j] = v
            P[j, i] = v
    return True, nx, nz, d2


# ---- compiled stage -------------------------------------------------------------------------------
# prm (27,): [B (4, row-major), q_a^2, q_s^2 (0 if s is frozen), sigma^2, gate_chi2, max_consecutive_rejections,
#   delay_compensation (0/1), position_sigma0^2, velocity_sigma0^2, flow_scale_sigma0^2 (0 if frozen),
#   rtol, atol_pos, atol_vel, min_step, max_step, wall projection lumen (0/1), max_rejection_s (inf: off),
#   the prediction's integrator (7, physics.integrator.integrator_vector: dopri5)]
# scal (5,): [t (s), t of the last accepted frame (s, -inf before), next integrator step (s), initialised (0/1),
#   acquisition time of the first frame of the current run of rejections (s; inf: none)]
# ist (6,) int64: [history count, history head, rejections in a row, rejected, covariance resets, track resets]
# y (5,), P (5, 5); history: hist_t (n,), hist_y (n, 5), hist_P (n, 5, 5), hist_u (n, 2)
# free (4,) the model's contact state; p the model's packed params, p_s (same size) scratch;
# work, fbuf: integrator workspace (new_workspace); vec (8, 5) and mat (6, 5, 5) scratch (vec[5]: time-terms memo)
# out (10,): [x (2), z (2), time since the last frame, innovation X_hat - Y (2), used, rejected, s_hat]
# err (8,): [t0, t1, integrator code, the 5 states the failing prediction started from]
EKF_PRM_SIZE = 27
EKF_OUT_SIZE = 10
#: codes of :func:`ekf_update` besides OK: the prediction failed (see ``err``)
PREDICTION_FAILED = 3


def ekf_params(params: EkfParams, b: tuple[float, float, float, float], ig: Any) -> npt.NDArray[np.float64]:
    """(27,) parameter vector of :func:`ekf_update` (squares formed as :class:`ExtendedKalmanObserver` forms them)."""
    q = params
    return np.array([*b, q.accel_noise_m_per_s2_sqrt_s**2,
                     q.flow_scale_noise_per_sqrt_s**2 if q.estimate_flow_scale else 0.0,
                     q.measurement_sigma_m**2, float(q.gate_chi2), float(q.max_consecutive_rejections),
                     1.0 if q.delay_compensation else 0.0, q.position_sigma0_m**2, q.velocity_sigma0_m_per_s**2,
                     q.flow_scale_sigma0**2 if q.estimate_flow_scale else 0.0,
                     ig.rtol, ig.atol_position_m, ig.atol_velocity_m_per_s, ig.min_step_s, ig.max_step_s,
                     1.0 if q.wall_projection == "lumen" else 0.0, q.max_rejection_s if q.max_rejection_s > 0.0 else math.inf,
                     0.0, ig.rtol, ig.atol_position_m, ig.atol_velocity_m_per_s, ig.min_step_s, ig.max_step_s, 0.0])


def ekf_history_len(params: EkfParams, tick_s: float) -> int:
    """Entries of the delay-compensation history: one per tick of ``history_s``, plus two."""
    return int(math.ceil(params.history_s / tick_s)) + 2


@numba.njit(cache=True, nogil=True)
def _ekf_reset_covariance(prm, P):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    for i in range(N):
        for j in range(N):
            P[i, j] = 0.0
    P[0, 0] = prm[10]
    P[1, 1] = prm[10]
    P[2, 2] = prm[11]
    P[3, 3] = prm[11]
    P[4, 4] = prm[12]


@numba.njit(cache=True, nogil=True)
def _ekf_predict(prm, scal, ist, t0, t1, y, P, ux, uz, free, p, p_s, work, fbuf, vec, mat, stats, err):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Mean by the model's integrator under ``V_f`` scaled by ``s``, covariance by :func:`_predict_cov`; code."""
    _predict_cov(t0, t1 - t0, y, P, ux, uz, prm[4], prm[5], free, p, p_s, vec[0], vec[1], vec[2], mat[0], mat[1],
                 mat[2], fbuf, vec[5], prm[18] > 0.5)
    _scaled(p, y[4], p_s)
    ys = vec[3, :4]  # the mean's (X, Z): the flow scale is not integrated
    ys[0] = y[0]
    ys[1] = y[1]
    ys[2] = y[2]
    ys[3] = y[3]
    g = work[G_ROW, :2]  # no gradient: the model's input is the acceleration U = B G
    g[0] = 0.0
    g[1] = 0.0
    u = work[U_ROW, :2]
    u[0] = ux
    u[1] = uz
    # the planar vessel reads no 3-D scratch: fbuf stands in for it
    code, h = integrate(t0, t1, ys, g, u, free, p_s, scal[2], prm[20:27], stats, work, fbuf, fbuf)
    scal[2] = h
    if code != OK or not (math.isfinite(ys[0]) and math.isfinite(ys[1]) and math.isfinite(ys[2])
                          and math.isfinite(ys[3])):
        err[0] = t0
        err[1] = t1
        err[2] = code
        for i in range(N):
            err[3 + i] = y[i]
        return PREDICTION_FAILED
    y[0] = ys[0]
    y[1] = ys[1]
    y[2] = ys[2]
    y[3] = ys[3]
    finite = True
    for i in range(N):
        for j in range(N):
            if not math.isfinite(P[i, j]):
                finite = False
    if not (finite and P[0, 0] < 1.0 and P[1, 1] < 1.0):  # covariance lost: start it again
        _ekf_reset_covariance(prm, P)
        ist[4] += 1
    return OK


@numba.njit(cache=True, nogil=True)
def _project(prm, t, y, p, free):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``wall_projection: lumen``: an estimate closer to a wall than the brush length put there (:func:`onto_lumen`: where
    the steric force starts, not at contact, where it throws the estimate off), with a fresh
    contact state (the one carried along belongs to the estimate before the jump); else nothing."""
    if prm[18] > 0.5:
        x0, x1, z0, z1 = onto_lumen(t, y[0], y[1], y[2], y[3], p, p[I_BRUSH_L0])
        if x0 != y[0] or x1 != y[1]:
            for i in range(free.shape[0]):
                free[i] = 0.0
        y[0], y[1], y[2], y[3] = x0, x1, z0, z1


@numba.njit(cache=True, nogil=True)
def _ekf_find(ist, hist_t, t_acq):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    n = hist_t.shape[0]
    for back in range(ist[0]):
        if abs(hist_t[(ist[1] - back + n) % n] - t_acq) <= 1e-9:
            return back
    return -1


@numba.njit(cache=True, nogil=True)
def _ekf_repredict(  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
        prm, scal, ist, back, yc, Pc, y, P, hist_t, hist_y, hist_P, hist_u, free, p, p_s, work, fbuf, vec, mat, stats, err):
    """``(yc, Pc)`` is the state ``back`` ticks ago: rewrite the history to now, set ``(y, P)``; code.

    With ``wall_projection: lumen`` the contact state starts afresh: the one carried along is now's, not
    the past state's, and on a wall the difference throws the re-prediction off.
    """
    n = hist_t.shape[0]
    if prm[18] > 0.5:
        for i in range(free.shape[0]):
            free[i] = 0.0
    for step in range(back, 0, -1):
        j = (ist[1] - step + n) % n
        k = (j + 1) % n
        hist_y[j, :] = yc
        hist_P[j, :, :] = Pc
        code = _ekf_predict(prm, scal, ist, hist_t[j], hist_t[k], yc, Pc, hist_u[j, 0], hist_u[j, 1], free, p, p_s,
                            work, fbuf, vec, mat, stats, err)
        if code != OK:
            return code
    hist_y[ist[1], :] = yc
    hist_P[ist[1], :, :] = Pc
    y[:] = yc
    P[:, :] = Pc
    return OK


@numba.njit(cache=True, nogil=True)
def _start_track(prm, scal, ist, restart, t_acq, m0, m1, y, P, hist_t, hist_y, hist_P, hist_u, free, p, p_s, work, fbuf,  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
                 vec, mat, stats, err):
    """Start the track on a frame: its position at its acquisition time, re-predicted to now; code.

    The first frame keeps the prior's velocity and scale covariance; a ``restart`` (the filter lost the robot)
    starts from the whole prior covariance and is counted.
    """
    n = hist_t.shape[0]
    yc = vec[4]
    Pc = mat[3]
    done = False
    if prm[9] > 0.5 and t_acq < scal[0] - 1e-9:
        back = _ekf_find(ist, hist_t, t_acq)
        if back >= 0:
            i = (ist[1] - back + n) % n
            yc[:] = hist_y[i]
            Pc[:, :] = hist_P[i]
            yc[0] = m0
            yc[1] = m1
            _project(prm, hist_t[i], yc, p, free)
            if restart:
                _ekf_reset_covariance(prm, Pc)
            else:
                for j in range(N):
                    Pc[0, j] = 0.0
                    Pc[j, 0] = 0.0
                    Pc[1, j] = 0.0
                    Pc[j, 1] = 0.0
                Pc[0, 0] = prm[10]
                Pc[1, 1] = prm[10]
            code = _ekf_repredict(prm, scal, ist, back, yc, Pc, y, P, hist_t, hist_y, hist_P, hist_u, free, p,
                                  p_s, work, fbuf, vec, mat, stats, err)
            if code != OK:
                return code
            done = True
    if not done:
        y[0] = m0
        y[1] = m1
        _project(prm, scal[0], y, p, free)
        if restart:
            _ekf_reset_covariance(prm, P)
        else:
            P[0, 0] = prm[10]
            P[1, 1] = prm[10]
        hist_y[ist[1], :] = y
        hist_P[ist[1], :, :] = P
    if restart:
        ist[5] += 1
        ist[2] = 0
    scal[4] = math.inf
    scal[1] = t_acq
    scal[3] = 1.0
    return OK


@numba.njit(cache=True, nogil=True)
def ekf_update(prm, scal, ist, y, P, hist_t, hist_y, hist_P, hist_u, free, p, p_s, work, fbuf, vec, mat,  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
               stats, t, gx, gz, has_meas, t_acq, m0, m1, out, err):
    """:meth:`ExtendedKalmanObserver.update` over explicit state: predict to ``t``, fuse a delivered frame.

    The caller checks that ``t`` is finite and not before ``scal[0]`` and that
    the gradient is finite.  Writes ``out`` (:data:`EKF_OUT_SIZE`,); allocates nothing.

    Returns:
        ``OK``, or :data:`PREDICTION_FAILED` (``err`` = ``[t0, t1, integrator code, state (5)]``,
        :func:`ekf_failure_message`).
    """
    n = hist_t.shape[0]
    ux = prm[0] * gx + prm[1] * gz
    uz = prm[2] * gx + prm[3] * gz
    if ist[0] > 0:  # the input over the last tick is the one applied since
        hist_u[ist[1], 0] = ux
        hist_u[ist[1], 1] = uz
    if t > scal[0]:
        code = _ekf_predict(prm, scal, ist, scal[0], t, y, P, ux, uz, free, p, p_s, work, fbuf, vec, mat, stats, err)
        if code != OK:
            return code
    scal[0] = t
    # push the prior at t (before any correction) and a zero input that the next tick overwrites
    head = (ist[1] + 1) % n
    ist[1] = head
    hist_t[head] = t
    hist_y[head, :] = y
    hist_P[head, :, :] = P
    hist_u[head, 0] = 0.0
    hist_u[head, 1] = 0.0
    ist[0] = min(ist[0] + 1, n)
    used = 0.0
    rejected = 0.0
    i0 = 0.0
    i1 = 0.0
    yc = vec[4]
    Pc = mat[3]
    KK = mat[4][:, :2]
    if has_meas:
        if not (math.isfinite(m0) and math.isfinite(m1) and math.isfinite(t_acq)) or t_acq > scal[0] + 1e-9:
            rejected = 1.0
        elif scal[3] < 0.5 or ist[2] >= prm[8]:
            code = _start_track(prm, scal, ist, scal[3] > 0.5, t_acq, m0, m1, y, P, hist_t, hist_y, hist_P, hist_u, free,
                                p, p_s, work, fbuf, vec, mat, stats, err)
            if code != OK:
                return code
            used = 1.0
        else:
            found = False
            ok = False
            nx = 0.0
            nz = 0.0
            if prm[9] > 0.5 and t_acq < scal[0] - 1e-9:
                back = _ekf_find(ist, hist_t, t_acq)
                if back >= 0:
                    found = True
                    i = (ist[1] - back + n) % n
                    yc[:] = hist_y[i]
                    Pc[:, :] = hist_P[i]
                    ok, nx, nz, _d2 = _correct(yc, Pc, m0, m1, prm[6], prm[7], KK, mat[2])
                    if ok:
                        _project(prm, hist_t[i], yc, p, free)
                        code = _ekf_repredict(prm, scal, ist, back, yc, Pc, y, P, hist_t, hist_y, hist_P, hist_u, free,
                                              p, p_s, work, fbuf, vec, mat, stats, err)
                        if code != OK:
                            return code
            if not found:
                ok, nx, nz, _d2 = _correct(y, P, m0, m1, prm[6], prm[7], KK, mat[2])
                if ok:
                    _project(prm, scal[0], y, p, free)
            if ok:
                i0 = -nx  # X_hat - Y, as Estimate documents
                i1 = -nz
                scal[1] = t_acq
                used = 1.0
                ist[2] = 0
                scal[4] = math.inf
            elif ist[2] >= 1 and t_acq - scal[4] >= prm[19]:
                # frames rejected in a row for max_rejection_s, and this one too: the filter lost the robot
                code = _start_track(prm, scal, ist, True, t_acq, m0, m1, y, P, hist_t, hist_y, hist_P, hist_u, free,
                                    p, p_s, work, fbuf, vec, mat, stats, err)
                if code != OK:
                    return code
                used = 1.0
            else:
                rejected = 1.0
                ist[2] += 1
                if ist[2] == 1:
                    scal[4] = t_acq
        if rejected > 0.5:
            ist[3] += 1
    write_estimate(out, y, scal[0] - scal[1], i0, i1, used, rejected)
    out[9] = y[4]
    return OK


def ekf_failure_message(err: npt.NDArray[np.float64]) -> str:
    """The error of a failed prediction (:data:`PREDICTION_FAILED`): the interval, the code and the state."""
    return f"observer: prediction failed on [{float(err[0])!r}, {float(err[1])!r}] (code {int(err[2])}), state {err[3:8].tolist()}"


class EkfState:
    """The explicit state of one filter (:func:`ekf_update`): estimate, covariance, history, scratch.

    Args:
        params: Filter settings.
        model: The dynamics model (packed parameters ``p``, input matrix, integrator).
        x_hat0: (2,) prior position, m.
        z_hat0: (2,) prior velocity, m/s.
        t0_s: Time of the prior (s).
        tick_s: Control period (s).
    """

    def __init__(self, params: EkfParams, model: Any, x_hat0: npt.NDArray[np.float64], z_hat0: npt.NDArray[np.float64],
                 t0_s: float, tick_s: float) -> None:
        self.prm = ekf_params(params, mat2(model.input_matrix), model.integrator)
        self.p = np.asarray(model.p, dtype=np.float64)
        self.p_s = np.empty_like(self.p)
        self.scal = np.array([float(t0_s), -math.inf, float(model.integrator.max_step_s), 0.0, math.inf])
        self.ist = np.zeros(6, dtype=np.int64)
        self.ist[1] = -1
        self.y = np.array([x_hat0[0], x_hat0[1], z_hat0[0], z_hat0[1], params.flow_scale0])
        self.P = np.diag([params.position_sigma0_m**2 * 1e4, params.position_sigma0_m**2 * 1e4,
                          params.velocity_sigma0_m_per_s**2, params.velocity_sigma0_m_per_s**2,
                          params.flow_scale_sigma0**2])
        if not params.estimate_flow_scale:
            self.P[4, 4] = 0.0
        n_hist = ekf_history_len(params, tick_s)
        self.hist_t = np.full(n_hist, -math.inf)
        self.hist_y = np.zeros((n_hist, N))
        self.hist_P = np.zeros((n_hist, N, N))
        self.hist_u = np.zeros((n_hist, 2))
        self.free = np.zeros(4)
        self.work, self.fbuf, _sc = new_workspace(2)
        self.vec = np.zeros((8, N))
        self.mat = np.zeros((6, N, N))
        self.out = np.zeros(EKF_OUT_SIZE)
        self.err = np.zeros(8)

    def copy(self) -> EkfState:
        """An independent copy (every array copied): a fresh run's state from a prepared one."""
        new = object.__new__(EkfState)
        for k, v in vars(self).items():
            setattr(new, k, v.copy() if isinstance(v, np.ndarray) and k != "p" else v)
        return new


class ExtendedKalmanObserver:
    """EKF over ``(X, Z, s)``; the same port as :class:`HighGainObserver` (:meth:`update` once per tick).

    Ports: inputs ``measurement`` (or None) and ``applied_gradient_prev``
    (T/m, applied since the previous tick); output :class:`Estimate`, whose
    ``flow_scale`` is ``s_hat`` (the flow-compensating controller reads it).
    Each update is one call of the compiled :func:`ekf_update` (which the
    compiled closed loop calls too).

    Args:
        params: Filter settings.
        model: Dynamics model with the controller's (possibly wrong) parameters
            (:class:`~vesselbot_ros.control.model.DynamicsModel`).
        x_hat0: (2,) prior position, m.
        z_hat0: (2,) prior velocity, m/s.
        t0_s: Time of the prior (s).
        tick_s: Control period (s): the history holds one entry per tick.
    """

    def __init__(self, params: EkfParams, model: Any, x_hat0: npt.ArrayLike, z_hat0: npt.ArrayLike = (0.0, 0.0),
                 t0_s: float = 0.0, tick_s: float = 1e-3) -> None:
        x0 = np.asarray(x_hat0, dtype=np.float64)
        z0 = np.asarray(z_hat0, dtype=np.float64)
        if x0.shape != (2,) or z0.shape != (2,) or not (np.all(np.isfinite(x0)) and np.all(np.isfinite(z0))):
            raise ModelInputError(f"observer prior must be finite (2,) + (2,), got {x_hat0!r}, {z_hat0!r}")
        if not (math.isfinite(tick_s) and tick_s > 0.0):
            raise ModelInputError(f"tick_s must be finite and > 0, got {tick_s!r}")
        self.params = params
        self.model = model
        self.stats = model.stats  # integrator statistics shared with the model, as observer (25)
        self.tick_s = float(tick_s)
        self.ekf = EkfState(params, model, x0, z0, float(t0_s), float(tick_s))

    @property
    def state(self) -> npt.NDArray[np.float64]:
        """(5,) ``(x, z, vx, vz, s)`` copy."""
        return self.ekf.y.copy()

    @property
    def covariance(self) -> npt.NDArray[np.float64]:
        """(5, 5) covariance copy."""
        return self.ekf.P.copy()

    @property
    def rejected(self) -> int:
        """Frames rejected so far (non-finite, from the future, or refused by the gate)."""
        return int(self.ekf.ist[3])

    @property
    def covariance_resets(self) -> int:
        """Times the covariance became non-finite or larger than 1 m and was reset to the prior."""
        return int(self.ekf.ist[4])

    @property
    def track_resets(self) -> int:
        """Times the track restarted on a frame after ``max_consecutive_rejections`` rejections in a row."""
        return int(self.ekf.ist[5])

    def update(self, t_s: float, measurement: Any | None, applied_gradient_prev: npt.ArrayLike) -> Estimate:
        """Predict to ``t_s`` under the applied gradient, then fuse a delivered frame.

        Args:
            t_s: Tick time (s), non-decreasing.
            measurement: A :class:`~vesselbot_ros.control.imager_model.Measurement` or None.
            applied_gradient_prev: (2,) gradient applied since the previous tick (T/m).

        Returns:
            The :class:`Estimate` at ``t_s`` (``flow_scale`` = ``s_hat``).
        """
        g = np.asarray(applied_gradient_prev, dtype=np.float64)
        if g.shape != (2,) or not (math.isfinite(g[0]) and math.isfinite(g[1])):
            raise ModelInputError(f"observer: applied gradient must be a finite (2,) array, got {applied_gradient_prev!r}")
        e = self.ekf
        if not math.isfinite(t_s) or t_s < e.scal[0] - 1e-12:
            raise ModelInputError(f"observer: time must be finite and non-decreasing, got {t_s!r} after {float(e.scal[0])!r}")
        has, t_acq, m0, m1 = measurement_scalars(measurement)
        code = ekf_update(e.prm, e.scal, e.ist, e.y, e.P, e.hist_t, e.hist_y, e.hist_P, e.hist_u, e.free, e.p, e.p_s,
                          e.work, e.fbuf, e.vec, e.mat, self.stats, float(t_s), float(g[0]), float(g[1]), has, t_acq,
                          m0, m1, e.out, e.err)
        if code != OK:
            raise ModelInputError(ekf_failure_message(e.err))
        o = e.out
        return Estimate(float(e.scal[0]), o[0:2].copy(), o[2:4].copy(), float(o[4]), o[5:7].copy(), bool(o[7] > 0.5),
                        bool(o[8] > 0.5), float(o[9]))
