"""A predictive controller built for the imaging/propulsion sequence (controller kind ``predictive``).

Law (24) asks for the gradient that would track the reference if it were
applied all the time; under the scanner's multiplexing it is applied in the
propulsion windows only, and the bead coasts (drifts with the blood and sinks)
through the tracking window and the dead times.  This controller plans each
propulsion window for the coast that follows:

* at the first tick of a propulsion window (and again when a new frame
  corrected the estimate during the window), it predicts the bead from the
  observer's estimate (position, velocity, blood-velocity scale) to the start
  of the next propulsion window with the model's own force kernel
  (:func:`~vesselbot_ros.physics.kernel.forces_into`, the controller's model
  with the flow scale applied) and a replica of the coil (saturation, slew,
  dB/dt, the sequence's gate: :func:`~vesselbot_ros.scanner.stages.seq_coil_apply`,
  fed the very commands this controller sends, so in lockstep it is the coil);
* the plan is ``pieces`` constant gradients over the rest of the window; it
  minimises the squared tracking error at every tick of the window and of
  the coast (the reference extrapolated from its sample with its velocity and
  acceleration), the velocity error at the coast's end (over
  ``velocity_weight_s``) and ``regularization`` times the squared gradient
  (in units of the saturation), by ``iterations`` Gauss-Newton steps from the
  last plan (finite-difference Jacobian, normal equations solved by Gaussian
  elimination in a fixed order: no BLAS), each piece projected into the
  saturation disc, each step halved until the cost falls (at most three
  times; a step that never lowers it ends the iterations);
* outside propulsion windows it commands exactly zero (the coil's gate gives
  zero there anyway).

In continuous mode (``sequence.mode: continuous``) it plans over
``horizon_s`` and replans every ``replan_period_s``.

Time budget and fallback.  The work per plan is bounded: at most
``iterations`` x (1 + 2 ``pieces`` + 4) predictions (twice that with a
``spread_m``: one per hypothesis) of at most
``max_horizon_ticks`` ticks (four force evaluations each), so its time is
bounded by construction, not by a clock (the same numbers on every machine).  A plan that comes out non-finite
(a prediction that blew up against a wall) is dropped: the controller commands
zero for the window and reports the tick ``nonfinite`` (counted in the
``cmd_status`` column and the controller node's diagnostics).  A stale
estimate (older than ``stale_timeout_s``) commands zero (``stale``).

The Python class and the compiled loop call the same compiled function
(:func:`predictive_command`; :func:`predictive_step` is its form for the
compiled loop's one controller signature), so both give the same doubles.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Literal

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.config import OMIT_IF, ConfigError, check_choice, check_positive, check_range
from vesselbot_ros.control.backstepping import (
    FLOW_SCALE_INVALID,
    STATUS_NONFINITE,
    STATUS_OK,
    STATUS_STALE,
    ControlCommand,
    flow_scale_message,
)
from vesselbot_ros.control.compiled_stage import CompiledController, lazy_step
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.integrator import (
    axes_of,
    forces_at,
    mass_of,
    onto_lumen_at,
    params_of,
    rests_on_lower_wall,
    with_params,
)
from vesselbot_ros.physics.kernel import flow_scaled_into
from vesselbot_ros.scanner.actuator_limits import CoilLimits, coil_params, new_coil_state
from vesselbot_ros.scanner.sequence import SequenceParams, cycle_at, phase_code, sequence_vector
from vesselbot_ros.scanner.stages import seq_coil_apply

__all__ = ["PredictiveParams", "PredictiveController", "predictive_command", "predictive_step", "STATUS_NAMES"]

STATUS_NAMES = ("ok", "stale", "nonfinite")
_CODE_PROPULSION = 3  # scanner.sequence.PHASE_CODES["propulsion"]
_ERR_SCALE_M = 1e-4  # residuals in units of 100 um (the imager's noise): a well-scaled least-squares problem


@dataclasses.dataclass(frozen=True)
class PredictiveParams:
    """Parameters of the predictive controller (``controller: {kind: predictive, ...}``).

    Attributes:
        kind: ``predictive``.
        pieces: Constant gradients per propulsion window (2 gives the window's
            end position and velocity, hence the coast, to the plan).
        iterations: Gauss-Newton steps per plan (fixed: the time budget).
        regularization: Weight of the squared gradient, in units of the
            saturation, against the squared tracking error in units of 100 um.
        horizon_s: Continuous mode: prediction horizon (s).
        replan_period_s: Continuous mode: time between plans (s).
        max_horizon_ticks: Longest prediction (ticks); a sequence whose window
            and coast are longer is refused.
        velocity_weight_s: Weight of the velocity error at the horizon's end,
            as the time over which it would carry the bead (s): the next window
            starts from that velocity.
        stale_timeout_s: Estimate age beyond which the controller commands zero (s).
        wall_contact: ``none``: the plan shapes both gradient components
            everywhere.  ``carried``: where the reference rests on a wall
            below it (as law (24)'s option of that name decides it), the plan's
            vertical gradient is held at zero and only the axial one is
            planned: the weight and the wall hold the bead there, and a
            vertical push only lifts it off the wall (``vesselbot plan`` sets it
            for a plan that rests there).
        spread_m: The estimate's uncertainty along the route (m).  0: the
            plan is for the estimate alone (certainty equivalence).  > 0: it
            is for two hypotheses, the estimate moved ``spread_m`` forward
            and back along the reference's velocity (two sigma points of a
            spread of that size along the route), and minimises the sum of
            their costs, at twice the predictions.  Where the model is not
            smooth along the route (over a crest of the floor, where the
            weight pulls back on the near slope and forward on the far one)
            a plan for the estimate alone brakes a bead the frames put just
            past the top while it is still climbing, and sends it back down
            (``vesselbot plan`` sets it for a route over a crest).
    """

    kind: Literal["predictive"] = "predictive"
    pieces: int = 2
    iterations: int = 4
    regularization: float = 0.1
    horizon_s: float = 0.02
    replan_period_s: float = 0.005
    max_horizon_ticks: int = 400
    velocity_weight_s: float = 0.005
    stale_timeout_s: float = 0.2
    wall_contact: Literal["none", "carried"] = "none"
    spread_m: float = dataclasses.field(default=0.0, metadata={OMIT_IF: lambda v: v == 0.0})

    def __post_init__(self) -> None:
        check_choice("kind", self.kind, ("predictive",))
        check_choice("wall_contact", self.wall_contact, ("none", "carried"))
        check_range("pieces", self.pieces, 1, 8)
        check_range("iterations", self.iterations, 1, 20)
        check_range("max_horizon_ticks", self.max_horizon_ticks, 1, 5000)
        check_positive("regularization", self.regularization)
        check_positive("horizon_s", self.horizon_s)
        check_positive("replan_period_s", self.replan_period_s)
        check_positive("stale_timeout_s", self.stale_timeout_s)
        if not (math.isfinite(self.velocity_weight_s) and self.velocity_weight_s >= 0.0):
            raise ConfigError(f"velocity_weight_s must be finite and >= 0, got {self.velocity_weight_s!r}")
        check_range("spread_m", self.spread_m, 0.0, 1e-3)


# ---- parameter and state vectors -----------------------------------------------------------------------------------
# On d axes (2: x, z; 3: x, y, z), read from the reference sample's length:
# prm: [pieces, iterations, horizon ticks (continuous), replan ticks (continuous), regularization, stale timeout,
#       dt, max horizon ticks, finite-difference step (T/m), saturation (T/m), terminal velocity weight (s),
#       coil prm (4), sequence sv (7), wall contact carried (0/1), spread along the route (m)]
_P_N, _P_IT, _P_HZ, _P_RE, _P_LAM, _P_STALE, _P_DT, _P_HMAX, _P_H, _P_SAT, _P_VW, _P_COIL, _P_SV, _P_WALL, _P_SPREAD = (
    0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 15, 22, 23)


# state: [coil replica (d + 2), plan start time, ticks per piece, last age, has plan (0/1),
#         contact (4, zeros: the model's memoryless contact), plan: pieces x (d gradient components)]
@numba.njit(cache=True, nogil=True)
def _state_offsets(d):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(coil, t0, len, age, plan, contact, g)`` offsets in the state on ``d`` axes."""
    return 0, d + 2, d + 3, d + 4, d + 5, d + 6, d + 10


