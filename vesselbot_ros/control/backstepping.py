"""Backstepping tracking law, eq. (24) of Arcese et al. (2012).

For the canonical form (23) ``Xd = Z, Zd = F(X, Z) + U`` (per unit mass,
frame W; axes x and z in the plane, x, y and z in a 3-D tree: the same law on each), with reference ``X_ref`` and its first two
derivatives, the law is::

    U = Xdd_ref + (k1 + k2) Xd_ref + (1 + k1 k2) X_ref
        - (1 + k1 k2) X - (k1 + k2) Z - F(X, Z)                        (24)

Assumptions: ``F`` is known (here: the physics core evaluated with the
controller's own, possibly wrong, parameters and at the *estimated* state),
``U`` is applied exactly and the state is known.  With ``e = X - X_ref`` and
exact cancellation the closed loop is ``edd + (k1 + k2) ed + (1 + k1 k2) e = 0``,
whose characteristic roots are ``-(k1+k2)/2 +/- sqrt((k1-k2)^2/4 - 1)``: both
real and negative for every ``k1, k2 > 0`` (Table III, ``k1 = 5, k2 = 10``:
``-5.21`` and ``-9.79`` 1/s).  A constant model error ``dF`` leaves a
steady-state error ``dF / (1 + k1 k2)``.

The acceleration ``U`` (m/s^2) is mapped to a gradient (T/m) by the model's
input matrix ``B`` (see :mod:`vesselbot_ros.scanner.input_mapping`):
``G = B^-1 U``.

Safe behaviour: when the estimate is older than ``stale_timeout_s`` (no
measurement for that long) the controller ``hold``\\ s its last command or
outputs ``zero``; a non-finite ``U`` (e.g. a model evaluated far outside the
vessel) gives the same safe action and ``status == "nonfinite"``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Literal, NamedTuple, Protocol

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.blas_free import mat_apply, mat_inverse
from vesselbot_ros.config import ConfigError, check_choice, check_positive
from vesselbot_ros.control.adaptive import AdaptiveParams, AdaptiveState, adapt_scales, adaptive_params
from vesselbot_ros.control.compiled_stage import STEP_FLOW_SCALE_INVALID, CompiledController, lazy_step, model_f_into
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.integrator import (
    axes_of,
    carried_into,
    forces_at,
    mass_of,
    params_of,
    rests_on_lower_wall,
    with_params,
)
from vesselbot_ros.physics.kernel import flow_scaled_into

__all__ = [
    "BacksteppingGains",
    "ControllerParams",
    "ControlCommand",
    "BacksteppingController",
    "backstepping_u",
    "controller_params",
    "law_work_size",
    "PRM_B_INV",
    "backstepping_command",
    "STATUS_OK",
    "STATUS_STALE",
    "STATUS_NONFINITE",
    "FLOW_SCALE_INVALID",
    "flow_scale_message",
]



class ForceFn(Protocol):
    """``F(t_s, X, Z[, flow_scale]) -> (d,)`` m/s^2 (:meth:`vesselbot_ros.control.model.DynamicsModel.F`'s shape)."""

    def __call__(self, t_s: float, x: npt.NDArray[np.float64], z: npt.NDArray[np.float64], flow_scale: float = 1.0, /
                 ) -> npt.NDArray[np.float64]: ...


@dataclasses.dataclass(frozen=True)
class BacksteppingGains:
    """Gains of eq. (24) (1/s, strictly positive).  Table III: k1 = 5, k2 = 10."""

    k1: float = 5.0
    k2: float = 10.0

    def __post_init__(self) -> None:
        check_positive("k1", self.k1)
        check_positive("k2", self.k2)


@dataclasses.dataclass(frozen=True)
class ControllerParams:
    """Backstepping controller parameters.

    Attributes:
        kind: ``backstepping``: law (24) with the model's parameters.
            ``adaptive_backstepping``: law (24) with on-line estimates of the
            blood-velocity scale and the magnetisation scale (the adaptive
            backstepping of the paper's ref. [39];
            :mod:`vesselbot_ros.control.adaptive`).
        adaptive: Gains and bounds of the adaptation (``kind: adaptive_backstepping``).
        gains: ``k1, k2`` of eq. (24).
        stale_timeout_s: Estimate age (time since the last measurement, s)
            beyond which the controller goes to its safe action.
        stale_action: ``hold`` the last command or output ``zero`` gradient.
        sample_hold: How (24) is sampled when ``U`` is held over a control
            period ``T`` (zero-order hold).  ``none``: ``F`` at the tick
            ``(t_k, X_k, Z_k)``, as printed.  ``midpoint``: ``F`` at the middle
            of the hold, ``(t_k + T/2, X_k + Z_k T/2 + a T^2/8, Z_k + a T/2)``
            with ``a = U + F`` the acceleration (24) asks for, so the *average*
            acceleration over the hold is the continuous law's (error O(T^2)
            instead of O(T); see docs/control.md).
        flow_compensation: ``none``: ``F`` with the model's blood velocity, as
            printed.  ``estimate``: ``F`` with the model's ``V_f`` scaled by the
            observer's estimate ``s_hat`` (``Estimate.flow_scale``; the
            extended Kalman observer estimates it), i.e. certainty-equivalence
            compensation of the blood-velocity error (Section III-D; the
            observer-based alternative to the adaptive law of ref. [39]).
        duty_compensation: ``none``: the gradient (24) asks for.  ``sequence``:
            divided by the scanner's propulsion duty cycle ``d`` (the fraction
            of time the gradient may be on, :mod:`vesselbot_ros.scanner.sequence`),
            so that the gradient averaged over a sequence period is the one (24)
            asks for (then saturated as usual).
        wall_contact: ``model``: (24) as printed, cancelling every force of
            the model at the estimate, the walls' included.  ``carried``: where
            the reference rests on a wall below it (a bead there would touch
            the nearest wall, whose inward normal points up: the straight
            vessel's lower wall, a network's or a tree's floor; the model's
            wall decides, :func:`~vesselbot_ros.physics.integrator.rests_on_lower_wall`),
            the vertical command is dropped (in a network or a tree: the
            command's component along the wall's inward normal, which tilts
            on a sloping or curved floor; :func:`~vesselbot_ros.physics.integrator.carried_into`):
            the weight holds the bead on the wall and the wall carries any
            push into it, so the whole coil goes along the wall (a plan that
            rides the wall, ``vesselbot plan``).  As
            printed, (24) cancels the weight (and the contact force at an
            estimate inside the wall), saturates the coil vertically, and the
            saturation's scaling leaves almost nothing for the axis along the
            vessel.
    """

    kind: Literal["backstepping", "adaptive_backstepping"] = "backstepping"
    adaptive: AdaptiveParams = dataclasses.field(default_factory=AdaptiveParams)
    gains: BacksteppingGains = dataclasses.field(default_factory=BacksteppingGains)
    stale_timeout_s: float = 0.2
    stale_action: Literal["hold", "zero"] = "zero"
    sample_hold: Literal["none", "midpoint"] = "none"
    flow_compensation: Literal["none", "estimate"] = "none"
    duty_compensation: Literal["none", "sequence"] = "none"
    wall_contact: Literal["model", "carried"] = "model"

    def __post_init__(self) -> None:
        check_positive("stale_timeout_s", self.stale_timeout_s)
        check_choice("stale_action", self.stale_action, ("hold", "zero"))
        check_choice("sample_hold", self.sample_hold, ("none", "midpoint"))
        check_choice("flow_compensation", self.flow_compensation, ("none", "estimate"))
        check_choice("duty_compensation", self.duty_compensation, ("none", "sequence"))
        check_choice("wall_contact", self.wall_contact, ("model", "carried"))
        check_choice("kind", self.kind, ("backstepping", "adaptive_backstepping"))
        if self.kind == "adaptive_backstepping" and self.flow_compensation != "none":
            raise ConfigError("flow_compensation must be 'none' with kind 'adaptive_backstepping' (the controller "
                              f"estimates the blood-velocity scale itself), got {self.flow_compensation!r}")


class ControlCommand(NamedTuple):
    """Output of :meth:`BacksteppingController.command`.

    Attributes:
        gradient_T_per_m: (d,) commanded gradient, T/m, frame W.
        u_m_per_s2: (d,) acceleration ``U`` of eq. (24), m/s^2 (zeros when not
            computed).
        status: ``ok``, ``stale`` (safe action, estimate too old) or
            ``nonfinite`` (safe action, the law gave a non-finite value).
    """

    gradient_T_per_m: npt.NDArray[np.float64]
    u_m_per_s2: npt.NDArray[np.float64]
    status: str


def backstepping_u(
    k1: float,
    k2: float,
    x: npt.NDArray[np.float64],
    z: npt.NDArray[np.float64],
    f: npt.NDArray[np.float64],
    p_ref: npt.NDArray[np.float64],
    v_ref: npt.NDArray[np.float64],
    a_ref: npt.NDArray[np.float64],
) -> npt.NDArray[np.float64]:
    """Eq. (24): the acceleration ``U`` (m/s^2), shape (d,).

    Args:
        k1: Gain k1 (1/s).
        k2: Gain k2 (1/s).
        x: (d,) position X (m).
        z: (d,) velocity Z (m/s).
        f: (d,) ``F(X, Z)`` (m/s^2).
        p_ref: (d,) ``X_ref`` (m).
        v_ref: (d,) ``Xd_ref`` (m/s).
        a_ref: (d,) ``Xdd_ref`` (m/s^2).
    """
    s = k1 + k2
    c = 1.0 + k1 * k2
    return a_ref + s * v_ref + c * p_ref - c * x - s * z - f


# ---- compiled stage -------------------------------------------------------------------------------
STATUS_OK, STATUS_STALE, STATUS_NONFINITE = 0, 1, 2
#: :func:`backstepping_command` refused the observer's flow scale (not finite and > 0): an error, not a status.
FLOW_SCALE_INVALID = STEP_FLOW_SCALE_INVALID
_STATUS_NAMES = ("ok", "stale", "nonfinite")
#: Index of ``B^-1`` (d x d, row-major) in :func:`controller_params`'s vector.
PRM_B_INV = 8


def controller_params(params: ControllerParams, b_inv: npt.ArrayLike, half_hold_s: float,
                      inv_duty: float = 1.0) -> npt.NDArray[np.float64]:
    """(8 + d^2,) parameter vector of :func:`backstepping_command`.

    ``[k1, k2, T/2 (midpoint hold, 0 = none), stale_timeout_s, hold (1) / zero (0), flow compensation
    (1 = estimate), 1 / duty cycle (1 = none), wall contact carried (1) / model (0), B^-1 (d x d, row-major)]``.
    """
    return np.array([float(params.gains.k1), float(params.gains.k2), float(half_hold_s), float(params.stale_timeout_s),
                     1.0 if params.stale_action == "hold" else 0.0,
                     1.0 if params.flow_compensation == "estimate" else 0.0, float(inv_duty),
                     1.0 if params.wall_contact == "carried" else 0.0,
                     *np.asarray(b_inv, dtype=np.float64).ravel()])


def law_work_size(model_p_size: int, dims: int) -> int:
    """Length of the laws' ``work``: ``[p_s (the model's size), y (2 d), g0 (d), e2 (d), phi_s (d), phi_m (d),
    fa (d)]``."""
    return int(model_p_size) + 7 * int(dims)


def flow_scale_message(flow_scale: float) -> str:
    """The error of a flow scale the compensating law cannot use (:data:`FLOW_SCALE_INVALID`)."""
    return f"controller: flow scale must be finite and > 0, got {flow_scale!r}"


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on the arrays it takes (physics.integrator)
def _safe_command(prm, last, out, status):  # type: ignore[no-untyped-def]  # numba kernel: types inferred at compile time
    d = last.shape[0]
    if prm[4] < 0.5:
        for c in range(d):
            last[c] = 0.0
    for c in range(d):
        out[c] = last[c]
        out[d + c] = 0.0
    return status


@numba.njit(cache=True, nogil=True, inline="always")  # inlined: its view of p_s is returned to no-runtime callers
def _scaled_model(geom, p_s, flow_scale):  # type: ignore[no-untyped-def]  # numba kernel: types inferred at compile time
    """The model with ``V_f`` times ``flow_scale`` (the model itself for 1), as ``DynamicsModel.F``."""
    p = params_of(geom)
    if flow_scale == 1.0:
        q = p
    else:
        flow_scaled_into(p, flow_scale, p_s)
        q = p_s[:p.shape[0]]
    return with_params(geom, q)


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on the arrays it takes (physics.integrator)
def _law(prm, geom, gq, work, free, fbuf, sc, t, est, pr, vr, ar, out):  # type: ignore[no-untyped-def]  # numba kernel: types inferred at compile time
    """Eq. (24) with ``F`` of the model ``gq``, mapped by ``B^-1`` and the duty compensation: ``out`` = [g (d), U (d)]."""
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    n = params_of(geom).shape[0]
    y = work[n:n + 2 * d]
    g0 = work[n + 2 * d:n + 3 * d]
    k1 = prm[0]
    k2 = prm[1]
    s = k1 + k2
    c = 1.0 + k1 * k2
    h = prm[2]
    m = mass_of(gq)
    if h > 0.0:  # F at the middle of the hold, along the acceleration (24) asks for
        hh = 0.5 * h * h
        for i in range(d):
            a = ar[i] + s * vr[i] + c * pr[i] - c * est[i] - s * est[d + i]
            out[d + i] = a
            y[i] = est[i] + h * est[d + i] + hh * a
            y[d + i] = est[d + i] + h * a
        forces_at(t + h, y, g0, free, gq, fbuf, sc)
        for i in range(d):
            out[d + i] = out[d + i] - fbuf[7, i] / m
    else:
        for i in range(d):
            y[i] = est[i]
            y[d + i] = est[d + i]
        forces_at(t, y, g0, free, gq, fbuf, sc)
        for i in range(d):
            out[d + i] = ar[i] + s * vr[i] + c * pr[i] - c * est[i] - s * est[d + i] - fbuf[7, i] / m
    if prm[7] > 0.5 and rests_on_lower_wall(t, pr, geom):
        carried_into(t, est, pr, geom, out, d)  # the reference rests on a wall below: the weight and the wall hold it
    for i in range(d):
        b = PRM_B_INV + i * d
        acc = prm[b] * out[d]
        for j in range(1, d):
            acc = acc + prm[b + j] * out[d + j]
        if prm[6] != 1.0:  # duty compensation
            acc = acc * prm[6]
        out[i] = acc


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on the arrays it takes (physics.integrator)
def _emit(prm, last, out):  # type: ignore[no-untyped-def]  # numba kernel: types inferred at compile time
    """Keep the command in ``out`` (or take the safe action if it is not finite); its status."""
    d = last.shape[0]
    for c in range(d):
        if not math.isfinite(out[c]):
            return _safe_command(prm, last, out, STATUS_NONFINITE)
    for c in range(d):
        last[c] = out[c]
    return STATUS_OK


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on the arrays it takes (physics.integrator)
def backstepping_command(prm, last, geom, work, free, fbuf, sc, t, est, pr, vr, ar, out):  # type: ignore[no-untyped-def]  # numba kernel: types inferred at compile time
    """Eq. (24) on the estimate, mapped to a gradient, with ``F`` from the model ``geom``, on d axes.

    Args: prm from :func:`controller_params`; last (d,) last command (T/m), updated; geom the model's vessel
    (:attr:`~vesselbot_ros.control.model.DynamicsModel.geom`); work (:func:`law_work_size`) scratch; free (4,)
    zeros (memoryless contact of ``F``); fbuf (8, d), sc (4, d) scratch; t (s); est ``[X (d), Z (d), age (s), the
    observer's flow scale]``; the reference p, v, a (d,).  Writes ``out`` = [g (d) (T/m), U (d) (m/s^2)].

    Returns:
        ``STATUS_OK``, ``STATUS_STALE`` or ``STATUS_NONFINITE`` (safe action taken), or :data:`FLOW_SCALE_INVALID`
        (nothing changed).
    """
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    if not est[2 * d] <= prm[3]:
        return _safe_command(prm, last, out, STATUS_STALE)
    flow_scale = est[2 * d + 1]
    gq = geom
    if prm[5] > 0.5:  # F with the model's V_f scaled by the observer's estimate
        if not (math.isfinite(flow_scale) and flow_scale > 0.0):
            return FLOW_SCALE_INVALID
        gq = _scaled_model(geom, work, flow_scale)
    _law(prm, geom, gq, work, free, fbuf, sc, t, est, pr, vr, ar, out)
    return _emit(prm, last, out)


@numba.njit(cache=True, nogil=True)
def adaptive_command(prm, aprm, ast, last, geom, work, free, fbuf, sc, t, est, pr, vr, ar, out):  # type: ignore[no-untyped-def]  # numba kernel: types inferred at compile time
    """Adaptive backstepping (:mod:`vesselbot_ros.control.adaptive`): adapt, then law (24) at the adapted scales.

    ``aprm`` from :func:`~vesselbot_ros.control.adaptive.adaptive_params`; ``ast`` (3,) ``[s_hat, m_hat,
    time of the last update]``, updated (:func:`~vesselbot_ros.control.adaptive.adapt_scales`);
    the rest as :func:`backstepping_command` (the observer's flow scale unused).  A stale estimate pauses the
    adaptation.  The law uses ``F`` at ``s_hat`` and divides the gradient by ``m_hat``.  The same doubles as the
    Python reading in :class:`BacksteppingController` with a user's ``F``.
    """
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    if not est[2 * d] <= prm[3]:
        ast[2] = t  # adaptation pauses while the estimate is stale
        return _safe_command(prm, last, out, STATUS_STALE)
    n = params_of(geom).shape[0]
    y = work[n:n + 2 * d]
    g0 = work[n + 2 * d:n + 3 * d]
    e2 = work[n + 3 * d:n + 4 * d]
    phi_s = work[n + 4 * d:n + 5 * d]
    phi_m = work[n + 5 * d:n + 6 * d]
    fa = work[n + 6 * d:n + 7 * d]
    k1 = prm[0]
    h = aprm[4]
    for i in range(d):
        e2[i] = est[d + i] - vr[i] + k1 * (est[i] - pr[i])
    model_f_into(t, est[:d], est[d:2 * d], _scaled_model(geom, work, ast[0]), free, fbuf, sc, y, g0, fa)
    model_f_into(t, est[:d], est[d:2 * d], _scaled_model(geom, work, ast[0] + h), free, fbuf, sc, y, g0, phi_s)
    for i in range(d):
        phi_s[i] = (phi_s[i] - fa[i]) / h
        b = 5 + i * d  # B G of the gradient commanded since the last update
        acc = aprm[b] * last[0]
        for j in range(1, d):
            acc = acc + aprm[b + j] * last[j]
        phi_m[i] = acc
    adapt_scales(aprm, ast, t, e2, phi_s, phi_m)
    flow_scale = ast[0]
    if not (math.isfinite(flow_scale) and flow_scale > 0.0):
        return FLOW_SCALE_INVALID
    _law(prm, geom, _scaled_model(geom, work, flow_scale), work, free, fbuf, sc, t, est, pr, vr, ar, out)
    inv_m = 1.0 / ast[1]
    if inv_m != 1.0:
        for i in range(d):
            out[i] = out[i] * inv_m
    return _emit(prm, last, out)


# ---- the compiled loop's form (control/compiled_stage.py): law (24) and the adaptive law behind one signature ----
# state: [last command (d) (T/m), memoryless contact (4, zeros)] + (adaptive) [s_hat, m_hat, time of the last update];
# prm: controller_params + (adaptive) adaptive_params; work: law_work_size
def _backstepping_step(prm, state, geom, work, fbuf, sc, t, est, pr, vr, ar, out):  # type: ignore[no-untyped-def]  # numba kernel: typed by controller_step_type
    """:func:`backstepping_command` as a compiled controller step (the observer's flow scale)."""
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    status = backstepping_command(prm, state[0:d], geom, work, state[d:d + 4], fbuf, sc, t, est, pr, vr, ar, out)
    out[2 * d] = est[2 * d + 1]
    out[2 * d + 1] = 1.0
    return status


def _adaptive_step(prm, state, geom, work, fbuf, sc, t, est, pr, vr, ar, out):  # type: ignore[no-untyped-def]  # numba kernel: typed by controller_step_type
    """:func:`adaptive_command` as a compiled controller step (its own adapted scales)."""
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    np_ = PRM_B_INV + d * d
    status = adaptive_command(prm[0:np_], prm[np_:], state[d + 4:d + 7], state[0:d], geom, work, state[d:d + 4], fbuf,
                              sc, t, est, pr, vr, ar, out)
    out[2 * d] = state[d + 4]  # the adapted scales after this tick's update
    out[2 * d + 1] = state[d + 5]
    return status


backstepping_step = lazy_step(_backstepping_step, nrt=False)
adaptive_step = lazy_step(_adaptive_step)


class BacksteppingController:
    """Eq. (24) on the observer's estimate, mapped to a coil gradient, on the model's axes (2 in the plane, 3 in a
    tree).

    Ports: inputs ``estimate`` (x_hat, z_hat, time since measurement) and
    ``ref_sample`` (X_ref, Xd_ref, Xdd_ref); output :class:`ControlCommand`.

    Args:
        params: Gains and safe-behaviour settings.
        force_fn: ``F(t_s, X, Z[, flow_scale]) -> (d,)`` m/s^2, all forces but the motive one divided by the mass,
            with the controller's own model parameters.  A :class:`~vesselbot_ros.control.model.DynamicsModel`'s
            ``F`` runs the compiled law (the compiled loop's very functions); any other in Python.
        input_matrix: (d, d) ``B`` with ``U = B G`` (m/s^2 per T/m); its size is the axis count.
        hold_period_s: Period ``T`` over which the coil holds each command (s);
            used by ``sample_hold: midpoint`` (0 = continuous, same as ``none``).
        duty_cycle: The scanner's propulsion duty cycle in (0, 1]; used by
            ``duty_compensation: sequence``.
    """

    def __init__(
        self,
        params: ControllerParams,
        force_fn: ForceFn,
        input_matrix: npt.ArrayLike,
        hold_period_s: float = 0.0,
        duty_cycle: float = 1.0,
    ) -> None:
        if not (math.isfinite(hold_period_s) and hold_period_s >= 0.0):
            raise ModelInputError(f"hold_period_s must be finite and >= 0, got {hold_period_s!r}")
        b = np.asarray(input_matrix, dtype=np.float64)
        if b.shape not in ((2, 2), (3, 3)):
            raise ModelInputError(f"input_matrix must be (2, 2) or (3, 3), got shape {b.shape}")
        try:
            b_inv = mat_inverse(b)  # G = B^-1 U in fixed-order scalar arithmetic, not BLAS (vesselbot_ros.blas_free)
        except ModelInputError as exc:
            raise ModelInputError(f"input_matrix: {exc}") from None
        d = b.shape[0]
        self.dims = d
        self.params = params
        self._f = force_fn
        self._b_inv = b_inv
        self._b = b
        self._k1 = float(params.gains.k1)
        self._k2 = float(params.gains.k2)
        self._last = np.zeros(d)
        self._half = 0.5 * float(hold_period_s) if params.sample_hold == "midpoint" else 0.0
        self._compensate = params.flow_compensation == "estimate"
        # the adapted scales [s_hat, m_hat, time of the last update] (``kind: adaptive_backstepping``), else None
        self._ast: npt.NDArray[np.float64] | None = (np.array([1.0, 1.0, math.nan])
                                                     if params.kind == "adaptive_backstepping" else None)
        self._aprm = adaptive_params(params.adaptive, b) if self._ast is not None else np.zeros(5 + d * d)
        if not (math.isfinite(duty_cycle) and 0.0 < duty_cycle <= 1.0):
            raise ModelInputError(f"duty_cycle must be in (0, 1], got {duty_cycle!r}")
        self._inv_duty = 1.0 / duty_cycle if params.duty_compensation == "sequence" else 1.0
        # F of a DynamicsModel is the force kernel on its geometry: then the law runs compiled (backstepping_command,
        # adaptive_command), as in the compiled loop; any other force_fn runs in Python.
        owner: Any = getattr(force_fn, "__self__", None)
        model_p = getattr(owner, "p", None)
        own = getattr(owner, "F", None) == force_fn and isinstance(model_p, np.ndarray) and hasattr(owner, "geom")
        self.model_params: npt.NDArray[np.float64] | None = model_p if own else None
        self.model_geom: Any = owner.geom if own else None
        self.params_vector = controller_params(params, b_inv, self._half, self._inv_duty)
        if params.wall_contact == "carried" and self.model_params is None:
            raise ConfigError("controller.wall_contact 'carried' needs the model's F (a DynamicsModel): it asks the "
                              "model's wall where the reference rests")
        n_p = self.model_params.shape[0] if self.model_params is not None else 0
        self._work = np.zeros(law_work_size(n_p, d))
        self._est = np.zeros(2 * d + 2)
        self._ref = np.zeros((3, d))
        self._out = np.zeros(2 * d)
        self._free = np.zeros(4)
        self._fbuf = np.empty((8, d))
        self._sc = np.zeros((4, d))

    def reset(self) -> None:
        """Forget the last command (the ``hold`` action then holds zero) and any adapted scale."""
        self._last[:] = 0.0
        if self._ast is not None:
            self._ast[:] = (1.0, 1.0, math.nan)

    @property
    def adapted(self) -> AdaptiveState | None:
        """The adapted scales now (``kind: adaptive_backstepping``; a copy), else None."""
        if self._ast is None:
            return None
        return AdaptiveState(float(self._ast[0]), float(self._ast[1]), float(self._ast[2]))

    @property
    def adaptive_vector(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None:
        """``(aprm, state (3,))`` of :func:`adaptive_command`, or None (not adaptive)."""
        return None if self._ast is None else (self._aprm, self._ast)

    def compiled(self) -> CompiledController:
        """This controller in the compiled loop's form (:mod:`vesselbot_ros.control.compiled_stage`), now.

        Raises:
            ModelInputError: its ``F`` is not a model's compiled kernel (a user's force function).
        """
        if self.model_params is None:
            raise ModelInputError("the compiled loop needs the controller's F from a DynamicsModel")
        state = np.concatenate([self._last, self._free])
        if self._ast is None:
            return CompiledController(backstepping_step, self.params_vector, state, self._work.shape[0])
        return CompiledController(adaptive_step, np.concatenate([self.params_vector, self._aprm]),
                                  np.concatenate([state, self._ast]), self._work.shape[0])

    def _safe(self, status: str) -> ControlCommand:
        if self.params.stale_action != "hold":
            self._last[:] = 0.0
        return ControlCommand(self._last.copy(), np.zeros(self.dims), status)

    def command(self, t_s: float, estimate: Any, ref: Any) -> ControlCommand:
        """Compute the gradient command from an observer estimate and a reference sample.

        Args:
            t_s: Time (s).
            estimate: An :class:`~vesselbot_ros.control.high_gain_observer.Estimate`
                (fields ``x_hat``, ``z_hat``, ``time_since_measurement_s``).
            ref: A :class:`~vesselbot_ros.control.bspline_reference.RefSample`.

        Returns:
            The :class:`ControlCommand`; see :meth:`command_arrays`.
        """
        return self.command_arrays(
            t_s, estimate.x_hat, estimate.z_hat, estimate.time_since_measurement_s, ref.p, ref.v, ref.a,
            estimate.flow_scale,
        )

    def command_arrays(
        self,
        t_s: float,
        x_hat: npt.NDArray[np.float64],
        z_hat: npt.NDArray[np.float64],
        time_since_measurement_s: float,
        p_ref: npt.NDArray[np.float64],
        v_ref: npt.NDArray[np.float64],
        a_ref: npt.NDArray[np.float64],
        flow_scale: float = 1.0,
    ) -> ControlCommand:
        """Compute the gradient command at time ``t_s``.

        Args:
            t_s: Time (s).
            x_hat: (d,) estimated position, m.
            z_hat: (d,) estimated velocity, m/s.
            time_since_measurement_s: Age of the last correction (s).
            p_ref: (d,) reference position, m.
            v_ref: (d,) reference velocity, m/s.
            a_ref: (d,) reference acceleration, m/s^2.
            flow_scale: Observer's blood-velocity scale ``s_hat`` (-); used
                only with ``flow_compensation: estimate``.

        Returns:
            The :class:`ControlCommand`.

        Raises:
            ModelInputError: if the estimate or the reference is not finite
                (the observer guarantees a finite estimate, so this is a bug
                upstream, not a run-time condition to hide).
        """
        d = self.dims
        est = self._est
        ref = self._ref
        # scalar checks: np.all(np.isfinite(.)) costs ~4 us per call on (2,) arrays
        for c in range(d):
            est[c] = x_hat[c]
            est[d + c] = z_hat[c]
            ref[0, c] = p_ref[c]
            ref[1, c] = v_ref[c]
            ref[2, c] = a_ref[c]
        if not all(math.isfinite(v) for v in est[:2 * d]):
            raise ModelInputError(f"controller: non-finite estimate x_hat={x_hat!r}, z_hat={z_hat!r}")
        if not all(math.isfinite(v) for v in ref.flat):
            raise ModelInputError("controller: non-finite reference sample")
        est[2 * d] = float(time_since_measurement_s)
        est[2 * d + 1] = float(flow_scale)
        if self.model_params is not None:
            o = self._out
            if self._ast is not None:
                status = adaptive_command(self.params_vector, self._aprm, self._ast, self._last, self.model_geom,
                                          self._work, self._free, self._fbuf, self._sc, float(t_s), est, ref[0],
                                          ref[1], ref[2], o)
                if status == FLOW_SCALE_INVALID:
                    raise ModelInputError(flow_scale_message(float(self._ast[0])))
            else:
                status = backstepping_command(self.params_vector, self._last, self.model_geom, self._work, self._free,
                                              self._fbuf, self._sc, float(t_s), est, ref[0], ref[1], ref[2], o)
                if status == FLOW_SCALE_INVALID:
                    raise ModelInputError(flow_scale_message(flow_scale))
            return ControlCommand(o[:d].copy(), o[d:].copy(), _STATUS_NAMES[status])
        return self._python_law(float(t_s), est[:d].copy(), est[d:2 * d].copy(), float(time_since_measurement_s),
                                ref[0].copy(), ref[1].copy(), ref[2].copy(), flow_scale)

    def _python_law(self, t_s: float, x_hat: npt.NDArray[np.float64], z_hat: npt.NDArray[np.float64], age: float,
                    p_ref: npt.NDArray[np.float64], v_ref: npt.NDArray[np.float64], a_ref: npt.NDArray[np.float64],
                    flow_scale: float) -> ControlCommand:
        """The law with a user's ``F`` (not a model's kernel), in Python."""
        if not age <= self.params.stale_timeout_s:
            if self._ast is not None:
                self._ast[2] = t_s  # adaptation pauses while the estimate is stale
            return self._safe("stale")
        inv_m = 1.0
        if self._ast is not None:
            flow_scale = self._adapt(t_s, x_hat, z_hat, p_ref, v_ref)
            inv_m = 1.0 / float(self._ast[1])
        if self._compensate or self._ast is not None:
            if not (math.isfinite(flow_scale) and flow_scale > 0.0):
                raise ModelInputError(flow_scale_message(flow_scale))

            def force(t: float, x: npt.NDArray[np.float64], z: npt.NDArray[np.float64], /) -> npt.NDArray[np.float64]:
                return self._f(t, x, z, flow_scale)
        else:
            force = self._f
        zero = np.zeros(self.dims)
        if self._half > 0.0:
            h = self._half
            a = backstepping_u(self._k1, self._k2, x_hat, z_hat, zero, p_ref, v_ref, a_ref)
            f = force(t_s + h, x_hat + h * z_hat + 0.5 * h * h * a, z_hat + h * a)
            u = a - f
        else:
            f = force(t_s, x_hat, z_hat)
            u = backstepping_u(self._k1, self._k2, x_hat, z_hat, f, p_ref, v_ref, a_ref)
        g = mat_apply(self._b_inv, u)
        if self._inv_duty != 1.0:
            g = g * self._inv_duty
        if inv_m != 1.0:
            g = g * inv_m
        if not all(math.isfinite(v) for v in g):
            return self._safe("nonfinite")
        self._last[:] = g
        return ControlCommand(g, u, "ok")

    def _adapt(self, t_s: float, x_hat: npt.NDArray[np.float64], z_hat: npt.NDArray[np.float64],
               p_ref: npt.NDArray[np.float64], v_ref: npt.NDArray[np.float64]) -> float:
        """One step of the adaptation laws (:mod:`vesselbot_ros.control.adaptive`); the flow scale to use."""
        ast = self._ast
        assert ast is not None
        k1 = self._k1
        h = self.params.adaptive.regressor_step
        s_hat = float(ast[0])
        f0 = self._f(t_s, x_hat, z_hat, s_hat)
        f1 = self._f(t_s, x_hat, z_hat, s_hat + h)
        e2 = np.array([float(z_hat[c] - v_ref[c] + k1 * (x_hat[c] - p_ref[c])) for c in range(self.dims)])
        phi_s = np.array([float((f1[c] - f0[c]) / h) for c in range(self.dims)])
        phi_m = mat_apply(self._b, self._last)  # B G of the gradient commanded since the last update (m = 1)
        adapt_scales(self._aprm, ast, t_s, e2, phi_s, phi_m)
        return float(ast[0])
