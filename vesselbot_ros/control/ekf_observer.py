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
itself out when the robot really is elsewhere.  With ``flung_restart_sigmas`` the track restarts on a frame too
when its update left the estimate that many measurement sigmas further from that frame than the prior was (a
Kalman correction brings the position nearer the frame it fuses; across a wall's crest the linearisation, the
re-prediction through the contact or the projection out of the wall along the wrong face can fling it by
millimetres).  Track restarts are counted in ``track_resets``.  A covariance that became non-finite or
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

from vesselbot_ros.control.compiled_stage import CompiledObserver, flat_view, lazy_step, observer_step_type
from vesselbot_ros.control.ekf_params import CHI2_2DOF_999, EkfParams
from vesselbot_ros.control.estimate import Estimate, measurement_arrays
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.integrator import (
    G_ROW,
    OK,
    U_ROW,
    axes_of,
    forces_memo,
    integrate,
    jacobian_position_step,
    mass_of,
    new_workspace,
    onto_lumen_at,
    params_of,
    wall_normal_into,
    wall_press,
    with_params,
)
from vesselbot_ros.physics.kernel import I_BRUSH_L0, flow_scaled_into

__all__ = ["EkfParams", "ExtendedKalmanObserver", "CHI2_2DOF_999", "EkfState", "ekf_update", "ekf_params", "ekf_failure_message",
           "EKF_OUT_SIZE", "PREDICTION_FAILED", "ekf_out_size", "ekf_prm_size", "gate_on_axes", "ekf_step", "s_inverse"]

#: ``wall_projection: lumen``: how near a wall (in bead radii) an estimate pressed towards it rests on it
#: (:func:`~vesselbot_ros.physics.integrator.wall_press`): within a radius the surface forces and the wall's
#: reaction set the motion across the lumen.
CONSTRAINT_ZONE_RADII = 1.0


@numba.njit(cache=True, nogil=True)
def _f(t, y, u, free, geom, p_s, out, fbuf, sc, tc, g0, constrained):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Continuous dynamics f(t, y) (2 d + 1,) into ``out`` (``fbuf`` (8, d), ``sc`` (4, d) scratch: the model's F, same
    doubles); ``u`` (d,) the input acceleration, ``g0`` (d,) zeros.

    ``tc`` memoises the planar force model's time-only terms (:func:`~vesselbot_ros.physics.kernel.time_terms_into`),
    which do not depend on ``V_f``, the only parameter ``s`` scales.  ``constrained`` (``wall_projection:
    lumen``): where the estimate rests on a wall (:func:`~vesselbot_ros.physics.integrator.wall_press`), the drag
    and the apparent weight only, the wall being a constraint (its stiff contact and surface forces would give the
    covariance a Jacobian of microsecond modes); elsewhere every force, as without the option.  Near a wall that
    does not hold the bead (the weight pulls it away from the upper one) the image-charge attraction, about
    5 m/s^2 a bead radius from the wall, is no constraint's: left out of the covariance there, it biased a
    noise-free estimate by 300-500 um.
    """
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    flow_scaled_into(params_of(geom), y[2 * d], p_s)
    gs = with_params(geom, p_s)
    forces_memo(t, y, g0, free, gs, fbuf, sc, tc)
    m = mass_of(gs)
    for c in range(d):
        out[c] = y[d + c]
    if constrained and wall_press(t, y, u, gs, fbuf, CONSTRAINT_ZONE_RADII):
        for c in range(d):
            out[d + c] = (fbuf[1, c] + fbuf[2, c]) / m + u[c]
    else:
        for c in range(d):
            out[d + c] = fbuf[7, c] / m + u[c]
    out[2 * d] = 0.0


@numba.njit(cache=True, nogil=True)
def _predict_cov(t, h, y, P, u, qa2, qs2, free, geom, p_s, f0, f1, yp, A, Phi, T, fbuf, sc, tc, g0, constrained):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``P <- Phi P Phi^T + Q h`` with ``Phi ~ exp(A h)``, ``A = df/dy`` at (t, y); returns the squarings."""
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    N = 2 * d + 1
    tc[0] = np.nan  # p (the model) may differ from the last call's
    _f(t, y, u, free, geom, p_s, f0, fbuf, sc, tc, g0, constrained)
    floor = jacobian_position_step(geom)  # a tree's wall field jumps over nanometres: a step above its facets
    for j in range(N):
        dj = max(1e-7 * max(abs(y[j]), 1e-3), floor) if j < d else (1e-7 * max(abs(y[j]), 1e-2) if j < 2 * d else 1e-7)
        for i in range(N):
            yp[i] = y[i]
        yp[j] = y[j] + dj
        _f(t, yp, u, free, geom, p_s, f1, fbuf, sc, tc, g0, constrained)
        for i in range(N):
            A[i, j] = (f1[i] - f0[i]) / dj
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
    for c in range(d):
        P[d + c, d + c] += qa2 * h
    P[2 * d, 2 * d] += qs2 * h
    return n_sq


