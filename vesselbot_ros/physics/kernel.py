"""Fast numba kernel of the force model for the stiff plant integration.

Every formula comes from the jitable functions of the concept modules
(``drag``, ``blood_flow``, ``bifurcation``, ``wall_contact``,
``wall_interactions``, ``magnetic_force``); this module only composes them for
the straight vessel of Table III (see ``blood_flow`` for the geometry).

Flat parameter vector ``p`` (:func:`pack_params`), float64, indices below.  The
bifurcation table follows at ``I_TABLE``: K knots (deg), then the (K, 7) values
and the (K, 7) slopes, row-major.

``contact_arr``: float64 (4,) = [phase (0 free, 1 loading, 2 unloading),
delta_max (m), F_max (N), delta_0 (m)] for the nearest wall, updated in place by
:func:`update_contact` (the caller decides when: typically once per accepted
integrator step).  ``forces_into`` fills ``out`` (8, 2) with rows
``TERM_NAMES`` (N).  The kernel never raises and returns finite numbers for
every finite input (penetration is clamped to r, the vdW gap to g_min, the
diameter ratio below 1).
"""

from __future__ import annotations

import functools
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.errors import ConfigError
from vesselbot_ros.geometry.polyline_wall import grid_cell, nearest_wall
from vesselbot_ros.physics.apparent_weight import apparent_weight_z
from vesselbot_ros.physics.bifurcation import load_profile_table
from vesselbot_ros.physics.blood_flow import (
    blended_profile,
    parabolic_profile,
    pulse_factor,
    vessel_diameter,
    wall_deltas,
)
from vesselbot_ros.physics.blood_viscosity import viscosity_for
from vesselbot_ros.physics.drag import drag_gain, wall_factor
from vesselbot_ros.physics.magnetic_force import bead_pulling_force
from vesselbot_ros.physics.params import BOLTZMANN_J_PER_K, VACUUM_PERMITTIVITY_F_PER_M, PhysicsParams
from vesselbot_ros.physics.wall_contact import contact_force_magnitude, contact_transition, hertz_stiffness
from vesselbot_ros.physics.wall_interactions import (
    contact_heaviside_flag,
    electrostatic_factor,
    robot_charge,
    steric_coefficient,
    wall_pair_forces_z,
)

# numba's cache of this module (and of every module that inlines it) is dropped when any numba
# source changes: vesselbot_ros.numba_cache, run on package import.

__all__ = [
    "TERM_NAMES",
    "flow_scaled_into",
    "pack_params",
    "pack_network_params",
    "accel",
    "accel_no_motive",
    "forces_into",
    "update_contact",
    "nearest_wall_delta",
    "diameter_at",
    "wall_delta_xz",
    "fluid_velocity_x",
    "fluid_velocity_xz",
    "onto_lumen",
    "network_geometry",
    "time_terms",
    "time_terms_into",
    "forces_at",
    "forces_tc",
    "wall_delta_at",
]

TERM_NAMES = ("magnetic", "drag", "apparent_weight", "contact", "van_der_waals", "electrostatic", "steric", "total")

