"""The 3-D plant's compiled right-hand side and integrators: a bead in a vessel tree in space.

State ``y = (x, y, z, vx, vy, vz)`` (m, m/s), input the gradient ``G`` (3,) (T/m) held over a control period
plus an optional constant acceleration ``u`` (3,) (m/s^2): the plant passes ``G`` and ``u = 0``, the
observer's model ``G = 0`` and ``u = B G`` (as the planar integrators of
:mod:`vesselbot_ros.physics.integrator`, whose docstring says why adaptive and what the codes mean).

Geometry and flow at a point (:func:`geometry3d`), from the tree's samples
(:mod:`vesselbot_ros.vessels.plant_field3d`):

* the wall: signed distance ``s`` (> 0 in the lumen), unit inward normal ``n`` and local diameter ``D`` of the
  meshed wall (:func:`~vesselbot_ros.physics.wall_field3d.wall_field3d`: the grid, exact where it cannot
  answer), moved out by the diameter pulsation (13) as in the planar network
  (:func:`~vesselbot_ros.physics.kernel.network_geometry`): ``s_t = s + D eps(t) / 2``, ``D_t = D (1 + eps)``;
* the blood: the steady 3-D velocity (trilinear on the grid, per unit inlet centreline velocity) sampled at the
  point moved towards the centreline by ``(D / 2 - s) (1 - 1 / (1 + eps))`` along ``n`` (the field dilates
  with the vessel), times ``V_f`` and the pulse (12); the viscosity (Pries at the node's diameter) at the point.

Forces: :func:`~vesselbot_ros.physics.kernel3d.forces3d_into` (the planar network's terms on 3-vectors).
The contact state advances after every accepted step with ``delta = r - s_t``.

Arguments that describe the tree: ``W``, the wall lookup's nine arrays (``wall_field3d(x, y, z, *W)``), ``F``
(nz, ny, nx, 4) ``(vx, vy, vz, eta)`` (float32 or float64) per node and ``fh`` (7,) ``(x0, y0, z0, h, nx, ny, nz)``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from vesselbot_ros.physics.blood_flow import pulse_factor
from vesselbot_ros.physics.integrator import (  # the planar integrator's Dormand-Prince 5(4) tableau and codes
    _A21,
    _A31,
    _A32,
    _A41,
    _A42,
    _A43,
    _A51,
    _A52,
    _A53,
    _A54,
    _A61,
    _A62,
    _A63,
    _A64,
    _A65,
    _B1,
    _B3,
    _B4,
    _B5,
    _B6,
    _C2,
    _C3,
    _C4,
    _C5,
    _E1,
    _E3,
    _E4,
    _E5,
    _E6,
    _E7,
    MAX_STEPS_PER_CALL,
    NON_FINITE,
    OK,
    STEP_TOO_SMALL,
)
from vesselbot_ros.physics.kernel import I_A_F, I_D_PULSE, I_MASS, I_OMEGA_F, I_PHI_F, I_R, I_V_F, update_contact
from vesselbot_ros.physics.kernel3d import forces3d_into
from vesselbot_ros.physics.wall_field3d import corner_weight, wall_field3d

__all__ = ["geometry3d", "forces3d_at", "integrate3d", "new_workspace3d", "FLOW_CHANNELS"]

#: Channels per node of the flow grid ``F``: velocity (3) per unit inlet centreline velocity, viscosity (Pa s).
FLOW_CHANNELS = 4


@numba.njit(cache=True)
def new_workspace3d():  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(work (9, 6), fbuf (8, 3), sc (4, 3))``: scratch of :func:`integrate3d` and :func:`forces3d_at`."""
    return np.empty((9, 6)), np.empty((8, 3)), np.zeros((4, 3))


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _cell(fh, x, y, z):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The flow grid's cell (i, j, k) holding (x, y, z) (m) and the point's place in it (tx, ty, tz) in [0, 1]
    (clamped to the grid's edge cells)."""
    h = fh[3]
    nx = int(fh[4])
    ny = int(fh[5])
    nz = int(fh[6])
    fx = (x - fh[0]) / h
    fy = (y - fh[1]) / h
    fz = (z - fh[2]) / h
    i = min(max(int(math.floor(fx)), 0), nx - 2)
    j = min(max(int(math.floor(fy)), 0), ny - 2)
    k = min(max(int(math.floor(fz)), 0), nz - 2)
    tx = min(1.0, max(0.0, fx - i))
    ty = min(1.0, max(0.0, fy - j))
    tz = min(1.0, max(0.0, fz - k))
    return i, j, k, tx, ty, tz


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _flow_at(F, fh, x, y, z, c):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Channel ``c`` of the flow grid, trilinear at (x, y, z) (m); clamped to the grid's edge cells."""
    i, j, k, tx, ty, tz = _cell(fh, x, y, z)
    v = 0.0
    for cc in range(8):
        cx, cy, cz, w = corner_weight(cc, tx, ty, tz)
        v += w * float(F[k + cz, j + cy, i + cx, c])
    return v


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _velocity_at(F, fh, x, y, z):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Channels 0-2 of the flow grid (the velocity), trilinear at (x, y, z) (m) in one pass over the cell
    (each channel summed as :func:`_flow_at` sums it: the same doubles)."""
    i, j, k, tx, ty, tz = _cell(fh, x, y, z)
    v0 = 0.0
    v1 = 0.0
    v2 = 0.0
    for cc in range(8):
        cx, cy, cz, w = corner_weight(cc, tx, ty, tz)
        v0 += w * float(F[k + cz, j + cy, i + cx, 0])
        v1 += w * float(F[k + cz, j + cy, i + cx, 1])
        v2 += w * float(F[k + cz, j + cy, i + cx, 2])
    return v0, v1, v2


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def geometry3d(t, x, y, z, p, W, F, fh):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(s_t, nx, ny, nz, D_t, eta, vfx, vfy, vfz)`` at (x, y, z) (m), time t (s) (module docstring)."""
    s, n0, n1, n2, d = wall_field3d(x, y, z, W[0], W[1], W[2], W[3], W[4], W[5], W[6], W[7], W[8])
    eps = p[I_D_PULSE] * np.sin(p[I_OMEGA_F] * t + p[I_PHI_F])
    s_t = s + 0.5 * d * eps
    d_t = d * (1.0 + eps)
    shift = (0.5 * d - s) * (1.0 - 1.0 / (1.0 + eps))
    qx = x + n0 * shift
    qy = y + n1 * shift
    qz = z + n2 * shift
    scale = p[I_V_F] * pulse_factor(t, p[I_A_F], p[I_OMEGA_F], p[I_PHI_F])
    eta = _flow_at(F, fh, x, y, z, 3)
    v0, v1, v2 = _velocity_at(F, fh, qx, qy, qz)
    return s_t, n0, n1, n2, d_t, eta, scale * v0, scale * v1, scale * v2


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def forces3d_at(t, y, g, contact, p, W, F, fh, fbuf, sc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Fill ``fbuf`` (8, 3) with the force terms (N) on the bead of state ``y`` (6,) under the gradient ``g`` (3,);
    returns ``s_t`` (m).  ``sc`` (4, 3) is scratch (velocity, -, normal, blood velocity)."""
    s_t, n0, n1, n2, d_t, eta, v0, v1, v2 = geometry3d(t, y[0], y[1], y[2], p, W, F, fh)
    sc[0, 0] = y[3]
    sc[0, 1] = y[4]
    sc[0, 2] = y[5]
    sc[2, 0] = n0
    sc[2, 1] = n1
    sc[2, 2] = n2
    sc[3, 0] = v0
    sc[3, 1] = v1
    sc[3, 2] = v2
    forces3d_into(sc[0], g, s_t, sc[2], d_t, eta, sc[3], contact, p, fbuf)
    return s_t


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _rhs3d(t, y, g, u, contact, p, W, F, fh, out, fbuf, sc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    forces3d_at(t, y, g, contact, p, W, F, fh, fbuf, sc)
    m = p[I_MASS]
    out[0] = y[3]
    out[1] = y[4]
    out[2] = y[5]
    out[3] = fbuf[7, 0] / m + u[0]
    out[4] = fbuf[7, 1] / m + u[1]
    out[5] = fbuf[7, 2] / m + u[2]


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _contact3d(t, y, contact, p, W, F, fh):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    s_t = geometry3d(t, y[0], y[1], y[2], p, W, F, fh)[0]
    update_contact(contact, p[I_R] - s_t, p)


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def integrate3d(t0, t1, y, g, u, contact, p, W, F, fh, h, ig, stats, work, fbuf, sc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Integrate ``y`` (6,) in place from ``t0`` to ``t1`` (s) under ``g`` (3,) T/m and ``u`` (3,) m/s^2.

    ``ig`` (7,) ``[rk4 (0/1), rtol, atol_pos, atol_vel, min_step, max_step, fixed_step]``
    (:func:`~vesselbot_ros.control.high_gain_observer.integrator_vector`); ``h`` the proposed first step
    (dopri5); ``stats`` (4,) int64 += [accepted, rejected, rhs evaluations, forced steps]; ``work``, ``fbuf``,
    ``sc`` from :func:`new_workspace3d`.  The planar integrators' rules: error control, forced steps at the
    minimum step, FSAL unless the contact state changed, the codes.

    Returns:
        (code, h_next).
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
    if ig[0] > 0.5:  # fixed-step RK4
        n = max(1, int(math.ceil((t1 - t0) / ig[6] - 1e-9)))
        hh = (t1 - t0) / n
        for j in range(n):
            t = t0 + j * hh
            _rhs3d(t, y, g, u, contact, p, W, F, fh, k1, fbuf, sc)
            for i in range(6):
                yt[i] = y[i] + 0.5 * hh * k1[i]
            _rhs3d(t + 0.5 * hh, yt, g, u, contact, p, W, F, fh, k2, fbuf, sc)
            for i in range(6):
                yt[i] = y[i] + 0.5 * hh * k2[i]
            _rhs3d(t + 0.5 * hh, yt, g, u, contact, p, W, F, fh, k3, fbuf, sc)
            for i in range(6):
                yt[i] = y[i] + hh * k3[i]
            _rhs3d(t + hh, yt, g, u, contact, p, W, F, fh, k4, fbuf, sc)
            for i in range(6):
                y[i] = y[i] + hh / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
            _contact3d(t + hh, y, contact, p, W, F, fh)
            stats[0] += 1
            stats[2] += 4
        for i in range(6):
            if not math.isfinite(y[i]):
                return NON_FINITE, h
        return OK, h
    rtol = ig[1]
    h_min = ig[4]
    h_max = ig[5]
    t = t0
    h = min(max(h, h_min), h_max)
    _rhs3d(t, y, g, u, contact, p, W, F, fh, k1, fbuf, sc)
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
        for i in range(6):
            yt[i] = y[i] + hs * _A21 * k1[i]
        _rhs3d(t + _C2 * hs, yt, g, u, contact, p, W, F, fh, k2, fbuf, sc)
        for i in range(6):
            yt[i] = y[i] + hs * (_A31 * k1[i] + _A32 * k2[i])
        _rhs3d(t + _C3 * hs, yt, g, u, contact, p, W, F, fh, k3, fbuf, sc)
        for i in range(6):
            yt[i] = y[i] + hs * (_A41 * k1[i] + _A42 * k2[i] + _A43 * k3[i])
        _rhs3d(t + _C4 * hs, yt, g, u, contact, p, W, F, fh, k4, fbuf, sc)
        for i in range(6):
            yt[i] = y[i] + hs * (_A51 * k1[i] + _A52 * k2[i] + _A53 * k3[i] + _A54 * k4[i])
        _rhs3d(t + _C5 * hs, yt, g, u, contact, p, W, F, fh, k5, fbuf, sc)
        for i in range(6):
            yt[i] = y[i] + hs * (_A61 * k1[i] + _A62 * k2[i] + _A63 * k3[i] + _A64 * k4[i] + _A65 * k5[i])
        _rhs3d(t + hs, yt, g, u, contact, p, W, F, fh, k6, fbuf, sc)
        for i in range(6):
            yn[i] = y[i] + hs * (_B1 * k1[i] + _B3 * k3[i] + _B4 * k4[i] + _B5 * k5[i] + _B6 * k6[i])
        _rhs3d(t + hs, yn, g, u, contact, p, W, F, fh, k7, fbuf, sc)
        stats[2] += 6
        err = 0.0
        for i in range(6):
            e = hs * (_E1 * k1[i] + _E3 * k3[i] + _E4 * k4[i] + _E5 * k5[i] + _E6 * k6[i] + _E7 * k7[i])
            atol = ig[2] if i < 3 else ig[3]
            r = abs(e) / (atol + rtol * max(abs(y[i]), abs(yn[i])))
            if not (r <= err):  # also catches NaN
                err = r
        if not math.isfinite(err):
            err = 1e10
        forced = err > 1.0 and hs <= h_min * (1.0 + 1e-12)
        if forced:
            stats[3] += 1
        if err <= 1.0 or forced:
            ok = True
            for i in range(6):
                ok = ok and math.isfinite(yn[i])
            for i in range(6):
                y[i] = yn[i]
            if not ok:
                return NON_FINITE, h
            t = t1 if last else t + hs
            c0, c1, c2, c3 = contact[0], contact[1], contact[2], contact[3]
            _contact3d(t, y, contact, p, W, F, fh)
            stats[0] += 1
            if c0 == contact[0] and c1 == contact[1] and c2 == contact[2] and c3 == contact[3]:
                for i in range(6):  # FSAL
                    k1[i] = k7[i]
            else:
                _rhs3d(t, y, g, u, contact, p, W, F, fh, k1, fbuf, sc)
                stats[2] += 1
            fac = 5.0 if err == 0.0 else min(5.0, max(0.2, 0.9 * err ** -0.2))
            if not last or hs >= h:
                h = min(h_max, hs * fac)
        else:
            stats[1] += 1
            h = max(h_min, hs * max(0.2, 0.9 * err ** -0.2))
    for i in range(6):
        if not math.isfinite(y[i]):
            return NON_FINITE, h
    return OK, h
