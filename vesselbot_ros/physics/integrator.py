"""Compiled integrators of ``Xd = Z, Zd = a(t, X, Z; G) + u`` over one control period.

The right-hand side is the physics kernel's total acceleration
(:func:`vesselbot_ros.physics.kernel.accel`) under a gradient ``G`` held over
the period, plus an optional constant acceleration ``u``: the plant passes the
true gradient and ``u = 0``; the observer's model passes ``G = 0`` and
``u = B G`` with its own input matrix ``B`` (so a wrong input mapping stays
the model's own mistake).

Why adaptive.  The Hertz contact (15) is stiff: at 1 um penetration its
linearised frequency is ``sqrt(1.5 k sqrt(delta) / m) ~ 2e5 rad/s`` for the
Table III robot, so explicit fixed-step RK4 needs ``dt ~ 1e-5 s`` everywhere,
although the robot touches a wall during a few milliseconds at most.  The
default ``dopri5`` is Dormand-Prince 5(4) with embedded error control
(max-norm of ``err_i / (atol_i + rtol |y_i|)``, safety 0.9, growth in
``[0.2, 5]``, FSAL): in free flow it takes steps up to ``max_step_s``, through
a contact it shrinks them to what stability and accuracy require, and the
step size is carried from one control period to the next.  ``rk4`` (fixed
step) is kept as the reference.

The contact loading/unloading state (``contact_arr``) is advanced by
:func:`~vesselbot_ros.physics.kernel.update_contact` after every accepted
step, with the nearest wall's ``delta``.

Return codes: 0 = ok; 1 = the step size collapsed (no progress in time, or more
than :data:`MAX_STEPS_PER_CALL` steps over one period); 2 = a non-finite state
(returned as soon as a step would accept one, so a NaN never loops on).
:func:`failure_message` words them for the plant's and the observer's errors.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import numba
import numpy as np

from vesselbot_ros.config import ConfigError, check_choice, check_positive
from vesselbot_ros.physics.kernel import I_MASS, I_NET_ON, forces_tc, time_terms_into, update_contact, wall_delta_at, wall_delta_xz

__all__ = [
    "IntegratorParams",
    "Workspace",
    "new_workspace",
    "integrate_dopri5",
    "integrate_dopri5_ws",
    "integrate_rk4",
    "integrate_rk4_ws",
    "OK",
    "STEP_TOO_SMALL",
    "NON_FINITE",
    "MAX_STEPS_PER_CALL",
    "failure_message",
]

OK = 0
STEP_TOO_SMALL = 1
NON_FINITE = 2
#: Steps (accepted + rejected) allowed in one call before it stops with STEP_TOO_SMALL: a normal
#: control period takes tens to a few thousand, so this bounds a collapsing run to seconds, never a hang.
MAX_STEPS_PER_CALL = 1_000_000
CAUSES = {OK: "ok", STEP_TOO_SMALL: "step size collapsed", NON_FINITE: "non-finite state"}


def failure_message(who: str, t0: float, t1: float, code: int, state: list[float]) -> str:
    """One line naming the integration that failed, its interval (the tick) and the cause."""
    return f"{who} integration failed on [{t0!r}, {t1!r}] (code {code}: {CAUSES.get(code, 'unknown')}): state {state}"

@dataclasses.dataclass(frozen=True)
class IntegratorParams:
    """Plant (and observer-prediction) integrator.

    Attributes:
        method: ``dopri5``: compiled adaptive Dormand-Prince 5(4) with error
            control (steps shrink automatically through wall contacts);
            ``rk4``: compiled fixed-step RK4 with ``fixed_step_s`` (reference).
        rtol: Relative tolerance (dopri5).
        atol_position_m: Absolute tolerance on positions (m).
        atol_velocity_m_per_s: Absolute tolerance on velocities (m/s).
        max_step_s: Largest step (s) (dopri5).
        min_step_s: Smallest step (s); a step that still fails the tolerance
            at this size is accepted and counted as *forced* (only happens
            across a jump of the right-hand side, see ``paper_heaviside``).
        fixed_step_s: Step of ``rk4`` (s); the control period is split into
            ``ceil(period / fixed_step_s)`` equal steps.
    """

    method: Literal["dopri5", "rk4"] = "dopri5"
    rtol: float = 1e-6
    atol_position_m: float = 1e-9
    atol_velocity_m_per_s: float = 1e-7
    max_step_s: float = 1e-3
    min_step_s: float = 1e-7
    fixed_step_s: float = 1e-5

    def __post_init__(self) -> None:
        check_choice("method", self.method, ("dopri5", "rk4"))
        check_positive("rtol", self.rtol)
        check_positive("atol_position_m", self.atol_position_m)
        check_positive("atol_velocity_m_per_s", self.atol_velocity_m_per_s)
        check_positive("max_step_s", self.max_step_s)
        check_positive("min_step_s", self.min_step_s)
        check_positive("fixed_step_s", self.fixed_step_s)
        if self.min_step_s > self.max_step_s:
            raise ConfigError(f"min_step_s must be <= max_step_s ({self.max_step_s!r}), got {self.min_step_s!r}")



# The functions that run once per force evaluation or per step are compiled with ``_nrt=False``: they allocate
# nothing, and without numba's runtime they take no atomic reference counts on the arrays they view and pass
# (those counts were ~18 % of a compiled run's samples under ``perf``, and contended between threads).

#: Scratch arrays of one integrator: ``(work (10, 4), fbuf (8, 2))`` float64.  ``work`` rows 0-8 are the
#: stages, row 9 the memo of the force model's time-only terms (:func:`~vesselbot_ros.physics.kernel.time_terms_into`).
Workspace = tuple[np.ndarray, np.ndarray]
#: Row of ``work`` holding the time-only terms ``[t, D(t), pulse factor, wall factor]``.
TIME_TERMS_ROW = 9


@numba.njit(cache=True)
def new_workspace():  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(work, fbuf)``: the scratch arrays :func:`integrate_dopri5_ws` and :func:`integrate_rk4_ws` write into."""
    work = np.empty((10, 4))
    work[TIME_TERMS_ROW, 0] = np.nan
    return work, np.empty((8, 2))


