"""A vessel tree in space, its side of the integrator's geometry edge: the compiled geometry, forces and right-hand side.

State ``y = (x, y, z, vx, vy, vz)`` (m, m/s), input the gradient ``G`` (3,) (T/m) held over a control period
plus an optional constant acceleration ``u`` (3,) (m/s^2): the plant passes ``G`` and ``u = 0``, the
observer's model ``G = 0`` and ``u = B G``; the one integrator of :mod:`vesselbot_ros.physics.integrator` steps it
(that module's docstring says why adaptive and what the codes mean).

Geometry and flow at a point (:func:`tree_geometry`), from the tree's samples
(:mod:`vesselbot_ros.vessels.tree_field`):

* the wall: signed distance ``s`` (> 0 in the lumen), unit inward normal ``n`` and local diameter ``D`` of the
  meshed wall (:func:`~vesselbot_ros.geometry.field_lookup.wall_field3d`: the grid, exact where it cannot
  answer), moved out by the diameter pulsation (13) as in the planar network
  (:func:`~vesselbot_ros.physics.kernel.network_geometry`): ``s_t = s + D eps(t) / 2``, ``D_t = D (1 + eps)``;
* the blood: the steady 3-D velocity (trilinear on the grid, per unit inlet centreline velocity) sampled at the
  point moved towards the centreline by ``(D / 2 - s) (1 - 1 / (1 + eps))`` along ``n`` (the field dilates
  with the vessel), times ``V_f`` and the pulse (12); the viscosity (Pries at the node's diameter) at the point.

Forces: :func:`~vesselbot_ros.physics.kernel.wall_forces_into` on three axes (the planar network's terms).
The contact state advances after every accepted step with ``delta = r - s_t``.

Arguments that describe the tree: ``W``, the wall lookup's nine arrays (``wall_field3d(x, y, z, *W)``), ``F``
(nz, ny, nx, 4) ``(vx, vy, vz, eta)`` (float32 or float64) per node and ``fh`` (7,) ``(x0, y0, z0, h, nx, ny, nz)``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from vesselbot_ros.geometry.field_lookup import corner_weight, wall_field3d
from vesselbot_ros.physics.blood_flow import pulse_factor
from vesselbot_ros.physics.kernel import (
    I_A_F,
    I_D_PULSE,
    I_MASS,
    I_OMEGA_F,
    I_PHI_F,
    I_R,
    I_V_F,
    update_contact,
    wall_forces_into,
)

__all__ = ["tree_geometry", "tree_forces_at", "tree_rhs_into", "tree_contact_update", "FLOW_CHANNELS"]

#: Channels per node of the flow grid ``F``: velocity (3) per unit inlet centreline velocity, viscosity (Pa s).
FLOW_CHANNELS = 4


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
def tree_geometry(t, x, y, z, p, W, F, fh):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
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
def tree_forces_at(t, y, g, contact, p, W, F, fh, fbuf):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Fill ``fbuf`` (8, 3) with the force terms (N) on the bead of state ``y`` (6,) under the gradient ``g`` (3,);
    returns ``(s_t, n_z)``: the signed distance (m) and the vertical component of the nearest wall's inward normal."""
    s_t, n0, n1, n2, d_t, eta, v0, v1, v2 = tree_geometry(t, y[0], y[1], y[2], p, W, F, fh)
    wall_forces_into((y[3], y[4], y[5]), g, s_t, (n0, n1, n2), d_t, eta, (v0, v1, v2), contact, p, fbuf)
    return s_t, n2


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def tree_rhs_into(t, y, g, u, contact, p, W, F, fh, out, fbuf):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    tree_forces_at(t, y, g, contact, p, W, F, fh, fbuf)
    m = p[I_MASS]
    out[0] = y[3]
    out[1] = y[4]
    out[2] = y[5]
    out[3] = fbuf[7, 0] / m + u[0]
    out[4] = fbuf[7, 1] / m + u[1]
    out[5] = fbuf[7, 2] / m + u[2]


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def tree_contact_update(t, y, contact, p, W, F, fh):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    s_t = tree_geometry(t, y[0], y[1], y[2], p, W, F, fh)[0]
    update_contact(contact, p[I_R] - s_t, p)