@numba.njit(cache=True, nogil=True)
def s_inverse(P, r2, d, Si):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``Si = (P[:d, :d] + r2 I)^-1`` (symmetric) by the adjugate, in a fixed order."""
    if d == 2:  # axis count: the plane's 2x2 adjugate (its bits), else the 3x3 one below
        s00 = P[0, 0] + r2
        s01 = P[0, 1]
        s11 = P[1, 1] + r2
        det = s00 * s11 - s01 * s01
        Si[0, 0] = s11 / det
        Si[0, 1] = -s01 / det
        Si[1, 0] = Si[0, 1]
        Si[1, 1] = s00 / det
        return
    a = P[0, 0] + r2
    b = P[0, 1]
    c = P[0, 2]
    e = P[1, 1] + r2
    f = P[1, 2]
    i = P[2, 2] + r2
    c00 = e * i - f * f
    c01 = c * f - b * i
    c02 = b * f - c * e
    det = a * c00 + b * c01 + c * c02
    Si[0, 0] = c00 / det
    Si[0, 1] = c01 / det
    Si[0, 2] = c02 / det
    Si[1, 1] = (a * i - c * c) / det
    Si[1, 2] = (b * c - a * f) / det
    Si[2, 2] = (a * e - b * b) / det
    Si[1, 0] = Si[0, 1]
    Si[2, 0] = Si[0, 2]
    Si[2, 1] = Si[1, 2]


@numba.njit(cache=True, nogil=True)
def _correct(y, P, m, r2, gate, KK, T, nu, Si, geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Kalman correction with a position frame ``m`` (d,); the innovation ``Y - X_hat`` in ``nu``; returns
    (accepted, d2)."""
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    N = 2 * d + 1
    for c in range(d):
        nu[c] = m[c] - y[c]
    s_inverse(P, r2, d, Si)
    d2 = 0.0
    for a in range(d):
        acc = Si[a, 0] * nu[0]
        for c in range(1, d):
            acc = acc + Si[a, c] * nu[c]
        d2 = d2 + nu[a] * acc
    if gate > 0.0 and d2 > gate:
        return False, d2
    for i in range(N):  # K = P[:, :d] S^-1
        for c in range(d):
            acc = P[i, 0] * Si[0, c]
            for k in range(1, d):
                acc = acc + P[i, k] * Si[k, c]
            KK[i, c] = acc
    for i in range(N):
        acc = KK[i, 0] * nu[0]
        for c in range(1, d):
            acc = acc + KK[i, c] * nu[c]
        y[i] += acc
    # Joseph form: P = (I - K H) P (I - K H)^T + K R K^T, H = [I_d 0]
    for i in range(N):  # T = (I - K H) P
        for j in range(N):
            acc = P[i, j]
            for c in range(d):
                acc = acc - KK[i, c] * P[c, j]
            T[i, j] = acc
    for i in range(N):
        for j in range(i, N):
            # (T (I - K H)^T)[i, j] = T[i, j] - sum_c T[i, c] K[j, c]
            acc = T[i, j]
            for c in range(d):
                acc = acc - T[i, c] * KK[j, c]
            kk = KK[i, 0] * KK[j, 0]
            for c in range(1, d):
                kk = kk + KK[i, c] * KK[j, c]
            v = acc + r2 * kk
            P[i, j] = v
            P[j, i] = v
    return True, d2


# ---- compiled stage -------------------------------------------------------------------------------
# On d axes (2: x, z; 3: x, y, z), the state N = 2 d + 1 long:
# prm (24 + d^2,): [q_a^2, q_s^2 (0 if s is frozen), sigma^2, gate_chi2 (on d degrees of freedom),
#   max_consecutive_rejections, delay_compensation (0/1), position_sigma0^2, velocity_sigma0^2,
#   flow_scale_sigma0^2 (0 if frozen), rtol, atol_pos, atol_vel, min_step, max_step, wall projection lumen (0/1),
#   max_rejection_s (inf: off), the prediction's integrator (7, physics.integrator.integrator_vector: dopri5),
#   flung_restart_sigmas times sigma (inf: off), wall_constraint_sigma^2 (0: off), B (d x d, row-major)]
# scal (5,): [t (s), t of the last accepted frame (s, -inf before), next integrator step (s), initialised (0/1),
#   acquisition time of the first frame of the current run of rejections (s; inf: none)]
# ist (6,) int64: [history count, history head, rejections in a row, rejected, covariance resets, track resets]
# y (N,), P (N, N); history: hist_t (n,), hist_y (n, N), hist_P (n, N, N), hist_u (n, d)
# free (4,) the model's contact state; geom the model's vessel (physics.integrator), p_s (its parameters' size)
# scratch; work, fbuf, sc: integrator workspace (new_workspace); vec (8, N) and mat (6, N, N) scratch
# (vec[5]: time-terms memo, vec[6]: zeros, vec[7]: the input acceleration and the innovation)
# out (3 d + 4,): [X (d), Z (d), time since the last frame, innovation X_hat - Y (d), used, rejected, s_hat]
# err (3 + N,): [t0, t1, integrator code, the states the failing prediction started from]
#: Indices in the parameter vector (module comment above).
_QA2, _QS2, _R2, _GATE, _MAX_REJ, _DELAY, _POS0, _VEL0, _S0 = 0, 1, 2, 3, 4, 5, 6, 7, 8
_LUMEN, _MAX_REJ_S, _IG, _FLUNG, _WALL_S2, _B = 14, 15, 16, 23, 24, 25
#: codes of :func:`ekf_update` besides OK: the prediction failed (see ``err``)
PREDICTION_FAILED = 3