# Dormand-Prince 5(4) tableau
_C2, _C3, _C4, _C5 = 1.0 / 5.0, 3.0 / 10.0, 4.0 / 5.0, 8.0 / 9.0
_A21 = 1.0 / 5.0
_A31, _A32 = 3.0 / 40.0, 9.0 / 40.0
_A41, _A42, _A43 = 44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0
_A51, _A52, _A53, _A54 = 19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0
_A61, _A62, _A63, _A64, _A65 = 9017.0 / 3168.0, -355.0 / 33.0, 46732.0 / 5247.0, 49.0 / 176.0, -5103.0 / 18656.0
_B1, _B3, _B4, _B5, _B6 = 35.0 / 384.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0
_E1 = 71.0 / 57600.0
_E3 = -71.0 / 16695.0
_E4 = 71.0 / 1920.0
_E5 = -17253.0 / 339200.0
_E6 = 22.0 / 525.0
_E7 = -1.0 / 40.0


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _rhs(t, y, gx, gz, ux, uz, contact, p, out, fbuf, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    # the kernel's accel() without its (8, 2) scratch, time-only terms memoised in tc: same operations, same doubles
    forces_tc(t, y[0], y[1], y[2], y[3], gx, gz, contact, p, fbuf, tc)
    out[0] = y[2]
    out[1] = y[3]
    out[2] = fbuf[7, 0] / p[I_MASS] + ux
    out[3] = fbuf[7, 1] / p[I_MASS] + uz


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _update_contact_at(t, y, contact, p, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if p[I_NET_ON] > 0.5:  # a network's wall comes from the grid at (x, z), not from D(t)
        delta, _wall = wall_delta_xz(t, y[0], y[1], p)
    else:
        time_terms_into(t, p, tc)
        delta, _wall = wall_delta_at(y[1], tc[1], p)
    update_contact(contact, delta, p)


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def integrate_dopri5_ws(t0, t1, y, gx, gz, ux, uz, contact, p, h, rtol, atol_pos, atol_vel, h_min, h_max, stats, work, fbuf):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Integrate ``y = (x, z, vx, vz)`` in place from ``t0`` to ``t1`` (s).

    Args: t0, t1 (s); y (4,) float64, overwritten; gx, gz gradient (T/m);
    ux, uz extra acceleration (m/s^2); contact (4,) contact state, updated;
    p packed physics params; h proposed first step (s); rtol (-); atol_pos (m);
    atol_vel (m/s); h_min, h_max (s); stats (4,) int64 += [accepted, rejected,
    rhs evaluations, steps forced at h_min].  A step that fails the tolerance
    at ``h_min`` is accepted and counted as forced (the tolerance cannot be met
    across a jump of the right-hand side).

    ``work`` (10, 4) and ``fbuf`` (8, 2) float64 are scratch arrays the caller
    allocates once (:func:`new_workspace`): nothing is allocated here.

    Returns:
        (code, h_next): return code and the step size to propose next period.
    """
    k1 = work[0]
    k2 = work[1]
    k3 = work[2]
    k4 = work[3]
    k5 = work[4]
    k6 = work[5]
    k7 = work[6]
    yt = work[7]
    yn = work[8]
    tc = work[TIME_TERMS_ROW]
    tc[0] = np.nan  # p may differ from the last call's
    t = t0
    h = min(max(h, h_min), h_max)
    _rhs(t, y, gx, gz, ux, uz, contact, p, k1, fbuf, tc)
    stats[2] += 1
    n_steps = 0
    while t < t1 - 1e-15 * max(1.0, abs(t1)):
        last = False
        hs = h
        if t + hs >= t1:
            hs = t1 - t
            last = True
        n_steps += 1
        if not t + hs > t or n_steps > MAX_STEPS_PER_CALL:
            return STEP_TOO_SMALL, h
        for i in range(4):
            yt[i] = y[i] + hs * _A21 * k1[i]
        _rhs(t + _C2 * hs, yt, gx, gz, ux, uz, contact, p, k2, fbuf, tc)
        for i in range(4):
            yt[i] = y[i] + hs * (_A31 * k1[i] + _A32 * k2[i])
        _rhs(t + _C3 * hs, yt, gx, gz, ux, uz, contact, p, k3, fbuf, tc)
        for i in range(4):
            yt[i] = y[i] + hs * (_A41 * k1[i] + _A42 * k2[i] + _A43 * k3[i])
        _rhs(t + _C4 * hs, yt, gx, gz, ux, uz, contact, p, k4, fbuf, tc)
        for i in range(4):
            yt[i] = y[i] + hs * (_A51 * k1[i] + _A52 * k2[i] + _A53 * k3[i] + _A54 * k4[i])
        _rhs(t + _C5 * hs, yt, gx, gz, ux, uz, contact, p, k5, fbuf, tc)
        for i in range(4):
            yt[i] = y[i] + hs * (_A61 * k1[i] + _A62 * k2[i] + _A63 * k3[i] + _A64 * k4[i] + _A65 * k5[i])
        _rhs(t + hs, yt, gx, gz, ux, uz, contact, p, k6, fbuf, tc)
        for i in range(4):
            yn[i] = y[i] + hs * (_B1 * k1[i] + _B3 * k3[i] + _B4 * k4[i] + _B5 * k5[i] + _B6 * k6[i])
        _rhs(t + hs, yn, gx, gz, ux, uz, contact, p, k7, fbuf, tc)
        stats[2] += 6
        err = 0.0
        for i in range(4):
            e = hs * (_E1 * k1[i] + _E3 * k3[i] + _E4 * k4[i] + _E5 * k5[i] + _E6 * k6[i] + _E7 * k7[i])
            atol = atol_pos if i < 2 else atol_vel
            sc = atol + rtol * max(abs(y[i]), abs(yn[i]))
            r = abs(e) / sc
            if not (r <= err):  # also catches NaN
                err = r
        if not math.isfinite(err):
            err = 1e10
        forced = err > 1.0 and hs <= h_min * (1.0 + 1e-12)
        if forced:
            # a discontinuous right-hand side (e.g. interactions x H(-delta) at
            # delta = 0) cannot meet the tolerance at any step: accept at h_min
            stats[3] += 1
        if err <= 1.0 or forced:
            if not (math.isfinite(yn[0]) and math.isfinite(yn[1]) and math.isfinite(yn[2]) and math.isfinite(yn[3])):
                for i in range(4):
                    y[i] = yn[i]
                return NON_FINITE, h
            t = t1 if last else t + hs
            for i in range(4):
                y[i] = yn[i]
            c0, c1, c2, c3 = contact[0], contact[1], contact[2], contact[3]
            _update_contact_at(t, y, contact, p, tc)
            stats[0] += 1
            if c0 == contact[0] and c1 == contact[1] and c2 == contact[2] and c3 == contact[3]:
                for i in range(4):  # FSAL: last stage is the next first stage
                    k1[i] = k7[i]
            else:  # the contact state changed the rhs: re-evaluate
                _rhs(t, y, gx, gz, ux, uz, contact, p, k1, fbuf, tc)
                stats[2] += 1
            fac = 5.0 if err == 0.0 else min(5.0, max(0.2, 0.9 * err ** -0.2))
            if not last or hs >= h:
                h = min(h_max, hs * fac)
        else:
            stats[1] += 1
            h = max(h_min, hs * max(0.2, 0.9 * err ** -0.2))
    for i in range(4):
        if not math.isfinite(y[i]):
            return NON_FINITE, h
    return OK, h


@numba.njit(cache=True)
def integrate_dopri5(t0, t1, y, gx, gz, ux, uz, contact, p, h, rtol, atol_pos, atol_vel, h_min, h_max, stats):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`integrate_dopri5_ws` with a workspace allocated for this call (convenience)."""
    work, fbuf = new_workspace()
    return integrate_dopri5_ws(t0, t1, y, gx, gz, ux, uz, contact, p, h, rtol, atol_pos, atol_vel, h_min, h_max,
                               stats, work, fbuf)


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def integrate_rk4_ws(t0, t1, y, gx, gz, ux, uz, contact, p, h_fixed, stats, work, fbuf):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Fixed-step RK4 from ``t0`` to ``t1`` with ``ceil((t1-t0)/h_fixed)`` equal steps.

    Same arguments as :func:`integrate_dopri5_ws`; returns the code.
    """
    n = int(math.ceil((t1 - t0) / h_fixed - 1e-9))
    if n < 1:
        n = 1
    h = (t1 - t0) / n
    k1 = work[0]
    k2 = work[1]
    k3 = work[2]
    k4 = work[3]
    yt = work[7]
    tc = work[TIME_TERMS_ROW]
    tc[0] = np.nan  # p may differ from the last call's
    for j in range(n):
        t = t0 + j * h
        _rhs(t, y, gx, gz, ux, uz, contact, p, k1, fbuf, tc)
        for i in range(4):
            yt[i] = y[i] + 0.5 * h * k1[i]
        _rhs(t + 0.5 * h, yt, gx, gz, ux, uz, contact, p, k2, fbuf, tc)
        for i in range(4):
            yt[i] = y[i] + 0.5 * h * k2[i]
        _rhs(t + 0.5 * h, yt, gx, gz, ux, uz, contact, p, k3, fbuf, tc)
        for i in range(4):
            yt[i] = y[i] + h * k3[i]
        _rhs(t + h, yt, gx, gz, ux, uz, contact, p, k4, fbuf, tc)
        for i in range(4):
            y[i] = y[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        _update_contact_at(t + h, y, contact, p, tc)
        stats[0] += 1
        stats[2] += 4
    for i in range(4):
        if not math.isfinite(y[i]):
            return NON_FINITE
    return OK


@numba.njit(cache=True)
def integrate_rk4(t0, t1, y, gx, gz, ux, uz, contact, p, h_fixed, stats):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`integrate_rk4_ws` with a workspace allocated for this call (convenience)."""
    work, fbuf = new_workspace()
    return integrate_rk4_ws(t0, t1, y, gx, gz, ux, uz, contact, p, h_fixed, stats, work, fbuf)