def state_size(pieces: int, dims: int) -> int:
    """Length of the controller's state on ``dims`` axes."""
    return int(dims) + 10 + int(pieces) * int(dims)


@numba.njit(cache=True, nogil=True)
def _layout(prm, n_model, d):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The work array's layout: ``(rows, residual, columns, normal matrix, rhs, step, coil out, replica, scratch,
    size)``.

    work: scaled model (``n_model``) | residual (``rows``) | d n columns (``rows`` each) | normal matrix
    (d n x d n) | rhs (d n) | step (d n) | coil out (2 d + 3) | coil replica (d + 2) | rollout scratch (9 d) |
    the two hypotheses' estimates (4 d; with a spread).  A row block per hypothesis (one, or two with a spread).
    """
    m = d * int(prm[_P_N])
    rows = (2 if prm[_P_SPREAD] > 0.0 else 1) * (d * int(prm[_P_HMAX]) + d + m)
    off_r = n_model
    off_cols = off_r + rows
    off_a = off_cols + rows * m
    off_b = off_a + m * m
    off_x = off_b + m
    off_cout = off_x + m
    off_rep = off_cout + 2 * d + 3
    off_scr = off_rep + d + 2
    return rows, off_r, off_cols, off_a, off_b, off_x, off_cout, off_rep, off_scr, off_scr + 9 * d + 4 * d


def work_size(prm: npt.NDArray[np.float64], n_model: int, dims: int) -> int:
    """Length of the controller's work array."""
    return int(_layout(prm, n_model, dims)[9])