def ekf_prm_size(dims: int) -> int:
    """Length of :func:`ekf_params`'s vector on ``dims`` axes."""
    return _B + int(dims) ** 2


def ekf_out_size(dims: int) -> int:
    """Length of :func:`ekf_update`'s ``out`` on ``dims`` axes: observer (25)'s and ``s_hat``."""
    return 3 * int(dims) + 4


#: The planar filter's ``out`` length.
EKF_OUT_SIZE = ekf_out_size(2)


def gate_on_axes(gate_chi2: float, dims: int) -> float:
    """``gate_chi2`` (a quantile of the chi-square law of 2 degrees of freedom, as configured) as the quantile of
    the same probability on ``dims`` degrees of freedom: the innovation has one per axis."""
    if dims == 2 or not gate_chi2 > 0.0:  # axis count: the configured quantile is on the plane's 2 degrees
        return float(gate_chi2)
    from scipy.stats import chi2  # deferred: scipy.stats takes a second to import; only a 3-D filter needs it

    return float(chi2.ppf(-math.expm1(-0.5 * float(gate_chi2)), dims))


def ekf_params(params: EkfParams, b: npt.ArrayLike, ig: Any) -> npt.NDArray[np.float64]:
    """Parameter vector of :func:`ekf_update` (squares formed as :class:`ExtendedKalmanObserver` forms them); ``b`` the
    model's input matrix (d, d)."""
    q = params
    bm = np.asarray(b, dtype=np.float64)
    return np.array([q.accel_noise_m_per_s2_sqrt_s**2,
                     q.flow_scale_noise_per_sqrt_s**2 if q.estimate_flow_scale else 0.0,
                     q.measurement_sigma_m**2, gate_on_axes(q.gate_chi2, bm.shape[0]), float(q.max_consecutive_rejections),
                     1.0 if q.delay_compensation else 0.0, q.position_sigma0_m**2, q.velocity_sigma0_m_per_s**2,
                     q.flow_scale_sigma0**2 if q.estimate_flow_scale else 0.0,
                     ig.rtol, ig.atol_position_m, ig.atol_velocity_m_per_s, ig.min_step_s, ig.max_step_s,
                     1.0 if q.wall_projection == "lumen" else 0.0, q.max_rejection_s if q.max_rejection_s > 0.0 else math.inf,
                     0.0, ig.rtol, ig.atol_position_m, ig.atol_velocity_m_per_s, ig.min_step_s, ig.max_step_s, 0.0,
                     q.flung_restart_sigmas * q.measurement_sigma_m if q.flung_restart_sigmas > 0.0 else math.inf,
                     q.wall_constraint_sigma_m**2 if q.wall_projection == "lumen" else 0.0, *bm.ravel()])


def ekf_history_len(params: EkfParams, tick_s: float) -> int:
    """Entries of the delay-compensation history: one per tick of ``history_s``, plus two."""
    return int(math.ceil(params.history_s / tick_s)) + 2