I_R = 0  # robot radius r (m)
I_VOLUME = 1  # V = 4/3 pi r^3 (m^3)
I_MASS = 2  # m = rho V (kg)
I_TAU = 3  # tau_m (-)
I_MAGNETIZATION = 4  # M (A/m)
I_RHO_F = 5  # blood density (kg/m^3)
I_ETA = 6  # blood viscosity at the nominal diameter (Pa s)
I_ALPHA0 = 7  # wall factor alpha0 (-)
I_LAMBDA0 = 8  # wall factor lambda0 (-)
I_DIAMETER = 9  # nominal D (m)
I_D_PULSE = 10  # relative diameter pulsation (-)
I_V_F = 11  # centreline velocity V_f (m/s)
I_A_F = 12  # pulsatility a_f (-)
I_OMEGA_F = 13  # omega_f (rad/s)
I_PHI_F = 14  # phi_f (rad)
I_WEIGHT_Z = 15  # apparent weight z component -V (rho - rho_f) g (N)
I_HERTZ_K = 16  # Hertz stiffness k (N/m^1.5)
I_UNLOAD_EXP = 17  # unloading exponent (-)
I_D0_RATIO = 18  # delta_0 / delta_max (-)
I_HAMAKER = 19  # A_h (J)
I_VDW_GMIN = 20  # vdW minimum separation (m)
I_CHARGE = 21  # q (C)
I_EPS_EPS0 = 22  # epsilon * epsilon_0 (F/m)
I_EL_FACTOR = 23  # 1 (paper printed) or 0.25 (image charge)
I_STERIC_COEF = 24  # 50 r L0 kB T tau^1.5 (N)
I_BRUSH_L0 = 25  # L0 (m)
I_HEAVISIDE = 26  # 1: interactions x H(-delta); 0: hold zero-gap value in contact
I_BIF_ON = 27  # 1 if a major bifurcation section exists
I_BIF_X0 = 28  # section start (m)
I_BIF_X1 = 29  # section end (m)
I_BIF_TH0 = 30  # theta at start (deg)
I_BIF_TH1 = 31  # theta at end (deg)
I_BIF_RAMP = 32  # blend ramp fraction (-)
I_BIF_NKNOTS = 33  # K
I_NET_ON = 34  # 1 if the vessel is a network (vessel.network): geometry and flow from the sampled CFD grid
I_NET_OFF = 35  # index of the network block (NET_HEAD entries, then 7 (nz, nx) grids in cfd.FIELD_NAMES order, the
# k wall segments (4 k: ax, az, bx, bz), the (nx-1)(nz-1)+1 cells' CSR offsets and their candidate segments)
I_TABLE = 36  # start of the table (3 K + ... entries)
N_FIXED = 36
NET_HEAD = 7  # network block head: x0, z0, h (m), nx, nz, k (wall segments), total candidates
_LAMBDA_MAX = 0.999


@functools.lru_cache(maxsize=64)
def pack_params(params: PhysicsParams) -> npt.NDArray[np.float64]:
    """Flatten ``params`` into the kernel's float64 vector (layout: ``I_*`` constants).

    Cached per (hashable, frozen) params; treat the result as read-only.  A network vessel
    (``vessel.network``) also needs its sampled CFD field, and packing never solves one: its vector
    comes from :func:`vesselbot_ros.vessels.cfd.packed_params` (the field shipped, cached or solved, once).

    Raises:
        ConfigError: ``params.vessel.network`` is set.
    """
    if params.vessel.network:
        raise ConfigError(f"vessel.network needs its CFD field, which pack_params never solves: pack with "
                          f"vesselbot_ros.vessels.cfd.packed_params, got network={params.vessel.network!r}")
    return pack_network_params(params, None)