@numba.njit(cache=True, nogil=True)
def _accel(t, y, g, contact, geom, fbuf, sc, a):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The prediction's acceleration into ``a`` (d,): magnetic, drag and apparent weight (the wall is a constraint:
    ``onto_lumen_at``).

    The contact and the surface forces are stiff (microseconds); at the prediction's one step per tick they
    would blow up, so the prediction keeps the bead in the lumen instead, where a wall carries it.
    """
    forces_at(t, y, g, contact, geom, fbuf, sc)
    m = mass_of(geom)
    for c in range(a.shape[0]):
        a[c] = (fbuf[0, c] + fbuf[1, c] + fbuf[2, c]) / m


@numba.njit(cache=True, nogil=True)
def _rollout(prm, state, geom, work, off_r, off_cout, off_rep, off_scr, fbuf, sc, t, est, pr, vr, ar, plan, n_win,  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
             n_hor, piece_len):
    """Predict ``n_hor`` ticks under ``plan`` (pieces over the first ``n_win`` ticks, zero after); residuals at ``off_r``."""
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    n = int(prm[_P_N])
    dt = prm[_P_DT]
    coil = prm[_P_COIL:_P_COIL + 4]
    sv = prm[_P_SV:_P_SV + 7]
    s_coil, _t0, _len, _age, _plan, s_contact, _g = _state_offsets(d)
    rep = work[off_rep:off_rep + d + 2]
    cout = work[off_cout:off_cout + 2 * d + 3]
    contact = state[s_contact:s_contact + 4]
    y = work[off_scr:off_scr + 2 * d]  # the bead (X, Z)
    ys = work[off_scr + 2 * d:off_scr + 4 * d]  # a stage's state
    ka = work[off_scr + 4 * d:off_scr + 5 * d]
    kb = work[off_scr + 5 * d:off_scr + 6 * d]
    kc = work[off_scr + 6 * d:off_scr + 7 * d]
    kd = work[off_scr + 7 * d:off_scr + 8 * d]
    g = work[off_scr + 8 * d:off_scr + 9 * d]
    for i in range(d + 2):
        rep[i] = state[s_coil + i]
    for i in range(2 * d):
        y[i] = est[i]
    h = dt
    for k in range(n_hor):
        tk = t + k * dt
        j = 0
        if k < n_win:
            j = k // piece_len
            if j > n - 1:
                j = n - 1
        for c in range(d):  # the command, in the coil's output slots (seq_coil_apply reads it before it writes them)
            cout[c] = plan[d * j + c] if k < n_win else 0.0
        seq_coil_apply(coil, sv, dt, rep, tk, cout[:d], cout)
        for c in range(d):
            g[c] = cout[c]
        # RK4 over [tk, tk + dt] under the gradient the coil applies over it
        _accel(tk, y, g, contact, geom, fbuf, sc, ka)
        for c in range(d):
            ys[c] = y[c] + 0.5 * h * y[d + c]
            ys[d + c] = y[d + c] + 0.5 * h * ka[c]
        _accel(tk + 0.5 * h, ys, g, contact, geom, fbuf, sc, kb)
        for c in range(d):
            ys[c] = y[c] + 0.5 * h * (y[d + c] + 0.5 * h * ka[c])
            ys[d + c] = y[d + c] + 0.5 * h * kb[c]
        _accel(tk + 0.5 * h, ys, g, contact, geom, fbuf, sc, kc)
        for c in range(d):
            ys[c] = y[c] + h * (y[d + c] + 0.5 * h * kb[c])
            ys[d + c] = y[d + c] + h * kc[c]
        _accel(tk + h, ys, g, contact, geom, fbuf, sc, kd)
        for c in range(d):
            y[c] = y[c] + h * (y[d + c] + h * (ka[c] + kb[c] + kc[c]) / 6.0)
            y[d + c] = y[d + c] + h * (ka[c] + 2.0 * kb[c] + 2.0 * kc[c] + kd[c]) / 6.0
        onto_lumen_at(tk + h, y, geom, 0.0)
        tau = (k + 1) * dt
        for c in range(d):
            work[off_r + d * k + c] = (y[c] - (pr[c] + vr[c] * tau + 0.5 * ar[c] * tau * tau)) / _ERR_SCALE_M
    # the velocity at the horizon's end (the next window starts from it), as the distance it carries the bead in
    # the velocity weight's time
    tau = n_hor * dt
    for c in range(d):
        work[off_r + d * n_hor + c] = prm[_P_VW] * (y[d + c] - (vr[c] + ar[c] * tau)) / _ERR_SCALE_M
    w = math.sqrt(prm[_P_LAM]) / prm[_P_SAT]
    for i in range(d * n):
        work[off_r + d * n_hor + d + i] = w * plan[i]


@numba.njit(cache=True, nogil=True)
def _rollouts(prm, state, geom, work, off_r, off_cout, off_rep, off_scr, fbuf, sc, t, est, hyp, pr, vr, ar, plan,  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
              n_win, n_hor, piece_len):
    """:func:`_rollout` from the estimate ``est``, or with a spread from each of its two hypotheses (``hyp``: the
    first's X, Z, then the second's), their residuals one block after the other from ``off_r``."""
    if prm[_P_SPREAD] > 0.0:
        d = axes_of(geom)
        used = d * n_hor + d + d * int(prm[_P_N])
        _rollout(prm, state, geom, work, off_r, off_cout, off_rep, off_scr, fbuf, sc, t, hyp[:2 * d], pr, vr, ar,
                 plan, n_win, n_hor, piece_len)
        _rollout(prm, state, geom, work, off_r + used, off_cout, off_rep, off_scr, fbuf, sc, t, hyp[2 * d:], pr, vr,
                 ar, plan, n_win, n_hor, piece_len)
    else:
        _rollout(prm, state, geom, work, off_r, off_cout, off_rep, off_scr, fbuf, sc, t, est, pr, vr, ar, plan, n_win,
                 n_hor, piece_len)


@numba.njit(cache=True, nogil=True)
def _hypotheses(prm, est, vr, hyp):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The two hypotheses of a spread into ``hyp`` (4 d): the estimate moved ``spread_m`` forward and back along the
    reference's velocity (not moved where the reference stands still), the estimated velocity kept."""
    d = vr.shape[0]
    big = abs(vr[0])  # the direction from the velocity over its largest component (no under- or overflow)
    for c in range(1, d):
        big = max(big, abs(vr[c]))
    shift = 0.0
    if big > 0.0:
        sq = (vr[0] / big) * (vr[0] / big)
        for c in range(1, d):
            sq = sq + (vr[c] / big) * (vr[c] / big)
        shift = prm[_P_SPREAD] / math.sqrt(sq)
    for c in range(d):
        u = vr[c] / big if big > 0.0 else 0.0
        hyp[c] = est[c] + shift * u
        hyp[d + c] = est[d + c]
        hyp[2 * d + c] = est[c] - shift * u
        hyp[3 * d + c] = est[d + c]