@numba.njit(cache=True, nogil=True)
def _finite_head(v, n):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Whether the first ``n`` entries of ``v`` are finite."""
    finite = True
    for i in range(n):
        finite = finite and math.isfinite(v[i])
    return finite


@numba.njit(cache=True, nogil=True)
def _ekf_reset_covariance(prm, P, d):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    N = 2 * d + 1
    for i in range(N):
        for j in range(N):
            P[i, j] = 0.0
    for c in range(d):
        P[c, c] = prm[_POS0]
    for c in range(d):
        P[d + c, d + c] = prm[_VEL0]
    P[2 * d, 2 * d] = prm[_S0]


@numba.njit(cache=True, nogil=True)
def _ekf_predict(prm, scal, ist, t0, t1, y, P, u, free, geom, p_s, work, fbuf, sc, vec, mat, stats, err):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Mean by the model's integrator under ``V_f`` scaled by ``s``, covariance by :func:`_predict_cov`; code."""
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    N = 2 * d + 1
    g0 = vec[6, :d]
    _predict_cov(t0, t1 - t0, y, P, u, prm[_QA2], prm[_QS2], free, geom, p_s, vec[0], vec[1], vec[2], mat[0], mat[1],
                 mat[2], fbuf, sc, vec[5], g0, prm[_LUMEN] > 0.5)
    flow_scaled_into(params_of(geom), y[2 * d], p_s)
    gs = with_params(geom, p_s)
    ys = vec[3, :2 * d]  # the mean's (X, Z): the flow scale is not integrated
    for i in range(2 * d):
        ys[i] = y[i]
    g = work[G_ROW, :d]  # no gradient: the model's input is the acceleration U = B G
    uu = work[U_ROW, :d]
    for c in range(d):
        g[c] = 0.0
        uu[c] = u[c]
    code, h = integrate(t0, t1, ys, g, uu, free, gs, scal[2], prm[_IG:_IG + 7], stats, work, fbuf, sc)
    scal[2] = h
    failed = code != OK or not _finite_head(ys, 2 * d)
    if failed:
        # the estimate sank into a wall (a frame pulled it there, or the model's contact is too stiff to cross at
        # the least step): put it back on the lumen a brush length from the wall, with a fresh contact state, and
        # predict again, once (counted: wall_recoveries); a run that never fails keeps its bits
        ys[:2 * d] = y[:2 * d]
        if onto_lumen_at(t0, ys, gs, params_of(gs)[I_BRUSH_L0]):
            free[:] = 0.0
            ist[6] += 1
            code, h = integrate(t0, t1, ys, g, uu, free, gs, prm[_IG + 5], prm[_IG:_IG + 7], stats, work, fbuf, sc)
            scal[2] = h
            failed = code != OK or not _finite_head(ys, 2 * d)
    if failed:
        err[0] = t0
        err[1] = t1
        err[2] = code
        for i in range(N):
            err[3 + i] = y[i]
        return PREDICTION_FAILED
    for i in range(2 * d):
        y[i] = ys[i]
    finite = True
    for i in range(N):
        for j in range(N):
            if not math.isfinite(P[i, j]):
                finite = False
    small = True
    for c in range(d):
        small = small and P[c, c] < 1.0
    if not (finite and small):  # covariance lost: start it again
        _ekf_reset_covariance(prm, P, d)
        ist[4] += 1
    elif prm[_WALL_S2] > 0.0:
        _constrain_on_wall(prm[_WALL_S2], t1, y, P, u, free, geom, p_s, fbuf, sc, vec[5], g0, vec[0], vec[1])
    return OK


