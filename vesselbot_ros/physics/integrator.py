"""The compiled integrator of ``Xd = Z, Zd = a(t, X, Z; G) + u`` over one control period, on any number of axes.

One integrator for every vessel: the plane's (a straight vessel or a planar network, state ``(x, z, vx, vz)``) and a
3-D tree's (state ``(x, y, z, vx, vy, vz)``); the vessel's right-hand side is chosen by the type of the ``geom``
argument at compile time (:func:`rhs_into`, the geometry's edge).

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
import numpy.typing as npt
from numba import types
from numba.extending import overload

from vesselbot_ros.config import ConfigError, check_choice, check_positive
from vesselbot_ros.physics.kernel import (
    I_MASS,
    I_NET_ON,
    I_R,
    diameter_at,
    fluid_velocity_xz,
    forces_into,
    forces_tc,
    network_geometry,
    onto_lumen,
    time_terms_into,
    update_contact,
    wall_delta_at,
    wall_delta_xz,
)
from vesselbot_ros.physics.tree_vessel import tree_contact_update, tree_forces_at, tree_geometry, tree_rhs_into

__all__ = [
    "IntegratorParams",
    "Workspace",
    "new_workspace",
    "integrator_vector",
    "IntegratorHolder",
    "integrate",
    "rhs_into",
    "axes_of",
    "wall_and_forces",
    "forces_at",
    "forces_memo",
    "wall_press",
    "onto_lumen_at",
    "jacobian_position_step",
    "rests_on_lower_wall",
    "carried_into",
    "blood_velocity_into",
    "blood_velocity",
    "wall_offset_into",
    "wall_offsets",
    "wall_frame_into",
    "wall_normal_into",
    "wall_frames",
    "floor_offsets",
    "params_of",
    "mass_of",
    "with_params",
    "plant_output",
    "G_ROW",
    "U_ROW",
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

#: Scratch arrays of one integrator on ``d`` axes: ``(work (12, 2 d), fbuf (8, d), sc (4, d))`` float64.  ``work``
#: rows 0-8 are the stages, row 9 the memo of the planar force model's time-only terms
#: (:func:`~vesselbot_ros.physics.kernel.time_terms_into`), rows 10 and 11 room for a caller's gradient and extra
#: acceleration (``g``, ``u``); ``sc`` is the 3-D force kernel's scratch.
Workspace = tuple[np.ndarray, np.ndarray, np.ndarray]
#: Row of ``work`` holding the time-only terms ``[t, D(t), pulse factor, wall factor]``.
TIME_TERMS_ROW = 9
#: Rows of ``work`` a caller may use for the gradient and the extra acceleration it passes.
G_ROW, U_ROW = 10, 11


def integrator_vector(ig: IntegratorParams) -> npt.NDArray[np.float64]:
    """(7,) ``[rk4 (0/1), rtol, atol_pos, atol_vel, min_step, max_step, fixed_step]``: :func:`integrate`'s ``ig``."""
    return np.array([1.0 if ig.method == "rk4" else 0.0, ig.rtol, ig.atol_position_m, ig.atol_velocity_m_per_s,
                     ig.min_step_s, ig.max_step_s, ig.fixed_step_s])


class IntegratorHolder:
    """A stage that integrates (a plant, a model): its ``integrator`` settings and their packed vector ``_ig``,
    set together; new settings take effect from the next step."""

    _integrator: IntegratorParams
    _ig: npt.NDArray[np.float64]

    @property
    def integrator(self) -> IntegratorParams:
        """Integrator settings; setting them takes effect from the next step."""
        return self._integrator

    @integrator.setter
    def integrator(self, value: IntegratorParams) -> None:
        self._integrator = value
        self._ig = integrator_vector(value)


@numba.njit(cache=True)
def new_workspace(dims=2):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(work, fbuf, sc)``: the scratch arrays :func:`integrate` and the force kernels write into (:data:`Workspace`)."""
    work = np.zeros((12, 2 * dims))
    work[TIME_TERMS_ROW, 0] = np.nan
    return work, np.empty((8, dims)), np.zeros((4, dims))


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


# ---- the geometry's edge: the vessel a bead flies in -------------------------------------------------------------
# ``geom`` is the plane's packed parameters ``p`` (a straight vessel or a planar network: the planar force kernel,
# state (x, z, vx, vz)) or a 3-D tree's ``(p, W, F, fh)`` (the 3-D force kernel, state (x, y, z, vx, vy, vz)).  The
# overloads below are the only places the loop's stages tell them apart, by the argument's type at compile time.
def rhs_into(t, y, g, u, contact, geom, out, fbuf, sc, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``out = (Z, a(t, X, Z; g) + u)`` of the bead in ``geom`` (compiled code only)."""
    raise NotImplementedError("rhs_into runs in compiled code only")