@numba.njit(cache=True, nogil=True)
def _solve(a, b, m, x):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Solve ``a[:m, :m] x = b[:m]`` by Gaussian elimination with partial pivoting (in place; fixed order)."""
    for c in range(m):
        piv = c
        for r in range(c + 1, m):
            if abs(a[r, c]) > abs(a[piv, c]):
                piv = r
        if piv != c:
            for k in range(m):
                tmp = a[c, k]
                a[c, k] = a[piv, k]
                a[piv, k] = tmp
            tmp = b[c]
            b[c] = b[piv]
            b[piv] = tmp
        d = a[c, c]
        if d == 0.0 or not math.isfinite(d):
            return False
        for r in range(c + 1, m):
            f = a[r, c] / d
            for k in range(c, m):
                a[r, k] -= f * a[c, k]
            b[r] -= f * b[c]
    for c in range(m - 1, -1, -1):
        s = b[c]
        for k in range(c + 1, m):
            s -= a[c, k] * x[k]
        x[c] = s / a[c, c]
    return True


@numba.njit(cache=True, nogil=True)
def _plan(prm, state, geom, work, n_model, fbuf, sc, t, est, pr, vr, ar, n_win, n_hor):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Gauss-Newton on the plan in ``state`` (``n_win`` window ticks, ``n_hor`` predicted); False if it is not finite."""
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    n = int(prm[_P_N])
    m = d * n
    used = d * n_hor + d + m
    rows, off_r, off_cols, off_a, off_b, off_x, off_cout, off_rep, off_scr, _size = _layout(prm, n_model, d)
    hyp = work[off_scr + 9 * d:off_scr + 13 * d]
    if prm[_P_SPREAD] > 0.0:
        _hypotheses(prm, est, vr, hyp)
        used = 2 * used
    _c, s_t0, s_len, _age, s_plan, _contact, s_g = _state_offsets(d)
    piece_len = (n_win + n - 1) // n
    if piece_len < 1:
        piece_len = 1
    plan = state[s_g:s_g + m]
    a = work[off_a:off_a + m * m].reshape((m, m))
    b = work[off_b:off_b + m]
    x = work[off_x:off_x + m]
    sat = prm[_P_SAT]
    step = prm[_P_H]
    # wall_contact carried and the reference on a wall below: the vertical components stay zero
    pinned = prm[_P_WALL] > 0.5 and rests_on_lower_wall(t, pr, geom)
    if pinned:
        for j in range(n):
            plan[d * j + d - 1] = 0.0
    for _it in range(int(prm[_P_IT])):
        _rollouts(prm, state, geom, work, off_r, off_cout, off_rep, off_scr, fbuf, sc, t, est, hyp, pr, vr, ar, plan,
                  n_win, n_hor, piece_len)
        for j in range(m):
            if pinned and j % d == d - 1:
                continue  # its row and column of the normal equations are the identity's (below): no step
            keep = plan[j]
            plan[j] = keep + step
            _rollouts(prm, state, geom, work, off_cols + j * rows, off_cout, off_rep, off_scr, fbuf, sc, t, est, hyp,
                      pr, vr, ar, plan, n_win, n_hor, piece_len)
            plan[j] = keep
            for i in range(used):
                work[off_cols + j * rows + i] = (work[off_cols + j * rows + i] - work[off_r + i]) / step
        for j in range(m):
            if pinned and j % d == d - 1:
                b[j] = 0.0
                for k in range(m):
                    a[j, k] = 1.0 if k == j else 0.0
                continue
            s = 0.0
            for i in range(used):
                s += work[off_cols + j * rows + i] * work[off_r + i]
            b[j] = -s
            for k in range(m):
                if pinned and k % d == d - 1:
                    a[j, k] = 0.0
                    continue
                s = 0.0
                for i in range(used):
                    s += work[off_cols + j * rows + i] * work[off_cols + k * rows + i]
                a[j, k] = s
        if not _solve(a, b, m, x):
            return False
        cost0 = 0.0
        for i in range(used):
            cost0 += work[off_r + i] * work[off_r + i]
        # the step, halved until the cost falls (the coil's gate and saturation make the problem non-smooth:
        # a full Gauss-Newton step can overshoot); none falls: the plan stands and the iterations end
        trial = work[off_cols:off_cols + m]  # the first column's storage is free again
        accepted = False
        alpha = 1.0
        for _half in range(4):
            for j in range(n):
                for c in range(d):
                    trial[d * j + c] = plan[d * j + c] + alpha * x[d * j + c]
                sq = trial[d * j] * trial[d * j]
                for c in range(1, d):
                    sq = sq + trial[d * j + c] * trial[d * j + c]
                norm = math.sqrt(sq)
                if norm > sat:
                    for c in range(d):
                        trial[d * j + c] = trial[d * j + c] * (sat / norm)
            _rollouts(prm, state, geom, work, off_cols + rows, off_cout, off_rep, off_scr, fbuf, sc, t, est, hyp, pr,
                      vr, ar, trial, n_win, n_hor, piece_len)
            cost = 0.0
            for i in range(used):
                cost += work[off_cols + rows + i] * work[off_cols + rows + i]
            if cost < cost0:
                accepted = True
                break
            alpha *= 0.5
        if not accepted:
            break
        for i in range(m):
            plan[i] = trial[i]
    for i in range(m):
        if not math.isfinite(plan[i]):
            return False
    state[s_t0] = t
    state[s_len] = piece_len
    state[s_plan] = 1.0
    return True