@numba.njit(cache=True, nogil=True)
def _constrain_on_wall(r2, t, y, P, u, free, geom, p_s, fbuf, sc, tc, g0, h, ph):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``wall_constraint_sigma_m``: where the estimate ``y`` at ``t`` rests on a wall (:func:`wall_press`, as the
    covariance's Jacobian tells it), ``P <- P - P h h^T P / (h^T P h + r2)`` with ``h = (n, 0, 0)``, ``n`` the wall's
    inward normal: a pseudo-measurement of the wall-normal position with zero innovation; whether it applied.
    ``h``, ``ph`` (2 d + 1,) scratch."""
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    N = 2 * d + 1
    flow_scaled_into(params_of(geom), y[2 * d], p_s)
    gs = with_params(geom, p_s)
    tc[0] = np.nan  # the memo may hold another time's or another scale's terms
    forces_memo(t, y, g0, free, gs, fbuf, sc, tc)
    if not wall_press(t, y, u, gs, fbuf, CONSTRAINT_ZONE_RADII):
        return False
    for i in range(N):
        h[i] = 0.0
    wall_normal_into(t, y, gs, h)
    s = r2
    for i in range(N):
        acc = 0.0
        for c in range(d):
            acc += P[i, c] * h[c]
        ph[i] = acc
    for c in range(d):
        s += h[c] * ph[c]
    for i in range(N):
        for j in range(i, N):
            v = P[i, j] - ph[i] * ph[j] / s
            P[i, j] = v
            P[j, i] = v
    return True


@numba.njit(cache=True, nogil=True)
def _project(prm, t, y, geom, free):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``wall_projection: lumen``: an estimate closer to a wall than the brush length put there
    (:func:`~vesselbot_ros.physics.integrator.onto_lumen_at`: where the steric force starts, not at contact, where it
    throws the estimate off), with a fresh contact state (the one carried along belongs to the estimate before the
    jump); else nothing."""
    if prm[_LUMEN] > 0.5 and onto_lumen_at(t, y, geom, params_of(geom)[I_BRUSH_L0]):
        for i in range(free.shape[0]):
            free[i] = 0.0


@numba.njit(cache=True, nogil=True)
def _ekf_find(ist, hist_t, t_acq):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    n = hist_t.shape[0]
    for back in range(ist[0]):
        if abs(hist_t[(ist[1] - back + n) % n] - t_acq) <= 1e-9:
            return back
    return -1


@numba.njit(cache=True, nogil=True)
def _ekf_repredict(  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
        prm, scal, ist, back, yc, Pc, y, P, hist_t, hist_y, hist_P, hist_u, free, geom, p_s, work, fbuf, sc, vec, mat,
        stats, err):
    """``(yc, Pc)`` is the state ``back`` ticks ago: rewrite the history to now, set ``(y, P)``; code.

    With ``wall_projection: lumen`` the contact state starts afresh: the one carried along is now's, not
    the past state's, and on a wall the difference throws the re-prediction off.
    """
    n = hist_t.shape[0]
    if prm[_LUMEN] > 0.5:
        for i in range(free.shape[0]):
            free[i] = 0.0
    for step in range(back, 0, -1):
        j = (ist[1] - step + n) % n
        k = (j + 1) % n
        hist_y[j, :] = yc
        hist_P[j, :, :] = Pc
        code = _ekf_predict(prm, scal, ist, hist_t[j], hist_t[k], yc, Pc, hist_u[j], free, geom, p_s, work, fbuf, sc,
                            vec, mat, stats, err)
        if code != OK:
            return code
    hist_y[ist[1], :] = yc
    hist_P[ist[1], :, :] = Pc
    y[:] = yc
    P[:, :] = Pc
    return OK


@numba.njit(cache=True, nogil=True)
def _start_track(prm, scal, ist, restart, t_acq, m, y, P, hist_t, hist_y, hist_P, hist_u, free, geom, p_s, work, fbuf,  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
                 sc, vec, mat, stats, err):
    """Start the track on a frame: its position at its acquisition time, re-predicted to now; code.

    The first frame keeps the prior's velocity and scale covariance; a ``restart`` (the filter lost the robot)
    starts from the whole prior covariance and is counted.
    """
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    N = 2 * d + 1
    n = hist_t.shape[0]
    yc = vec[4]
    Pc = mat[3]
    done = False
    if prm[_DELAY] > 0.5 and t_acq < scal[0] - 1e-9:
        back = _ekf_find(ist, hist_t, t_acq)
        if back >= 0:
            i = (ist[1] - back + n) % n
            yc[:] = hist_y[i]
            Pc[:, :] = hist_P[i]
            for c in range(d):
                yc[c] = m[c]
            _project(prm, hist_t[i], yc, geom, free)
            if restart:
                _ekf_reset_covariance(prm, Pc, d)
            else:
                for c in range(d):
                    for j in range(N):
                        Pc[c, j] = 0.0
                        Pc[j, c] = 0.0
                for c in range(d):
                    Pc[c, c] = prm[_POS0]
            code = _ekf_repredict(prm, scal, ist, back, yc, Pc, y, P, hist_t, hist_y, hist_P, hist_u, free, geom,
                                  p_s, work, fbuf, sc, vec, mat, stats, err)
            if code != OK:
                return code
            done = True
    if not done:
        for c in range(d):
            y[c] = m[c]
        _project(prm, scal[0], y, geom, free)
        if restart:
            _ekf_reset_covariance(prm, P, d)
        else:
            for c in range(d):
                P[c, c] = prm[_POS0]
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
def ekf_update(prm, scal, ist, y, P, hist_t, hist_y, hist_P, hist_u, free, geom, p_s, work, fbuf, sc, vec, mat,  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
               stats, t, g, has_meas, t_acq, m, out, err):
    """:meth:`ExtendedKalmanObserver.update` over explicit state, on the axes of ``g`` (d,): predict to ``t``, fuse a
    delivered frame ``m`` (d,) acquired at ``t_acq``.

    The caller checks that ``t`` is finite and not before ``scal[0]`` and that
    the gradient is finite.  Writes ``out`` (:func:`ekf_out_size`); allocates nothing.

    Returns:
        ``OK``, or :data:`PREDICTION_FAILED` (``err`` = ``[t0, t1, integrator code, state (N)]``,
        :func:`ekf_failure_message`).
    """
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    n = hist_t.shape[0]
    u = vec[7, :d]  # U = B G, the input acceleration
    for i in range(d):
        acc = prm[_B + i * d] * g[0]
        for j in range(1, d):
            acc = acc + prm[_B + i * d + j] * g[j]
        u[i] = acc
    if ist[0] > 0:  # the input over the last tick is the one applied since
        for c in range(d):
            hist_u[ist[1], c] = u[c]
    if t > scal[0]:
        code = _ekf_predict(prm, scal, ist, scal[0], t, y, P, u, free, geom, p_s, work, fbuf, sc, vec, mat, stats, err)
        if code != OK:
            return code
    scal[0] = t
    # push the prior at t (before any correction) and a zero input that the next tick overwrites
    head = (ist[1] + 1) % n
    ist[1] = head
    hist_t[head] = t
    hist_y[head, :] = y
    hist_P[head, :, :] = P
    for c in range(d):
        hist_u[head, c] = 0.0
    ist[0] = min(ist[0] + 1, n)
    used = 0.0
    rejected = 0.0
    innov = out[2 * d + 1:3 * d + 1]
    for c in range(d):
        innov[c] = 0.0
    yc = vec[4]
    Pc = mat[3]
    KK = mat[4][:, :d]
    nu = vec[7, d:2 * d]
    Si = mat[5][:d, :d]
    if has_meas:
        finite = math.isfinite(t_acq)
        for c in range(d):
            finite = finite and math.isfinite(m[c])
        if not finite or t_acq > scal[0] + 1e-9:
            rejected = 1.0
        elif scal[3] < 0.5 or ist[2] >= prm[_MAX_REJ]:
            code = _start_track(prm, scal, ist, scal[3] > 0.5, t_acq, m, y, P, hist_t, hist_y, hist_P, hist_u, free,
                                geom, p_s, work, fbuf, sc, vec, mat, stats, err)
            if code != OK:
                return code
            used = 1.0
        else:
            found = False
            ok = False
            before = 0.0  # the prior's distance from the frame (squared)
            for c in range(d):
                before = before + (y[c] - m[c]) * (y[c] - m[c])
            if prm[_DELAY] > 0.5 and t_acq < scal[0] - 1e-9:
                back = _ekf_find(ist, hist_t, t_acq)
                if back >= 0:
                    found = True
                    i = (ist[1] - back + n) % n
                    yc[:] = hist_y[i]
                    Pc[:, :] = hist_P[i]
                    ok, _d2 = _correct(yc, Pc, m, prm[_R2], prm[_GATE], KK, mat[2], nu, Si, geom)
                    if ok:
                        _project(prm, hist_t[i], yc, geom, free)
                        code = _ekf_repredict(prm, scal, ist, back, yc, Pc, y, P, hist_t, hist_y, hist_P, hist_u, free,
                                              geom, p_s, work, fbuf, sc, vec, mat, stats, err)
                        if code != OK:
                            return code
            if not found:
                ok, _d2 = _correct(y, P, m, prm[_R2], prm[_GATE], KK, mat[2], nu, Si, geom)
                if ok:
                    _project(prm, scal[0], y, geom, free)
            if ok:
                after = 0.0
                for c in range(d):
                    after = after + (y[c] - m[c]) * (y[c] - m[c])
                if math.sqrt(after) > math.sqrt(before) + prm[_FLUNG]:
                    # the update took the estimate away from the frame it fused (a linearisation across a wall's
                    # crest, re-predicted through its contact, or a projection out of the wall along the wrong
                    # face): a Kalman correction cannot, so the filter lost the robot; its track restarts here
                    code = _start_track(prm, scal, ist, True, t_acq, m, y, P, hist_t, hist_y, hist_P, hist_u, free,
                                        geom, p_s, work, fbuf, sc, vec, mat, stats, err)
                    if code != OK:
                        return code
                for c in range(d):
                    innov[c] = -nu[c]  # X_hat - Y, as Estimate documents
                scal[1] = t_acq
                used = 1.0
                ist[2] = 0
                scal[4] = math.inf
            elif ist[2] >= 1 and t_acq - scal[4] >= prm[_MAX_REJ_S]:
                # frames rejected in a row for max_rejection_s, and this one too: the filter lost the robot
                code = _start_track(prm, scal, ist, True, t_acq, m, y, P, hist_t, hist_y, hist_P, hist_u, free,
                                    geom, p_s, work, fbuf, sc, vec, mat, stats, err)
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
    for c in range(2 * d):
        out[c] = y[c]
    out[2 * d] = scal[0] - scal[1]
    out[3 * d + 1] = used
    out[3 * d + 2] = rejected
    out[3 * d + 3] = y[2 * d]
    return OK


# ---- the compiled loop's form (control/compiled_stage.py's observer signature) -------------------------------------
# prm: ekf_params | history length n; state: scal (5) | y (N) | P (N x N) | hist_t (n) | hist_y (n x N) |
# hist_P (n x N x N) | hist_u (n x d) | free (4); istate: ist (6); work: p_s (the model's size) | work (12 x 2 d) |
# fbuf (8 x d) | sc (4 x d) | vec (8 x N) | mat (6 x N x N)
def _ekf_step(prm, state, istate, geom, work, stats, t, g, has_meas, t_acq, m, out, err):  # type: ignore[no-untyped-def]  # numba kernel: typed by observer_step_type
    """:func:`ekf_update` as a compiled observer step."""
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    nx = 2 * d + 1
    n_prm = _B + d * d
    n = int(prm[n_prm])
    o = 0
    scal = state[o:o + 5]
    o += 5
    y = state[o:o + nx]
    o += nx
    P = flat_view(state, o, (nx, nx))
    o += nx * nx
    hist_t = state[o:o + n]
    o += n
    hist_y = flat_view(state, o, (n, nx))
    o += n * nx
    hist_P = flat_view(state, o, (n, nx, nx))
    o += n * nx * nx
    hist_u = flat_view(state, o, (n, d))
    o += n * d
    free = state[o:o + 4]
    n_p = params_of(geom).shape[0]
    o = 0
    p_s = work[o:o + n_p]
    o += n_p
    w = flat_view(work, o, (12, 2 * d))
    o += 24 * d
    fbuf = flat_view(work, o, (8, d))
    o += 8 * d
    sc = flat_view(work, o, (4, d))
    o += 4 * d
    vec = flat_view(work, o, (8, nx))
    o += 8 * nx
    mat = flat_view(work, o, (6, nx, nx))
    return ekf_update(prm[0:n_prm], scal, istate[0:7], y, P, hist_t, hist_y, hist_P, hist_u, free, geom, p_s, w, fbuf, sc,
                      vec, mat, stats, t, g, has_meas, t_acq, m, out, err)


ekf_step = lazy_step(_ekf_step, observer_step_type)


def ekf_failure_message(err: npt.NDArray[np.float64]) -> str:
    """The error of a failed prediction (:data:`PREDICTION_FAILED`): the interval, the code and the state."""
    return f"observer: prediction failed on [{float(err[0])!r}, {float(err[1])!r}] (code {int(err[2])}), state {err[3:].tolist()}"


class EkfState:
    """The explicit state of one filter (:func:`ekf_update`): estimate, covariance, history, scratch.

    Args:
        params: Filter settings.
        model: The dynamics model (its ``geom``, input matrix, integrator; its axis count ``dims``).
        x_hat0: (d,) prior position, m.
        z_hat0: (d,) prior velocity, m/s.
        t0_s: Time of the prior (s).
        tick_s: Control period (s).
    """

    def __init__(self, params: EkfParams, model: Any, x_hat0: npt.NDArray[np.float64], z_hat0: npt.NDArray[np.float64],
                 t0_s: float, tick_s: float) -> None:
        d = int(getattr(model, "dims", 2))
        n_x = 2 * d + 1
        self.dims = d
        self.prm = ekf_params(params, model.input_matrix, model.integrator)
        self.geom = model.geom
        p = self.geom if isinstance(self.geom, np.ndarray) else self.geom[0]
        self.p_s = p.copy()  # flow_scaled_into then copies only the scalars (a network's field block is in place)
        self.scal = np.array([float(t0_s), -math.inf, float(model.integrator.max_step_s), 0.0, math.inf])
        # history count, head, rejections in a row, rejected, covariance resets, track resets, wall recoveries
        self.ist = np.zeros(7, dtype=np.int64)
        self.ist[1] = -1
        self.y = np.array([*x_hat0[:d], *z_hat0[:d], params.flow_scale0])
        self.P = np.diag([params.position_sigma0_m**2 * 1e4] * d + [params.velocity_sigma0_m_per_s**2] * d
                         + [params.flow_scale_sigma0**2])
        if not params.estimate_flow_scale:
            self.P[2 * d, 2 * d] = 0.0
        n_hist = ekf_history_len(params, tick_s)
        self.hist_t = np.full(n_hist, -math.inf)
        self.hist_y = np.zeros((n_hist, n_x))
        self.hist_P = np.zeros((n_hist, n_x, n_x))
        self.hist_u = np.zeros((n_hist, d))
        self.free = np.zeros(4)
        self.work, self.fbuf, self.sc = new_workspace(d)
        self.vec = np.zeros((8, n_x))
        self.mat = np.zeros((6, n_x, n_x))
        self.out = np.zeros(ekf_out_size(d))
        self.err = np.zeros(3 + n_x)

    def copy(self) -> EkfState:
        """An independent copy (every array copied): a fresh run's state from a prepared one."""
        new = object.__new__(EkfState)
        for k, v in vars(self).items():
            setattr(new, k, v.copy() if isinstance(v, np.ndarray) else v)  # geom: the model's, shared
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
        x_hat0: (d,) prior position, m (d the model's axes).
        z_hat0: (d,) prior velocity, m/s; zeros if None.
        t0_s: Time of the prior (s).
        tick_s: Control period (s): the history holds one entry per tick.
    """

    def __init__(self, params: EkfParams, model: Any, x_hat0: npt.ArrayLike, z_hat0: npt.ArrayLike | None = None,
                 t0_s: float = 0.0, tick_s: float = 1e-3) -> None:
        d = int(getattr(model, "dims", 2))
        x0 = np.asarray(x_hat0, dtype=np.float64)
        z0 = np.zeros(d) if z_hat0 is None else np.asarray(z_hat0, dtype=np.float64)
        if x0.shape != (d,) or z0.shape != (d,) or not (np.all(np.isfinite(x0)) and np.all(np.isfinite(z0))):
            raise ModelInputError(f"observer prior must be finite ({d},) + ({d},), got {x_hat0!r}, {z_hat0!r}")
        self.dims = d
        if not (math.isfinite(tick_s) and tick_s > 0.0):
            raise ModelInputError(f"tick_s must be finite and > 0, got {tick_s!r}")
        self.params = params
        self.model = model
        self.stats = model.stats  # integrator statistics shared with the model, as observer (25)
        self.tick_s = float(tick_s)
        self.ekf = EkfState(params, model, x0, z0, float(t0_s), float(tick_s))

    @property
    def state(self) -> npt.NDArray[np.float64]:
        """(2 d + 1,) ``(X, Z, s)`` copy."""
        return self.ekf.y.copy()

    def compiled(self) -> CompiledObserver:
        """This filter in the compiled loop's form (:mod:`vesselbot_ros.control.compiled_stage`), now."""
        e = self.ekf
        state = np.concatenate([e.scal, e.y, e.P.ravel(), e.hist_t, e.hist_y.ravel(), e.hist_P.ravel(), e.hist_u.ravel(),
                                e.free])
        work = np.concatenate([e.p_s, e.work.ravel(), e.fbuf.ravel(), e.sc.ravel(), e.vec.ravel(), e.mat.ravel()])
        return CompiledObserver(ekf_step, np.concatenate([e.prm, [float(len(e.hist_t))]]), state, e.ist, work, e.geom,
                                ekf_failure_message)

    @property
    def covariance(self) -> npt.NDArray[np.float64]:
        """(2 d + 1, 2 d + 1) covariance copy."""
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
    def wall_recoveries(self) -> int:
        """Predictions that failed with the estimate in a wall and were made again from the lumen (a brush length
        from the wall, fresh contact state)."""
        return int(self.ekf.ist[6])

    @property
    def track_resets(self) -> int:
        """Times the track restarted on a frame after ``max_consecutive_rejections`` rejections in a row."""
        return int(self.ekf.ist[5])

    def update(self, t_s: float, measurement: Any | None, applied_gradient_prev: npt.ArrayLike) -> Estimate:
        """Predict to ``t_s`` under the applied gradient, then fuse a delivered frame.

        Args:
            t_s: Tick time (s), non-decreasing.
            measurement: A :class:`~vesselbot_ros.scanner.imager_model.Measurement` or None.
            applied_gradient_prev: (d,) gradient applied since the previous tick (T/m).

        Returns:
            The :class:`Estimate` at ``t_s`` (``flow_scale`` = ``s_hat``).
        """
        d = self.dims
        g = np.asarray(applied_gradient_prev, dtype=np.float64)
        if g.shape != (d,) or not bool(np.isfinite(g).all()):
            raise ModelInputError(f"observer: applied gradient must be a finite ({d},) array, got {applied_gradient_prev!r}")
        e = self.ekf
        if not math.isfinite(t_s) or t_s < e.scal[0] - 1e-12:
            raise ModelInputError(f"observer: time must be finite and non-decreasing, got {t_s!r} after {float(e.scal[0])!r}")
        has, t_acq, m = measurement_arrays(measurement, d)
        code = ekf_update(e.prm, e.scal, e.ist, e.y, e.P, e.hist_t, e.hist_y, e.hist_P, e.hist_u, e.free, e.geom, e.p_s,
                          e.work, e.fbuf, e.sc, e.vec, e.mat, self.stats, float(t_s), np.ascontiguousarray(g), has, t_acq,
                          m, e.out, e.err)
        if code != OK:
            raise ModelInputError(ekf_failure_message(e.err))
        o = e.out
        return Estimate(float(e.scal[0]), o[0:d].copy(), o[d:2 * d].copy(), float(o[2 * d]), o[2 * d + 1:3 * d + 1].copy(),
                        bool(o[3 * d + 1] > 0.5), bool(o[3 * d + 2] > 0.5), float(o[3 * d + 3]))
