"""The plant's forces in three dimensions, from the local wall geometry and flow (the 3-D vessel trees' plant).

The planar kernel (:mod:`vesselbot_ros.physics.kernel`) works in the paper's
XZ plane.  In a 3-D vessel tree the same terms act along 3-vectors: the bead's
state is ``(x, y, z)``, the gradient has three axes, gravity acts along the
scanner's vertical ``-z`` and every wall term acts along the inward normal of
the nearest wall, a 3-vector.  The terms are the planar network's
(:func:`vesselbot_ros.physics.kernel._forces_network`) written for 3-vectors,
in the same operation order, so a point, a velocity, a gradient and a wall
with ``y = 0`` give the planar network's doubles in x and z and exactly 0 in y
(test: ``test/unit/physics/test_kernel3d.py``):

* magnetic (2): each gradient axis ``tau V M G_i``;
* drag (11) with the wall factor of the local diameter ``D_t``:
  ``-c(|u|) u``, ``u = v - v_f`` (``v_f`` the blood velocity at the bead);
* apparent weight (14) along ``z``;
* contact (15)-(16) along the inward normal ``n`` of the nearest wall,
  overlap ``r - s_t`` (``s_t`` the signed distance of the centre, > 0 inside);
* vdW (18), electrostatic (19) and steric (22) forces of the nearest wall
  (gap ``s_t - r``) and of the opposite one across the local diameter
  (gap ``D_t - s_t - r``), along ``-n`` towards the nearest.

The geometry (``s_t``, ``n``, ``D_t``, viscosity, ``v_f``) is an input: the
3-D wall and flow lookups answer it.
"""

from __future__ import annotations

import numba
import numpy as np

from vesselbot_ros.physics.drag import drag_gain, wall_factor
from vesselbot_ros.physics.kernel import (
    _LAMBDA_MAX,
    I_ALPHA0,
    I_BRUSH_L0,
    I_CHARGE,
    I_EL_FACTOR,
    I_EPS_EPS0,
    I_HAMAKER,
    I_HEAVISIDE,
    I_HERTZ_K,
    I_LAMBDA0,
    I_MAGNETIZATION,
    I_MASS,
    I_R,
    I_RHO_F,
    I_STERIC_COEF,
    I_TAU,
    I_UNLOAD_EXP,
    I_VDW_GMIN,
    I_VOLUME,
    I_WEIGHT_Z,
)
from vesselbot_ros.physics.magnetic_force import bead_pulling_force
from vesselbot_ros.physics.wall_contact import contact_force_magnitude
from vesselbot_ros.physics.wall_interactions import wall_pair_forces_z

__all__ = ["forces3d_into", "accel3d"]


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def forces3d_into(v, g, s_t, n, d_t, eta, vf, contact_arr, p, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Fill ``out`` (8, 3) with the force terms (N) in :data:`~vesselbot_ros.physics.kernel.TERM_NAMES` order.

    Args:
        v: (3,) the bead's velocity (m/s).
        g: (3,) the applied gradient (T/m), one per axis.
        s_t: Signed distance of the bead's centre to the nearest wall at time t (m, > 0 inside).
        n: (3,) unit inward normal of the nearest wall.
        d_t: Local lumen diameter at time t (m).
        eta: Blood viscosity there (Pa s).
        vf: (3,) blood velocity at the bead (m/s).
        contact_arr: (4,) the Hertz loading/unloading state.
        p: Packed physical parameters (:func:`vesselbot_ros.physics.kernel.pack_params`).
        out: (8, 3) float64, overwritten.
    """
    r = p[I_R]
    for i in range(3):
        out[0, i] = bead_pulling_force(p[I_TAU], p[I_VOLUME], p[I_MAGNETIZATION], g[i])
    ux = v[0] - vf[0]
    uy = v[1] - vf[1]
    uz = v[2] - vf[2]
    lam = min(2.0 * r / max(d_t, 2.0 * r), _LAMBDA_MAX)
    c = drag_gain(np.sqrt(ux * ux + uy * uy + uz * uz), r, eta, p[I_RHO_F], wall_factor(lam, p[I_ALPHA0], p[I_LAMBDA0]))
    out[1, 0] = -c * ux
    out[1, 1] = -c * uy
    out[1, 2] = -c * uz
    out[2, 0] = 0.0
    out[2, 1] = 0.0
    out[2, 2] = p[I_WEIGHT_Z]
    d_near = min(r - s_t, r)
    d_far = min(r - (d_t - s_t), r)
    fc = contact_force_magnitude(d_near, contact_arr[0], contact_arr[1], contact_arr[2], contact_arr[3], p[I_HERTZ_K],
                                 p[I_UNLOAD_EXP])
    # wall_pair_forces_z's "+" is towards its first wall: here the nearest one, direction -n
    vdw, el, st = wall_pair_forces_z(d_near, d_far, r, p[I_HAMAKER], p[I_VDW_GMIN], p[I_CHARGE], p[I_EPS_EPS0],
                                     p[I_EL_FACTOR], p[I_STERIC_COEF], p[I_BRUSH_L0], p[I_HEAVISIDE])
    for i in range(3):
        out[3, i] = fc * n[i]
        out[4, i] = -vdw * n[i]
        out[5, i] = -el * n[i]
        out[6, i] = -st * n[i]
        out[7, i] = out[0, i] + out[1, i] + out[2, i] + out[3, i] + out[4, i] + out[5, i] + out[6, i]


@numba.njit(cache=True)
def accel3d(v, g, s_t, n, d_t, eta, vf, contact_arr, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(3,) the bead's acceleration (m/s^2): the total force of :func:`forces3d_into` over m = rho V."""
    out = np.empty((8, 3))
    forces3d_into(v, g, s_t, n, d_t, eta, vf, contact_arr, p, out)
    return out[7] / p[I_MASS]