@numba.njit(cache=True, nogil=True)
def predictive_command(prm, state, geom, work, fbuf, sc, t, est, pr, vr, ar, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """One tick of the predictive controller (module docstring), as a compiled controller step
    (:mod:`vesselbot_ros.control.compiled_stage`: the estimate ``est`` = [X (d), Z (d), age, flow scale], the
    model ``geom``, the reference p, v, a (d,)); writes ``out`` = [g (d), U (d), flow scale, 1].

    Returns ``STATUS_OK``, ``STATUS_STALE``, ``STATUS_NONFINITE`` (a plan that came out non-finite: zero
    for the window) or :data:`~vesselbot_ros.control.backstepping.FLOW_SCALE_INVALID`.
    """
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    dt = prm[_P_DT]
    n = int(prm[_P_N])
    model_p = params_of(geom)
    n_model = model_p.shape[0]
    sv = prm[_P_SV:_P_SV + 7]
    s_coil, s_t0, s_len, s_age, s_plan, s_contact, s_g = _state_offsets(d)
    age = est[2 * d]
    flow_scale = est[2 * d + 1]
    out[2 * d] = flow_scale
    out[2 * d + 1] = 1.0
    status = STATUS_OK
    for c in range(d):
        out[c] = 0.0
    if not age <= prm[_P_STALE]:
        status = STATUS_STALE
        state[s_plan] = 0.0
    elif not (math.isfinite(flow_scale) and flow_scale > 0.0):
        return FLOW_SCALE_INVALID
    else:
        p = work[0:n_model]  # the model, its V_f scaled by the observer's estimate (a copy: the same doubles at 1)
        flow_scaled_into(model_p, flow_scale, p)
        gq = with_params(geom, p)
        new_frame = age < state[s_age] - 0.5 * dt  # a frame corrected the estimate since the last tick
        multiplexed = sv[0] > 0.5
        in_window = (not multiplexed) or phase_code(sv, t) == _CODE_PROPULSION
        if not in_window:
            state[s_plan] = 0.0  # the window ended: the next one is planned afresh
        else:
            elapsed = int(math.floor((t - state[s_t0]) / dt + 0.5)) if state[s_plan] > 0.5 else 0
            if multiplexed:
                _period, tau = cycle_at(sv, t)  # in a propulsion window: after start_s
                n_win = int(math.floor((sv[1] + sv[2] + sv[3] - tau) / dt + 0.5))
                n_hor = n_win + int(math.floor((sv[1] + 2.0 * sv[2]) / dt + 0.5))
                replan = state[s_plan] < 0.5 or new_frame
            else:
                n_win = int(prm[_P_HZ])
                n_hor = n_win
                replan = state[s_plan] < 0.5 or new_frame or elapsed >= int(prm[_P_RE])
            if n_hor > int(prm[_P_HMAX]):
                n_hor = int(prm[_P_HMAX])
            if n_win > n_hor:
                n_win = n_hor
            if replan:
                if state[s_plan] < 0.5:  # a new window starts from no gradient (the last window's plan is a poor
                    for i in range(d * n):  # start: the problem is not convex, and Gauss-Newton stays near it)
                        state[s_g + i] = 0.0
                if not _plan(prm, state, gq, work, n_model, fbuf, sc, t, est, pr, vr, ar, n_win, n_hor):
                    for i in range(d * n):
                        state[s_g + i] = 0.0
                    state[s_plan] = 0.0
                    status = STATUS_NONFINITE
                elapsed = 0
            if status == STATUS_OK:
                j = elapsed // int(state[s_len])
                if j > n - 1:
                    j = n - 1
                for c in range(d):
                    out[c] = state[s_g + d * j + c]
    state[s_age] = age
    # the coil replica takes the command the coil takes (the compiled sequence gate, saturation and slew)
    off_cout = _layout(prm, n_model, d)[6]
    cout = work[off_cout:off_cout + 2 * d + 3]
    nonzero = False
    for c in range(d):
        cout[c] = out[c]  # the command, in the coil's output slots (seq_coil_apply reads it before it writes them)
        nonzero = nonzero or out[c] != 0.0
    seq_coil_apply(prm[_P_COIL:_P_COIL + 4], sv, dt, state[s_coil:s_coil + d + 2], t, cout[:d], cout)
    if not nonzero:
        for c in range(d):
            out[d + c] = 0.0
    else:  # the motive acceleration the command asks for at the estimate: the magnetic term over the mass
        forces_at(t, est[:2 * d], out[:d], state[s_contact:s_contact + 4], geom, fbuf, sc)
        m = mass_of(geom)
        for c in range(d):
            out[d + c] = fbuf[0, c] / m
    return status


def _predictive_step(prm, state, geom, work, fbuf, sc, t, est, pr, vr, ar, out):  # type: ignore[no-untyped-def]  # numba kernel: typed by controller_step_type
    """:func:`predictive_command` as the compiled loop's controller step."""
    return predictive_command(prm, state, geom, work, fbuf, sc, t, est, pr, vr, ar, out)


predictive_step = lazy_step(_predictive_step)


def predictive_params(params: PredictiveParams, coil: CoilLimits, sequence: SequenceParams,
                      dt_s: float) -> npt.NDArray[np.float64]:
    """The (24,) parameter vector of :func:`predictive_command`.

    Raises:
        ConfigError: a propulsion window and its coast longer than ``max_horizon_ticks``.
    """
    sv = sequence_vector(sequence)
    if sequence.mode == "multiplexed":
        ticks = sequence.period_s / dt_s  # a whole window and the coast after it
        if ticks > params.max_horizon_ticks + 0.5:
            raise ConfigError(f"controller.max_horizon_ticks must cover a propulsion window and its coast "
                              f"({ticks:.0f} ticks of {dt_s!r} s), got {params.max_horizon_ticks!r}")
    sat = float(coil.saturation_T_per_m)
    return np.array([
        float(params.pieces), float(params.iterations), float(max(1, round(params.horizon_s / dt_s))),
        float(max(1, round(params.replan_period_s / dt_s))), float(params.regularization),
        float(params.stale_timeout_s), float(dt_s), float(params.max_horizon_ticks), 1e-3 * sat, sat,
        float(params.velocity_weight_s), *coil_params(coil), *sv, 1.0 if params.wall_contact == "carried" else 0.0,
        float(params.spread_m),
    ])


class PredictiveController:
    """The predictive controller's stage (module docstring): ``command(t, estimate, ref)`` and its compiled form, on
    the model's axes (the plane or a 3-D tree).

    Args:
        params: Its parameters.
        model: The controller's model of the plant (:class:`~vesselbot_ros.control.model.DynamicsModel`: its
            ``geom`` and ``dims``).
        coil: The coil's effective limits (dB/dt applied), as the coil stage has them.
        sequence: The scanner's sequence.
        dt_s: The control period (s).
    """

    def __init__(self, params: PredictiveParams, model: Any, coil: CoilLimits, sequence: SequenceParams,
                 dt_s: float) -> None:
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ModelInputError(f"dt_s must be finite and > 0, got {dt_s!r}")
        d = int(getattr(model, "dims", 2))
        self.dims = d
        self.params = params
        self.prm = predictive_params(params, coil, sequence, dt_s)
        self.geom = model.geom
        n_model = int(model.p.shape[0])
        self.state = np.zeros(state_size(params.pieces, d))
        self.state[0:d + 2] = new_coil_state(d, -dt_s)  # the coil stage's start (idle before t = 0)
        self.state[d + 4] = math.inf  # no estimate yet
        self.work = np.zeros(work_size(self.prm, n_model, d))
        self.fbuf = np.empty((8, d))
        self.sc = np.zeros((4, d))
        self._est = np.zeros(2 * d + 2)
        self._ref = np.zeros((3, d))
        self._out = np.zeros(2 * d + 2)

    def command(self, t_s: float, estimate: Any, ref: Any) -> ControlCommand:
        """The gradient for ``[t_s, t_s + dt]`` from the estimate and the reference sample."""
        d = self.dims
        est, r = self._est, self._ref
        est[:d] = estimate.x_hat
        est[d:2 * d] = estimate.z_hat
        est[2 * d] = float(estimate.time_since_measurement_s)
        est[2 * d + 1] = float(estimate.flow_scale)
        r[0] = ref.p
        r[1] = ref.v
        r[2] = ref.a
        status = predictive_command(self.prm, self.state, self.geom, self.work, self.fbuf, self.sc, float(t_s), est,
                                    r[0], r[1], r[2], self._out)
        if status == FLOW_SCALE_INVALID:
            raise ModelInputError(flow_scale_message(float(estimate.flow_scale)))
        return ControlCommand(self._out[0:d].copy(), self._out[d:2 * d].copy(), STATUS_NAMES[status])

    def compiled(self) -> CompiledController:
        """This controller in the compiled loop's form, now."""
        return CompiledController(predictive_step, self.prm, self.state, self.work.shape[0])