def pack_network_params(params: PhysicsParams, fld: Any) -> npt.NDArray[np.float64]:
    """:func:`pack_params` with a network vessel's sampled CFD field ``fld`` packed in (``None``: no network).

    ``fld`` is a :class:`vesselbot_ros.vessels.cfd.NetworkField` (grid origin ``x0_m``, ``z0_m``, spacing
    ``h_m``, ``nx`` x ``nz`` nodes, ``data``, ``wall_segments``, ``cell_offsets``, ``cell_index``).  Not
    cached (the field is not hashable): :func:`vesselbot_ros.vessels.cfd.packed_params` caches per params.

    Raises:
        ConfigError: a field without ``vessel.network`` or a network without a field.
    """
    if (fld is not None) != bool(params.vessel.network):
        raise ConfigError(f"a CFD field goes with vessel.network and only with it, got network={params.vessel.network!r} "
                          f"and {'a' if fld is not None else 'no'} field")
    b, f, v, rb, w, it, dg = params.blood, params.flow, params.vessel, params.robot, params.wall, params.interactions, params.drag
    eta = viscosity_for(b, v.diameter_m)
    r = rb.radius_m
    q = robot_charge(r, rb.charge_C, rb.charge_scale)
    head = np.zeros(N_FIXED)
    head[I_R] = r
    head[I_VOLUME] = rb.volume_m3
    head[I_MASS] = rb.mass_kg
    head[I_TAU] = rb.magnetic_ratio
    head[I_MAGNETIZATION] = rb.magnetization_A_per_m
    head[I_RHO_F] = b.density_kg_per_m3
    head[I_ETA] = eta
    head[I_ALPHA0] = dg.alpha0
    head[I_LAMBDA0] = dg.lambda0
    head[I_DIAMETER] = v.diameter_m
    head[I_D_PULSE] = f.diameter_pulsation
    head[I_V_F] = f.inflow_velocity_m_per_s  # V_f times flow.inflow_fraction (1: V_f itself, bit for bit)
    head[I_A_F] = f.pulsatility
    head[I_OMEGA_F] = f.angular_frequency_rad_per_s
    head[I_PHI_F] = f.phase_rad
    head[I_WEIGHT_Z] = apparent_weight_z(rb.volume_m3, rb.density_kg_per_m3, b.density_kg_per_m3, v.gravity_m_per_s2)
    head[I_HERTZ_K] = hertz_stiffness(r, rb.young_modulus_Pa, rb.poisson_ratio, w.young_modulus_Pa, w.poisson_ratio)
    head[I_UNLOAD_EXP] = w.unloading_exponent
    head[I_D0_RATIO] = w.permanent_deformation_ratio
    head[I_HAMAKER] = it.hamaker_constant_J
    head[I_VDW_GMIN] = it.vdw_floor_m
    head[I_CHARGE] = q
    head[I_EPS_EPS0] = b.relative_permittivity * VACUUM_PERMITTIVITY_F_PER_M
    head[I_EL_FACTOR] = electrostatic_factor(it.electrostatic_model)
    head[I_STERIC_COEF] = steric_coefficient(r, it.brush_length_m, BOLTZMANN_J_PER_K * b.temperature_K, it.grafting_density_per_m2)
    head[I_BRUSH_L0] = it.brush_length_m
    head[I_HEAVISIDE] = contact_heaviside_flag(it.in_contact)
    bif = v.major_bifurcation
    tail = np.zeros(0)
    if bif.enabled:
        table = load_profile_table(bif.profile_table)
        head[I_BIF_ON] = 1.0
        head[I_BIF_X0], head[I_BIF_X1] = bif.x_start_m, bif.x_end_m
        head[I_BIF_TH0], head[I_BIF_TH1] = bif.theta_start_deg, bif.theta_end_deg
        head[I_BIF_RAMP] = bif.ramp_fraction
        head[I_BIF_NKNOTS] = table.knots_deg.size
        tail = np.concatenate([table.knots_deg, table.values.ravel(), table.slopes.ravel()])
    net_block = np.zeros(0)
    if fld is not None:
        head[I_NET_ON] = 1.0
        head[I_NET_OFF] = N_FIXED + tail.size
        net_block = np.concatenate([[fld.x0_m, fld.z0_m, fld.h_m, fld.nx, fld.nz, len(fld.wall_segments), fld.cell_index.size],
                                    fld.data.ravel(), fld.wall_segments.ravel(), fld.cell_offsets, fld.cell_index])
    out = np.concatenate([head, tail, net_block])
    out.setflags(write=False)
    return out


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def diameter_at(t, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """D(t) of the straight vessel (eq. (3)'s pulsation) from the packed parameters ``p`` (m)."""
    return vessel_diameter(t, p[I_DIAMETER], p[I_D_PULSE], p[I_OMEGA_F], p[I_PHI_F])


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _grid_cell(p, x, z):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The network grid's cell holding (x, z) (m): ``(base index, nx, cells per field, w00, w10, w01, w11)``.

    Bilinear weights; outside the grid the cell at the nearest grid edge, its weights clipped to [0, 1].
    """
    o = int(p[I_NET_OFF])
    x0 = p[o]
    z0 = p[o + 1]
    h = p[o + 2]
    nx = int(p[o + 3])
    nz = int(p[o + 4])
    fx = (x - x0) / h
    fz = (z - z0) / h
    i, j = grid_cell(fx, fz, nx, nz)
    tx = min(1.0, max(0.0, fx - i))
    tz = min(1.0, max(0.0, fz - j))
    return (o + NET_HEAD + j * nx + i, nx, nx * nz, (1.0 - tx) * (1.0 - tz), tx * (1.0 - tz), (1.0 - tx) * tz, tx * tz)


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _grid_value(p, cell, field):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Grid field ``field`` interpolated in ``cell`` (:func:`_grid_cell`)."""
    base, nx, n, w00, w10, w01, w11 = cell
    b = base + field * n
    return w00 * p[b] + w10 * p[b + 1] + w01 * p[b + nx] + w11 * p[b + nx + 1]


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _network_wall(p, x, z):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(s, nx, nz): exact signed distance (m, > 0 inside) and unit inward normal of the meshed wall at (x, z) (m).

    :func:`vesselbot_ros.geometry.polyline_wall.nearest_wall` over the packed wall segments and cell candidates.
    """
    o = int(p[I_NET_OFF])
    nx = int(p[o + 3])
    nz = int(p[o + 4])
    k = int(p[o + 5])
    n_idx = int(p[o + 6])
    segs = o + NET_HEAD + 7 * nx * nz
    offs = segs + 4 * k
    idx = offs + (nx - 1) * (nz - 1) + 1
    return nearest_wall(x, z, p[segs:offs], p[offs:idx], p[idx:idx + n_idx], p[o], p[o + 1], p[o + 2], nx, nz)


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def network_geometry(t, x, z, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(s_t, nx, nz, D_t, eta, vfx, vfz) of a network at (x, z) (m), time t (s).

    s_t: signed distance of the centre to the meshed wall (m, > 0 inside; exact, computed
    here from the wall's segments: geometry/polyline_wall.py) with the wall moved out by the
    diameter pulsation (13): s + D eps(t) / 2, D_t = D (1 + eps(t));
    (nx, nz): unit inward normal of the nearest wall (exact); D: local diameter and
    eta: viscosity (Pa s), bilinear on the grid; (vfx, vfz): blood velocity (m/s),
    eq. (12) on the steady CFD field, which dilates with the vessel: sampled at the point
    moved towards the centreline by the factor 1 / (1 + eps) (exactly p_p(z, D(t)) in a
    straight branch).  Allocates nothing (grid fields 5-6: D, eta; 0-1: velocity).
    """
    s, gx, gz = _network_wall(p, x, z)
    cell = _grid_cell(p, x, z)
    d = _grid_value(p, cell, 5)
    eta = _grid_value(p, cell, 6)
    eps = p[I_D_PULSE] * np.sin(p[I_OMEGA_F] * t + p[I_PHI_F])
    s_t = s + 0.5 * d * eps
    d_t = d * (1.0 + eps)
    shift = (0.5 * d - s) * (1.0 - 1.0 / (1.0 + eps))
    cell = _grid_cell(p, x + gx * shift, z + gz * shift)
    scale = p[I_V_F] * pulse_factor(t, p[I_A_F], p[I_OMEGA_F], p[I_PHI_F])
    return s_t, gx, gz, d_t, eta, scale * _grid_value(p, cell, 0), scale * _grid_value(p, cell, 1)


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def wall_delta_xz(t, x, z, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(delta (m), wall) of the nearest wall for a robot centred at (x, z).

    Straight vessel: :func:`nearest_wall_delta`.  Network: delta = r - s_t;
    wall = +1 if the nearest wall lies above the centre (inward normal down), else -1.
    """
    if p[I_NET_ON] > 0.5:
        s_t, _gx, gz, _d_t, _eta, _vx, _vz = network_geometry(t, x, z, p)
        return p[I_R] - s_t, (1.0 if gz <= 0.0 else -1.0)
    return nearest_wall_delta(t, z, p)


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def onto_lumen(t, x0, x1, z0, z1, p, gap):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """A robot closer to a wall than ``gap`` (m; 0: in it) put ``gap`` from it, its velocity into the wall removed:
    ``(x0, x1, z0, z1)``.

    The wall as a constraint, for estimators and predictions that step too
    coarsely for the stiff contact (a constrained filter's projection).
    """
    delta, wall = wall_delta_xz(t, x0, x1, p)
    delta = delta + gap
    if not delta > 0.0:
        return x0, x1, z0, z1
    if p[I_NET_ON] > 0.5:
        _s, nx, nz, _d, _eta, _vx, _vz = network_geometry(t, x0, x1, p)  # the wall's inward normal
    else:
        nx = 0.0
        nz = -wall  # the upper wall (+1) pushes down
    x0 = x0 + delta * nx
    x1 = x1 + delta * nz
    vn = z0 * nx + z1 * nz
    if vn < 0.0:
        z0 = z0 - vn * nx
        z1 = z1 - vn * nz
    return x0, x1, z0, z1


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def fluid_velocity_xz(t, x, z, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(v_fx, v_fz) blood velocity (m/s) at (x, z) (m), time t (s)."""
    if p[I_NET_ON] > 0.5:
        r = network_geometry(t, x, z, p)
        return r[5], r[6]
    return fluid_velocity_x(t, x, z, p), 0.0


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def time_terms(t, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The terms of the force model that depend on time only: ``(D(t) (m), pulse factor (-), wall factor f (-))``.

    ``D(t)`` of eq. (13), ``1 + a_f sin(omega_f t + phi_f)`` of eq. (12) and the
    drag's wall factor (10)-(11) at ``lambda = min(2 r / D(t), 0.999)``.
    """
    d_t = diameter_at(t, p)
    pulse = pulse_factor(t, p[I_A_F], p[I_OMEGA_F], p[I_PHI_F])
    lam = min(2.0 * p[I_R] / d_t, _LAMBDA_MAX)
    return d_t, pulse, wall_factor(lam, p[I_ALPHA0], p[I_LAMBDA0])


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def time_terms_into(t, p, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Fill ``tc`` (4,) = ``[t, *time_terms(t, p)]`` unless it already holds time ``t``.

    The memo of one integrator call: its stages revisit the same times (the
    last two stages and the contact update all sit at the step's end; the
    extended Kalman filter's Jacobian evaluates one time six times).  Whoever
    owns ``tc`` sets ``tc[0] = nan`` whenever ``p`` may have changed (every
    integrator call does), so a hit always means the same ``t`` and ``p``.
    """
    if tc[0] != t:
        d_t, pulse, wf = time_terms(t, p)
        tc[0] = t
        tc[1] = d_t
        tc[2] = pulse
        tc[3] = wf


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _flow_x(x, z, d_t, pulse, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if p[I_BIF_ON] > 0.5:
        nk = int(p[I_BIF_NKNOTS])
        i0 = I_TABLE
        knots = p[i0:i0 + nk]
        values = p[i0 + nk:i0 + 8 * nk]
        slopes = p[i0 + 8 * nk:i0 + 15 * nk]
        prof = blended_profile(x, z, d_t, p[I_BIF_X0], p[I_BIF_X1], p[I_BIF_TH0], p[I_BIF_TH1], p[I_BIF_RAMP], knots, values, slopes)
    else:
        prof = parabolic_profile(z, d_t)
    return p[I_V_F] * pulse * prof


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def fluid_velocity_x(t, x, z, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Blood velocity v_f along +x (m/s) at (x, z) (m), time t (s)."""
    if p[I_NET_ON] > 0.5:
        return network_geometry(t, x, z, p)[5]
    return _flow_x(x, z, diameter_at(t, p), pulse_factor(t, p[I_A_F], p[I_OMEGA_F], p[I_PHI_F]), p)


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def wall_delta_at(z, d_t, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(delta (m), wall (+1 upper / -1 lower)) of the nearest wall for a robot centred at z, vessel diameter d_t.

    Straight vessel only; a network's wall: :func:`wall_delta_xz`.
    """
    d_up, d_lo = wall_deltas(z, p[I_R], d_t)
    if d_up >= d_lo:
        return d_up, 1.0
    return d_lo, -1.0


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def nearest_wall_delta(t, z, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(delta (m), wall (+1 upper / -1 lower)) of the nearest wall for a robot centred at z."""
    return wall_delta_at(z, diameter_at(t, p), p)


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def forces_at(x, z, vx, vz, gx, gz, contact_arr, p, out, d_t, pulse, wf):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`forces_into` of a straight vessel with the time-only terms given (``time_terms``): the same doubles.

    Not for a network (``p[I_NET_ON]``): use :func:`forces_into` / :func:`forces_tc`, which dispatch.
    """
    r = p[I_R]
    # magnetic (2)
    out[0, 0] = bead_pulling_force(p[I_TAU], p[I_VOLUME], p[I_MAGNETIZATION], gx)
    out[0, 1] = bead_pulling_force(p[I_TAU], p[I_VOLUME], p[I_MAGNETIZATION], gz)
    # drag (11)
    ux = vx - _flow_x(x, z, d_t, pulse, p)
    uz = vz
    c = drag_gain(np.sqrt(ux * ux + uz * uz), r, p[I_ETA], p[I_RHO_F], wf)
    out[1, 0] = -c * ux
    out[1, 1] = -c * uz
    # apparent weight (14)
    out[2, 0] = 0.0
    out[2, 1] = p[I_WEIGHT_Z]
    # contact (15)-(16), nearest wall, along -n
    d_up, d_lo = wall_deltas(z, r, d_t)
    d_up = min(d_up, r)
    d_lo = min(d_lo, r)
    if d_up >= d_lo:
        delta, wall = d_up, 1.0
    else:
        delta, wall = d_lo, -1.0
    fc = contact_force_magnitude(delta, contact_arr[0], contact_arr[1], contact_arr[2], contact_arr[3], p[I_HERTZ_K], p[I_UNLOAD_EXP])
    out[3, 0] = 0.0
    out[3, 1] = -wall * fc
    # interactions (18), (19), (22), both walls
    vdw, el, st = wall_pair_forces_z(d_up, d_lo, r, p[I_HAMAKER], p[I_VDW_GMIN], p[I_CHARGE], p[I_EPS_EPS0],
                                     p[I_EL_FACTOR], p[I_STERIC_COEF], p[I_BRUSH_L0], p[I_HEAVISIDE])
    out[4, 0] = 0.0
    out[4, 1] = vdw
    out[5, 0] = 0.0
    out[5, 1] = el
    out[6, 0] = 0.0
    out[6, 1] = st
    out[7, 0] = out[0, 0] + out[1, 0] + out[2, 0] + out[3, 0] + out[4, 0] + out[5, 0] + out[6, 0]
    out[7, 1] = out[0, 1] + out[1, 1] + out[2, 1] + out[3, 1] + out[4, 1] + out[5, 1] + out[6, 1]


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def forces_into(t, x, z, vx, vz, gx, gz, contact_arr, p, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Fill ``out`` (8, 2) with the force terms (N) in ``TERM_NAMES`` order.

    Args: t (s); x, z (m); vx, vz (m/s); gx, gz gradient (T/m); contact_arr (4,);
    p packed params; out (8, 2) float64, overwritten.
    """
    if p[I_NET_ON] > 0.5:
        _forces_network(t, x, z, vx, vz, gx, gz, contact_arr, p, out)
        return
    d_t, pulse, wf = time_terms(t, p)
    forces_at(x, z, vx, vz, gx, gz, contact_arr, p, out, d_t, pulse, wf)


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def forces_tc(t, x, z, vx, vz, gx, gz, contact_arr, p, out, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`forces_into` with the time-only terms memoised in ``tc`` (:func:`time_terms_into`): the same doubles.

    A network (``p[I_NET_ON]``) takes its time-dependent terms from the grid at (x, z), not from the
    straight vessel's D(t) and wall factor: it goes to :func:`forces_into`'s network path, unmemoised.
    """
    if p[I_NET_ON] > 0.5:
        _forces_network(t, x, z, vx, vz, gx, gz, contact_arr, p, out)
        return
    time_terms_into(t, p, tc)
    forces_at(x, z, vx, vz, gx, gz, contact_arr, p, out, tc[1], tc[2], tc[3])


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _forces_network(t, x, z, vx, vz, gx, gz, contact_arr, p, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`forces_into` in a planar vessel network: :func:`wall_forces_into` at the wall and flow of the
    network's grid at (x, z) (:func:`network_geometry`)."""
    s_t, nx, nz, d_t, eta, vfx, vfz = network_geometry(t, x, z, p)
    wall_forces_into((vx, vz), (gx, gz), s_t, (nx, nz), d_t, eta, (vfx, vfz), contact_arr, p, out)


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def wall_forces_into(v, g, s_t, n, d_t, eta, vf, contact_arr, p, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Fill ``out`` (8, d) with the force terms (N) on d axes, every one from the local wall and flow.

    The axes are ``len(n)``: (x, z) in the plane, (x, y, z) in space, the last the vertical; a planar
    scene on three axes with y = 0 gives the plane's doubles in x and z and exactly 0 in y (tested).
    Magnetic (2) per gradient axis; drag (11) on ``v - vf`` with the wall factor of the local diameter
    ``d_t``; apparent weight (14) along the vertical; contact (15)-(16) against the nearest wall along
    its inward normal ``n`` (overlap ``r - s_t``); vdW (18), electrostatic (19) and steric (22) forces
    of the nearest wall (gap ``s_t - r``) and of the opposite one (gap ``d_t - s_t - r``) along ``-n``.

    Args:
        v, g, n, vf: The bead's velocity (m/s), the gradient (T/m), the unit inward normal and the blood
            velocity at the bead (m/s), each d values (tuples or arrays).
        s_t: Signed distance of the bead's centre to the nearest wall (m, > 0 inside).
        d_t: Local lumen diameter (m).
        eta: Blood viscosity there (Pa s).
        contact_arr: (4,) the Hertz loading/unloading state.
        p: Packed physical parameters (:func:`pack_params`).
        out: (8, d) float64, overwritten.
    """
    d = len(n)
    r = p[I_R]
    uu = 0.0
    for i in range(d):
        out[0, i] = bead_pulling_force(p[I_TAU], p[I_VOLUME], p[I_MAGNETIZATION], g[i])
        u = v[i] - vf[i]
        uu += u * u
    lam = min(2.0 * r / max(d_t, 2.0 * r), _LAMBDA_MAX)
    c = drag_gain(np.sqrt(uu), r, eta, p[I_RHO_F], wall_factor(lam, p[I_ALPHA0], p[I_LAMBDA0]))
    for i in range(d):
        out[1, i] = -c * (v[i] - vf[i])
        out[2, i] = 0.0
    out[2, d - 1] = p[I_WEIGHT_Z]
    d_near = min(r - s_t, r)
    d_far = min(r - (d_t - s_t), r)
    fc = contact_force_magnitude(d_near, contact_arr[0], contact_arr[1], contact_arr[2], contact_arr[3], p[I_HERTZ_K], p[I_UNLOAD_EXP])
    # wall_pair_forces_z's "+" is towards its first wall: here the nearest one, direction -n
    vdw, el, st = wall_pair_forces_z(d_near, d_far, r, p[I_HAMAKER], p[I_VDW_GMIN], p[I_CHARGE], p[I_EPS_EPS0],
                                     p[I_EL_FACTOR], p[I_STERIC_COEF], p[I_BRUSH_L0], p[I_HEAVISIDE])
    for i in range(d):
        out[3, i] = fc * n[i]
        out[4, i] = -vdw * n[i]
        out[5, i] = -el * n[i]
        out[6, i] = -st * n[i]
        out[7, i] = out[0, i] + out[1, i] + out[2, i] + out[3, i] + out[4, i] + out[5, i] + out[6, i]


@numba.njit(cache=True)
def accel(t, x, z, vx, vz, gx, gz, contact_arr, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(ax, az) (m/s^2): total force including the magnetic term, divided by m = rho V."""
    out = np.empty((8, 2))
    forces_into(t, x, z, vx, vz, gx, gz, contact_arr, p, out)
    return out[7, 0] / p[I_MASS], out[7, 1] / p[I_MASS]


@numba.njit(cache=True, nogil=True)
def flow_scaled_into(p, s, p_s):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Copy the packed parameters ``p`` into ``p_s`` (at least as long) with the centreline blood velocity ``V_f``
    times ``s``: a model that believes another blood velocity (an estimate of the flow scale).

    A network's sampled CFD block (``p[I_NET_OFF]:``, megabytes: the field is normalised, ``V_f`` scales it where
    it is read) is the same in both and is copied only when ``p_s`` does not hold it yet (its offset or its last
    entry differ: a fresh ``p_s``); the scalars and the bifurcation table before it are copied on every call.
    Copying the whole block on every force evaluation made the flow-scale estimators 450x slower in a network.
    """
    n = p.shape[0]
    head = n
    if p[I_NET_ON] > 0.5:
        o = int(p[I_NET_OFF])
        if p_s[I_NET_OFF] == p[I_NET_OFF] and p_s[n - 1] == p[n - 1] and p_s[o] == p[o]:
            head = o
    for i in range(head):
        p_s[i] = p[i]
    p_s[I_V_F] = p[I_V_F] * s


@numba.njit(cache=True)
def accel_no_motive(t, x, z, vx, vz, contact_arr, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """F(X, Z) of eq. (23): (total force without the magnetic term) / m (m/s^2)."""
    return accel(t, x, z, vx, vz, 0.0, 0.0, contact_arr, p)


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def update_contact(contact_arr, delta, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Advance the loading/unloading state in place after observing ``delta`` (m)."""
    ph, dm, fm, d0 = contact_transition(contact_arr[0], contact_arr[1], contact_arr[2], contact_arr[3],
                                        min(delta, p[I_R]), p[I_HERTZ_K], p[I_D0_RATIO])
    contact_arr[0] = ph
    contact_arr[1] = dm
    contact_arr[2] = fm
    contact_arr[3] = d0