def contact_after_step(t, y, contact, geom, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Advance the contact state after an accepted step, with the nearest wall's ``delta`` (compiled code only)."""
    raise NotImplementedError("contact_after_step runs in compiled code only")


def _planar_rhs(t, y, g, u, contact, geom, out, fbuf, sc, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    # the kernel's accel() without its (8, 2) scratch, time-only terms memoised in tc: same operations, same doubles
    forces_tc(t, y[0], y[1], y[2], y[3], g[0], g[1], contact, geom, fbuf, tc)
    out[0] = y[2]
    out[1] = y[3]
    out[2] = fbuf[7, 0] / geom[I_MASS] + u[0]
    out[3] = fbuf[7, 1] / geom[I_MASS] + u[1]


def _tree_rhs(t, y, g, u, contact, geom, out, fbuf, sc, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    tree_rhs_into(t, y, g, u, contact, geom[0], geom[1], geom[2], geom[3], out, fbuf)


def _planar_contact(t, y, contact, geom, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if geom[I_NET_ON] > 0.5:  # a network's wall comes from the grid at (x, z), not from D(t)
        delta, _wall = wall_delta_xz(t, y[0], y[1], geom)
    else:
        time_terms_into(t, geom, tc)
        delta, _wall = wall_delta_at(y[1], tc[1], geom)
    update_contact(contact, delta, geom)


def _tree_contact(t, y, contact, geom, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    tree_contact_update(t, y, contact, geom[0], geom[1], geom[2], geom[3])


def axes_of(geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The axis count d of ``geom``, a literal at compile time (so the loops over axes unroll)."""
    raise NotImplementedError("axes_of runs in compiled code only")


@overload(axes_of, inline="always")
def _axes_of(geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if isinstance(geom, types.Array):
        return lambda geom: 2
    return lambda geom: 3


def wall_and_forces(t, y, g, contact, geom, fbuf, sc, with_forces):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(delta, wall)`` of the bead of state ``y`` in ``geom``: its signed penetration of the nearest wall (m, > 0 in
    contact) and which wall (+1 above the centre, -1 below); the force terms (8, d) under ``g`` in ``fbuf`` if
    ``with_forces`` (a tree's kernel computes them anyway).  Compiled code only."""
    raise NotImplementedError("wall_and_forces runs in compiled code only")


def _planar_wall(t, y, g, contact, geom, fbuf, sc, with_forces):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    delta, wall = wall_delta_xz(t, y[0], y[1], geom)
    if with_forces:
        forces_into(t, y[0], y[1], y[2], y[3], g[0], g[1], contact, geom, fbuf)
    return delta, wall


def _tree_wall(t, y, g, contact, geom, fbuf, sc, with_forces):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    p = geom[0]
    s_t, n_z = tree_forces_at(t, y, g, contact, p, geom[1], geom[2], geom[3], fbuf)
    return p[I_R] - s_t, (1.0 if n_z <= 0.0 else -1.0)  # the wall above when its inward normal points down


@overload(wall_and_forces, jit_options={"nogil": True, "_nrt": False})  # type: ignore[typeddict-unknown-key]  # _nrt: as above
def _wall_and_forces(t, y, g, contact, geom, fbuf, sc, with_forces):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    return _planar_wall if isinstance(geom, types.Array) else _tree_wall


def forces_at(t, y, g, contact, geom, fbuf, sc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The force terms (8, d) on the bead of state ``y`` (2 d,) under the gradient ``g`` (d,) in ``fbuf``: the
    models' ``F`` (row 7 is the sum); compiled code only."""
    raise NotImplementedError("forces_at runs in compiled code only")


def _planar_forces(t, y, g, contact, geom, fbuf, sc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    forces_into(t, y[0], y[1], y[2], y[3], g[0], g[1], contact, geom, fbuf)


def _tree_forces(t, y, g, contact, geom, fbuf, sc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    tree_forces_at(t, y, g, contact, geom[0], geom[1], geom[2], geom[3], fbuf)


@overload(forces_at, inline="always")
def _forces_at(t, y, g, contact, geom, fbuf, sc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    return _planar_forces if isinstance(geom, types.Array) else _tree_forces


def forces_memo(t, y, g, contact, geom, fbuf, sc, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`forces_at` with the planar force model's time-only terms memoised in ``tc``
    (:func:`~vesselbot_ros.physics.kernel.forces_tc`: the same doubles); a tree's kernel has none to keep."""
    raise NotImplementedError("forces_memo runs in compiled code only")


def _planar_forces_memo(t, y, g, contact, geom, fbuf, sc, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    forces_tc(t, y[0], y[1], y[2], y[3], g[0], g[1], contact, geom, fbuf, tc)


def _tree_forces_memo(t, y, g, contact, geom, fbuf, sc, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    tree_forces_at(t, y, g, contact, geom[0], geom[1], geom[2], geom[3], fbuf)


@overload(forces_memo, inline="always")
def _forces_memo(t, y, g, contact, geom, fbuf, sc, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    return _planar_forces_memo if isinstance(geom, types.Array) else _tree_forces_memo


def wall_press(t, y, u, geom, fbuf, zone_radii):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Whether a bead at ``y`` rests on the nearest wall: within ``zone_radii`` bead radii of it, and the drag, the
    apparent weight and the image charge (``fbuf``'s rows 1, 2 and 5, over the mass) plus ``u`` press it there
    (compiled code only)."""
    raise NotImplementedError("wall_press runs in compiled code only")


def _planar_press(t, y, u, geom, fbuf, zone_radii):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    delta, wall = wall_delta_xz(t, y[0], y[1], geom)
    if not delta > -zone_radii * geom[I_R]:
        return False
    return wall * ((fbuf[1, 1] + fbuf[2, 1] + fbuf[5, 1]) / geom[I_MASS] + u[1]) > 0.0


def _tree_press(t, y, u, geom, fbuf, zone_radii):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    p = geom[0]
    s_t, n0, n1, n2, _d, _eta, _v0, _v1, _v2 = tree_geometry(t, y[0], y[1], y[2], p, geom[1], geom[2], geom[3])
    if not p[I_R] - s_t > -zone_radii * p[I_R]:
        return False
    m = p[I_MASS]
    push = (n0 * ((fbuf[1, 0] + fbuf[2, 0] + fbuf[5, 0]) / m + u[0]) + n1 * ((fbuf[1, 1] + fbuf[2, 1] + fbuf[5, 1]) / m + u[1])
            + n2 * ((fbuf[1, 2] + fbuf[2, 2] + fbuf[5, 2]) / m + u[2]))
    return push < 0.0  # against the inward normal: into the wall


@overload(wall_press, jit_options={"nogil": True})
def _wall_press(t, y, u, geom, fbuf, zone_radii):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    return _planar_press if isinstance(geom, types.Array) else _tree_press


def onto_lumen_at(t, y, geom, gap):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """A bead of state ``y`` (2 d,) closer to a wall than ``gap`` (m) put ``gap`` from it along the wall's inward
    normal, its velocity into the wall removed, in place; whether it moved (compiled code only).  The wall as a
    constraint, for estimators that step too coarsely for the stiff contact."""
    raise NotImplementedError("onto_lumen_at runs in compiled code only")


def _planar_onto(t, y, geom, gap):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    x0, x1, z0, z1 = onto_lumen(t, y[0], y[1], y[2], y[3], geom, gap)
    moved = x0 != y[0] or x1 != y[1]
    y[0], y[1], y[2], y[3] = x0, x1, z0, z1
    return moved


def _tree_onto(t, y, geom, gap):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    p = geom[0]
    s_t, n0, n1, n2, _d, _eta, _v0, _v1, _v2 = tree_geometry(t, y[0], y[1], y[2], p, geom[1], geom[2], geom[3])
    delta = p[I_R] - s_t + gap
    if not delta > 0.0:
        return False
    y[0] = y[0] + delta * n0
    y[1] = y[1] + delta * n1
    y[2] = y[2] + delta * n2
    vn = y[3] * n0 + y[4] * n1 + y[5] * n2
    if vn < 0.0:
        y[3] = y[3] - vn * n0
        y[4] = y[4] - vn * n1
        y[5] = y[5] - vn * n2
    return True


@overload(onto_lumen_at, jit_options={"nogil": True})
def _onto_lumen_at(t, y, geom, gap):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    return _planar_onto if isinstance(geom, types.Array) else _tree_onto


def jacobian_position_step(geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The least position step (m) of a finite-difference Jacobian of the forces in ``geom`` (compiled code only).

    The plane: 0 (the estimators' relative step, 0.1 um per mm, stands).  A 3-D tree: a twenty-fifth of its flow
    and wall grid's spacing (10 um on a 0.25 mm grid).  The tree's wall field takes the nearest facet's normal and
    the local diameter, which the pulsating lumen's flow sample moves along: where the nearest facet changes (in a
    junction) the force jumps by up to ~0.2 m/s^2 over nanometres, and a 1 nm step made that a 1e8 1/s^2 gradient
    that threw the extended Kalman filter's covariance (and its estimate) off by a millimetre.
    """
    raise NotImplementedError("jacobian_position_step runs in compiled code only")


@overload(jacobian_position_step, inline="always")
def _jacobian_position_step(geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if isinstance(geom, types.Array):
        return lambda geom: 0.0
    return lambda geom: geom[3][3] / 25.0


def rests_on_lower_wall(t, x, geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Whether a bead centred at ``x`` (d,) at ``t`` rests on a wall below it: in contact with the nearest wall (its
    centre within a radius of it) whose inward normal points up.  What ``wall_contact: carried`` asks before it
    leaves the vertical to the weight and the wall (compiled code only)."""
    raise NotImplementedError("rests_on_lower_wall runs in compiled code only")


def _planar_rests(t, x, geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if geom[I_NET_ON] > 0.5:  # a planar network: the meshed wall nearest (x, z)
        delta, wall = wall_delta_xz(t, x[0], x[1], geom)
        return delta >= 0.0 and wall < 0.0
    # the straight vessel: its lower wall at -D(t)/2 (the printed comparison, kept for its bits)
    return x[1] <= geom[I_R] - 0.5 * diameter_at(t, geom)


def _tree_rests(t, x, geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    p = geom[0]
    s_t, _n0, _n1, n2, _d, _eta, _v0, _v1, _v2 = tree_geometry(t, x[0], x[1], x[2], p, geom[1], geom[2], geom[3])
    return p[I_R] - s_t >= 0.0 and n2 > 0.0


@overload(rests_on_lower_wall, jit_options={"nogil": True})
def _rests_on_lower_wall(t, x, geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    return _planar_rests if isinstance(geom, types.Array) else _tree_rests


def carried_into(t, x, pr, geom, out, k):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``out[k:k + d]`` (an acceleration the coil is asked for, the reference ``pr`` (d,) resting on a wall below)
    without what that wall carries: its component along the wall's inward normal (a push into the wall is the
    wall's, a pull off it lifts the bead from where it rests).  The straight vessel's lower wall: the vertical
    component, as printed in ``controller.wall_contact: carried`` (its bits).  A network's or a tree's floor:
    along the normal of the wall nearest the bead's estimate ``x`` (d,) where that is within a bead radius of the
    wall (where it touches it: a curved floor tilts it), else nearest the reference (compiled code only)."""
    raise NotImplementedError("carried_into runs in compiled code only")


def _planar_carried(t, x, pr, geom, out, k):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if geom[I_NET_ON] > 0.5:  # a planar network: the normal of its meshed wall nearest the bead (or the reference)
        s, nx, nz, _d, _eta, _vx, _vz = network_geometry(t, x[0], x[1], geom)
        if not s <= 2.0 * geom[I_R]:
            s, nx, nz, _d, _eta, _vx, _vz = network_geometry(t, pr[0], pr[1], geom)
        un = out[k] * nx + out[k + 1] * nz
        out[k] = out[k] - un * nx
        out[k + 1] = out[k + 1] - un * nz
    else:
        out[k + 1] = 0.0


def _tree_carried(t, x, pr, geom, out, k):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    p = geom[0]
    s, n0, n1, n2, _d, _eta, _v0, _v1, _v2 = tree_geometry(t, x[0], x[1], x[2], p, geom[1], geom[2], geom[3])
    if not s <= 2.0 * p[I_R]:
        s, n0, n1, n2, _d, _eta, _v0, _v1, _v2 = tree_geometry(t, pr[0], pr[1], pr[2], p, geom[1], geom[2], geom[3])
    un = out[k] * n0 + out[k + 1] * n1 + out[k + 2] * n2
    out[k] = out[k] - un * n0
    out[k + 1] = out[k + 1] - un * n1
    out[k + 2] = out[k + 2] - un * n2


@overload(carried_into, jit_options={"nogil": True})
def _carried_into(t, x, pr, geom, out, k):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    return _planar_carried if isinstance(geom, types.Array) else _tree_carried


def blood_velocity_into(t, x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``out`` (d,) = the blood velocity (m/s) at the point ``x`` (d,) at ``t`` in ``geom`` (compiled code only)."""
    raise NotImplementedError("blood_velocity_into runs in compiled code only")


def _planar_blood(t, x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    vx, vz = fluid_velocity_xz(t, x[0], x[1], geom)
    out[0] = vx
    out[1] = vz


def _tree_blood(t, x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    r = tree_geometry(t, x[0], x[1], x[2], geom[0], geom[1], geom[2], geom[3])
    out[0] = r[6]
    out[1] = r[7]
    out[2] = r[8]


@overload(blood_velocity_into, jit_options={"nogil": True})
def _blood_velocity_into(t, x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    return _planar_blood if isinstance(geom, types.Array) else _tree_blood


@numba.njit(cache=True, nogil=True)
def blood_velocity(t, x, geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The blood velocity (d,) (m/s) at the point ``x`` (d,) at ``t`` in ``geom``: :func:`blood_velocity_into`,
    callable from Python (the flow-synchronised reference's timing asks it)."""
    out = np.empty(axes_of(geom))
    blood_velocity_into(t, x, geom, out)
    return out


def wall_offset_into(x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``out`` (d,) = ``D n / 2`` of the wall nearest the point ``x`` (d,) in ``geom`` at t = 0 (``D`` the local
    diameter, ``n`` the unit inward normal): the eq. (13) pulsation ``eps`` moves that wall by ``-eps D n / 2``.
    Pass a geometry whose pulsation is zero for the still wall (compiled code only)."""
    raise NotImplementedError("wall_offset_into runs in compiled code only")


def _planar_offset(x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if geom[I_NET_ON] > 0.5:  # a planar network: its meshed wall
        _s, nx, nz, d, _eta, _vx, _vz = network_geometry(0.0, x[0], x[1], geom)
        out[0] = 0.5 * d * nx
        out[1] = 0.5 * d * nz
    else:  # the straight vessel: its nearer wall, +-D/2
        d = diameter_at(0.0, geom)
        _delta, wall = wall_delta_at(x[1], d, geom)
        out[0] = 0.0
        out[1] = -0.5 * d * wall


def _tree_offset(x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    _s, n0, n1, n2, d, _eta, _v0, _v1, _v2 = tree_geometry(0.0, x[0], x[1], x[2], geom[0], geom[1], geom[2], geom[3])
    out[0] = 0.5 * d * n0
    out[1] = 0.5 * d * n1
    out[2] = 0.5 * d * n2


@overload(wall_offset_into, jit_options={"nogil": True})
def _wall_offset_into(x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    return _planar_offset if isinstance(geom, types.Array) else _tree_offset


@numba.njit(cache=True, nogil=True)
def wall_offsets(points, geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(n, d) :func:`wall_offset_into` at each of the points (n, d), callable from Python (a reference that follows
    a pulsating wall asks it along its path)."""
    out = np.empty_like(points)
    for i in range(points.shape[0]):
        wall_offset_into(points[i], geom, out[i])
    return out


def wall_frame_into(t, x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``out`` (d,) = the unit inward normal of the wall nearest the point ``x`` (d,) of a network or a tree at time
    ``t``; returns ``(s_t, D_t)``: the centre's signed distance to that wall (m, > 0 inside, the pulsation's wall)
    and the local diameter then (m).  A planar ``geom`` must be a network's (compiled code only); for the normal
    alone in any vessel, :func:`wall_normal_into`."""
    raise NotImplementedError("wall_frame_into runs in compiled code only")


def _planar_frame(t, x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    s_t, nx, nz, d_t, _eta, _vx, _vz = network_geometry(t, x[0], x[1], geom)
    out[0] = nx
    out[1] = nz
    return s_t, d_t


def _tree_frame(t, x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    s_t, n0, n1, n2, d_t, _eta, _v0, _v1, _v2 = tree_geometry(t, x[0], x[1], x[2], geom[0], geom[1], geom[2], geom[3])
    out[0] = n0
    out[1] = n1
    out[2] = n2
    return s_t, d_t


@overload(wall_frame_into, jit_options={"nogil": True})
def _wall_frame_into(t, x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    return _planar_frame if isinstance(geom, types.Array) else _tree_frame


def wall_normal_into(t, x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``out`` (d,) = the unit inward normal of the wall nearest the point ``x`` (d,) at time ``t``, in any vessel:
    the straight vessel's upper or lower wall, a network's or a tree's (:func:`wall_frame_into`), the normal that
    :func:`onto_lumen_at` projects along (compiled code only)."""
    raise NotImplementedError("wall_normal_into runs in compiled code only")


def _planar_normal(t, x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if geom[I_NET_ON] > 0.5:
        wall_frame_into(t, x, geom, out)
    else:
        _delta, wall = wall_delta_xz(t, x[0], x[1], geom)
        out[0] = 0.0
        out[1] = -wall  # the upper wall (+1) pushes down


def _tree_normal(t, x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    wall_frame_into(t, x, geom, out)


@overload(wall_normal_into, jit_options={"nogil": True})
def _wall_normal_into(t, x, geom, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    return _planar_normal if isinstance(geom, types.Array) else _tree_normal


@numba.njit(cache=True, nogil=True)
def wall_frames(ts, points, geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(s_t (n,), normals (n, d), D_t (n,))``: :func:`wall_frame_into` at each point (n, d) and time (n,), callable
    from Python (the planner rests a bead on a network's or a tree's floor with it)."""
    n = points.shape[0]
    s = np.empty(n)
    d = np.empty(n)
    normals = np.empty_like(points)
    for i in range(n):
        s[i], d[i] = wall_frame_into(ts[i], points[i], geom, normals[i])
    return s, normals, d


@numba.njit(cache=True, nogil=True)
def floor_offsets(points, geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(n, d) ``D n / 2`` of the floor below each point (n, d) of a network or a tree (``geom`` with its pulsation
    zero: the wall at rest): the wall met going down (``-z``) from the point, where its inward normal points up
    (vertical component > 0.2); where there is none within two local diameters (or the point is outside), the
    nearest wall's (:func:`wall_offsets`).  What a reference resting on the floor below its path follows (its
    ``wall_follow`` share of it): one smooth field over the lumen, where the nearest wall's flips mid-lumen."""
    n, d = points.shape
    out = np.empty_like(points)
    normal = np.empty(d)
    q = np.empty(d)
    for i in range(n):
        s0, d0 = wall_frame_into(0.0, points[i], geom, normal)
        found = False
        if s0 > 0.0:
            step = max(0.05 * d0, 1e-6)
            lo, hi = 0.0, step
            while hi <= 2.0 * d0:
                q[:] = points[i]
                q[d - 1] -= hi
                s, _d = wall_frame_into(0.0, q, geom, normal)
                if s <= 0.0:
                    found = True
                    break
                lo = hi
                hi += step
            if found:
                for _ in range(50):
                    mid = 0.5 * (lo + hi)
                    q[:] = points[i]
                    q[d - 1] -= mid
                    s, _d = wall_frame_into(0.0, q, geom, normal)
                    if s > 0.0:
                        lo = mid
                    else:
                        hi = mid
                q[:] = points[i]
                q[d - 1] -= lo
                s, dq = wall_frame_into(0.0, q, geom, normal)
                if normal[d - 1] > 0.2:
                    for j in range(d):
                        out[i, j] = 0.5 * dq * normal[j]
                else:
                    found = False
        if not found:
            wall_offset_into(points[i], geom, out[i])
    return out


def params_of(geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The packed physics parameters of ``geom`` (compiled code only)."""
    raise NotImplementedError("params_of runs in compiled code only")


@overload(params_of, inline="always", jit_options={"_nrt": True})  # type: ignore[typeddict-unknown-key]  # typed with the runtime: a no-runtime caller (the laws) inlines it, and returning geom[0] is not allowed without one
def _params_of(geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if isinstance(geom, types.Array):
        return lambda geom: geom
    return lambda geom: geom[0]


def mass_of(geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The bead's mass in ``geom``'s packed parameters (kg; compiled code only)."""
    raise NotImplementedError("mass_of runs in compiled code only")


@overload(mass_of, inline="always")
def _mass_of(geom):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if isinstance(geom, types.Array):
        return lambda geom: geom[I_MASS]
    return lambda geom: geom[0][I_MASS]


def with_params(geom, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``geom`` with its packed physics parameters replaced by ``p`` (the same vessel; compiled code only)."""
    raise NotImplementedError("with_params runs in compiled code only")


@overload(with_params, inline="always")
def _with_params(geom, p):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if isinstance(geom, types.Array):
        return lambda geom, p: p
    return lambda geom, p: (p, geom[1], geom[2], geom[3])


@numba.njit(cache=True, nogil=True)
def plant_output(t, y, g, contact, geom, fbuf, sc, with_forces):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`wall_and_forces` callable from Python (the plant's ground truth at a tick)."""
    return wall_and_forces(t, y, g, contact, geom, fbuf, sc, with_forces)


@overload(rhs_into, jit_options={"nogil": True, "_nrt": False})  # type: ignore[typeddict-unknown-key]  # _nrt: as above
def _rhs_into(t, y, g, u, contact, geom, out, fbuf, sc, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    return _planar_rhs if isinstance(geom, types.Array) else _tree_rhs


@overload(contact_after_step, jit_options={"nogil": True, "_nrt": False})  # type: ignore[typeddict-unknown-key]  # _nrt: as above
def _contact_after_step(t, y, contact, geom, tc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    return _planar_contact if isinstance(geom, types.Array) else _tree_contact


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _integrate_rk4(t0, t1, y, g, u, contact, geom, h, ig, stats, work, fbuf, sc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`integrate`'s fixed-step RK4: ``ceil((t1 - t0) / fixed_step)`` equal steps (same arguments, returns
    ``(code, h)`` with ``h`` unchanged).

    Its own function, not a branch of :func:`integrate`: with the four RK4 stages inline, LLVM laid out the
    Dormand-Prince loop worse (the plant's integration of sound_small_artery 0.98 against 0.87 us a period before the
    integrators were one; 0.89 with this split).
    """
    n = 2 * axes_of(geom)  # 2 d, the stages' length
    k1 = work[0]
    k2 = work[1]
    k3 = work[2]
    k4 = work[3]
    yt = work[7]
    tc = work[TIME_TERMS_ROW]
    m = int(math.ceil((t1 - t0) / ig[6] - 1e-9))
    if m < 1:
        m = 1
    hh = (t1 - t0) / m
    for j in range(m):
        t = t0 + j * hh
        rhs_into(t, y, g, u, contact, geom, k1, fbuf, sc, tc)
        for i in range(n):
            yt[i] = y[i] + 0.5 * hh * k1[i]
        rhs_into(t + 0.5 * hh, yt, g, u, contact, geom, k2, fbuf, sc, tc)
        for i in range(n):
            yt[i] = y[i] + 0.5 * hh * k2[i]
        rhs_into(t + 0.5 * hh, yt, g, u, contact, geom, k3, fbuf, sc, tc)
        for i in range(n):
            yt[i] = y[i] + hh * k3[i]
        rhs_into(t + hh, yt, g, u, contact, geom, k4, fbuf, sc, tc)
        for i in range(n):
            y[i] = y[i] + hh / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        contact_after_step(t + hh, y, contact, geom, tc)
        stats[0] += 1
        stats[2] += 4
    for i in range(n):
        if not math.isfinite(y[i]):
            return NON_FINITE, h
    return OK, h


@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def integrate(t0, t1, y, g, u, contact, geom, h, ig, stats, work, fbuf, sc):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Integrate ``y = (X, Z)`` (2 d,) in place from ``t0`` to ``t1`` (s) in the vessel ``geom``, on any number of axes.

    Args: t0, t1 (s); y (2 d,) float64, overwritten; g (d,) gradient (T/m);
    u (d,) extra acceleration (m/s^2); contact (4,) contact state, updated;
    geom the vessel (the geometry's edge above); h proposed first step (s, dopri5);
    ig (7,) :func:`integrator_vector`; stats (4,) int64 += [accepted, rejected,
    rhs evaluations, steps forced at h_min].  A step that fails the tolerance
    at ``h_min`` is accepted and counted as forced (the tolerance cannot be met
    across a jump of the right-hand side).

    ``work``, ``fbuf`` and ``sc`` are scratch arrays the caller allocates once
    (:func:`new_workspace`): nothing is allocated here.  ``g`` and ``u`` may be
    rows :data:`G_ROW` and :data:`U_ROW` of ``work``.

    Returns:
        (code, h_next): return code and the step size to propose next period.
    """
    n = 2 * axes_of(geom)  # 2 d, the stages' length (y may be longer: its first n entries are integrated)
    half = n // 2
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
    tc[0] = np.nan  # the vessel may differ from the last call's
    if ig[0] > 0.5:  # fixed-step RK4 (tc invalidated above, as it reads it)
        return _integrate_rk4(t0, t1, y, g, u, contact, geom, h, ig, stats, work, fbuf, sc)
    rtol = ig[1]
    h_min = ig[4]
    h_max = ig[5]
    t = t0
    h = min(max(h, h_min), h_max)
    rhs_into(t, y, g, u, contact, geom, k1, fbuf, sc, tc)
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
        for i in range(n):
            yt[i] = y[i] + hs * _A21 * k1[i]
        rhs_into(t + _C2 * hs, yt, g, u, contact, geom, k2, fbuf, sc, tc)
        for i in range(n):
            yt[i] = y[i] + hs * (_A31 * k1[i] + _A32 * k2[i])
        rhs_into(t + _C3 * hs, yt, g, u, contact, geom, k3, fbuf, sc, tc)
        for i in range(n):
            yt[i] = y[i] + hs * (_A41 * k1[i] + _A42 * k2[i] + _A43 * k3[i])
        rhs_into(t + _C4 * hs, yt, g, u, contact, geom, k4, fbuf, sc, tc)
        for i in range(n):
            yt[i] = y[i] + hs * (_A51 * k1[i] + _A52 * k2[i] + _A53 * k3[i] + _A54 * k4[i])
        rhs_into(t + _C5 * hs, yt, g, u, contact, geom, k5, fbuf, sc, tc)
        for i in range(n):
            yt[i] = y[i] + hs * (_A61 * k1[i] + _A62 * k2[i] + _A63 * k3[i] + _A64 * k4[i] + _A65 * k5[i])
        rhs_into(t + hs, yt, g, u, contact, geom, k6, fbuf, sc, tc)
        for i in range(n):
            yn[i] = y[i] + hs * (_B1 * k1[i] + _B3 * k3[i] + _B4 * k4[i] + _B5 * k5[i] + _B6 * k6[i])
        rhs_into(t + hs, yn, g, u, contact, geom, k7, fbuf, sc, tc)
        stats[2] += 6
        err = 0.0
        for i in range(n):
            e = hs * (_E1 * k1[i] + _E3 * k3[i] + _E4 * k4[i] + _E5 * k5[i] + _E6 * k6[i] + _E7 * k7[i])
            atol = ig[2] if i < half else ig[3]
            r = abs(e) / (atol + rtol * max(abs(y[i]), abs(yn[i])))
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
            finite = True
            for i in range(n):
                finite = finite and math.isfinite(yn[i])
            for i in range(n):
                y[i] = yn[i]
            if not finite:
                return NON_FINITE, h
            t = t1 if last else t + hs
            c0, c1, c2, c3 = contact[0], contact[1], contact[2], contact[3]
            contact_after_step(t, y, contact, geom, tc)
            stats[0] += 1
            if c0 == contact[0] and c1 == contact[1] and c2 == contact[2] and c3 == contact[3]:
                for i in range(n):  # FSAL: last stage is the next first stage
                    k1[i] = k7[i]
            else:  # the contact state changed the rhs: re-evaluate
                rhs_into(t, y, g, u, contact, geom, k1, fbuf, sc, tc)
                stats[2] += 1
            fac = 5.0 if err == 0.0 else min(5.0, max(0.2, 0.9 * err ** -0.2))
            if not last or hs >= h:
                h = min(h_max, hs * fac)
        else:
            stats[1] += 1
            h = max(h_min, hs * max(0.2, 0.9 * err ** -0.2))
    for i in range(n):
        if not math.isfinite(y[i]):
            return NON_FINITE, h
    return OK, h
