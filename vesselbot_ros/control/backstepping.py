"""Backstepping tracking law, eq. (24) of Arcese et al. (2012).

For the canonical form (23) ``Xd = Z, Zd = F(X, Z) + U`` (per unit mass,
frame W, axes x and z), with reference ``X_ref`` and its first two
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
input matrix ``B`` (see :mod:`vesselbot_ros.control.input_mapping`):
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

from vesselbot_ros.blas_free import mat2, mat2_apply, mat2_inverse
from vesselbot_ros.config import ConfigError, check_choice, check_positive
from vesselbot_ros.control.adaptive import AdaptiveParams, AdaptiveState, adapt_scales, adaptive_params
from vesselbot_ros.control.compiled_stage import STEP_FLOW_SCALE_INVALID, CompiledController, lazy_step
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.kernel import I_MASS, I_NET_ON, I_R, I_V_F, diameter_at, forces_into

__all__ = [
    "BacksteppingGains",
    "ControllerParams",
    "ControlCommand",
    "BacksteppingController",
    "backstepping_u",
    "controller_params",
    "backstepping_command",
    "STATUS_OK",
    "STATUS_STALE",
    "STATUS_NONFINITE",
    "FLOW_SCALE_INVALID",
    "flow_scale_message",
    "rests_on_lower_wall",
]



class ForceFn(Protocol):
    """``F(t_s, X, Z[, flow_scale]) -> (2,)`` m/s^2 (:meth:`vesselbot_ros.control.model.DynamicsModel.F`'s shape)."""

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
            the reference rests on the straight vessel's lower wall (at or
            below the height where the bead touches it), the vertical command
            is dropped: the weight holds the bead on the wall and the wall
            carries any push into it, so the whole coil goes to the axial
            command (a plan that rides the wall, ``vesselbot plan``).  As
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
        gradient_T_per_m: (2,) commanded gradient, T/m, frame W.
        u_m_per_s2: (2,) acceleration ``U`` of eq. (24), m/s^2 (zeros when not
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
    """Eq. (24): the acceleration ``U`` (m/s^2), shape (2,).

    Args:
        k1: Gain k1 (1/s).
        k2: Gain k2 (1/s).
        x: (2,) position X (m).
        z: (2,) velocity Z (m/s).
        f: (2,) ``F(X, Z)`` (m/s^2).
        p_ref: (2,) ``X_ref`` (m).
        v_ref: (2,) ``Xd_ref`` (m/s).
        a_ref: (2,) ``Xdd_ref`` (m/s^2).
    """
    s = k1 + k2
    c = 1.0 + k1 * k2
    return a_ref + s * v_ref + c * p_ref - c * x - s * z - f


# ---- compiled stage -------------------------------------------------------------------------------
STATUS_OK, STATUS_STALE, STATUS_NONFINITE = 0, 1, 2
#: :func:`backstepping_command` refused the observer's flow scale (not finite and > 0): an error, not a status.
FLOW_SCALE_INVALID = STEP_FLOW_SCALE_INVALID
_STATUS_NAMES = ("ok", "stale", "nonfinite")


def controller_params(params: ControllerParams, b_inv: tuple[float, float, float, float], half_hold_s: float,
                      inv_duty: float = 1.0) -> npt.NDArray[np.float64]:
    """(12,) parameter vector of :func:`backstepping_command`.

    ``[k1, k2, T/2 (midpoint hold, 0 = none), stale_timeout_s, hold (1) / zero (0), B^-1 (4, row-major),
    flow compensation (1 = estimate), 1 / duty cycle (1 = none), wall contact carried (1) / model (0)]``.
    """
    return np.array([float(params.gains.k1), float(params.gains.k2), float(half_hold_s), float(params.stale_timeout_s),
                     1.0 if params.stale_action == "hold" else 0.0, *b_inv,
                     1.0 if params.flow_compensation == "estimate" else 0.0, float(inv_duty),
                     1.0 if params.wall_contact == "carried" else 0.0])


def flow_scale_message(flow_scale: float) -> str:
    """The error of a flow scale the compensating law cannot use (:data:`FLOW_SCALE_INVALID`)."""
    return f"controller: flow scale must be finite and > 0, got {flow_scale!r}"


@numba.njit(cache=True, nogil=True)
def _safe_command(prm, last, out, status):  # type: ignore[no-untyped-def]  # numba kernel: types inferred at compile time
    if prm[4] < 0.5:
        last[0] = 0.0
        last[1] = 0.0
    out[0] = last[0]
    out[1] = last[1]
    out[2] = 0.0
    out[3] = 0.0
    return status


@numba.njit(cache=True, nogil=True)
def backstepping_command(prm, last, model_p, p_s, free_contact, fbuf, t, x0, x1, z0, z1, age, flow_scale,  # type: ignore[no-untyped-def]  # numba kernel: types inferred at compile time
                         pr0, pr1, vr0, vr1, ar0, ar1, out):
    """Eq. (24) on the estimate, mapped to a gradient, with ``F`` from the model's packed parameters.

    Args: prm (12,) from :func:`controller_params`; last (2,) last command (T/m),
    updated; model_p packed model physics; p_s scratch of its size (``V_f``
    scaled by ``flow_scale`` with flow compensation); free_contact (4,) zeros
    (memoryless contact of ``F``); fbuf (8, 2) scratch; t (s); estimate x, z
    (m, m/s); age (s); the observer's flow scale ``s_hat`` (-); reference p, v,
    a.  Writes ``out`` = [g x, g z (T/m), U x, U z (m/s^2)].

    Returns:
        ``STATUS_OK``, ``STATUS_STALE`` or ``STATUS_NONFINITE`` (safe action taken),
        or :data:`FLOW_SCALE_INVALID` (nothing changed).  The same doubles as
        :func:`backstepping_u`, ``DynamicsModel.F`` and ``blas_free.mat2_apply``.
    """
    if not age <= prm[3]:
        return _safe_command(prm, last, out, STATUS_STALE)
    compensate = prm[9] > 0.5  # F with the model's V_f scaled by the observer's estimate
    if compensate and not (math.isfinite(flow_scale) and flow_scale > 0.0):
        return FLOW_SCALE_INVALID
    p = _scaled_model(model_p, p_s, flow_scale) if compensate else model_p
    g0, g1, u0, u1 = _law(prm, model_p, p, free_contact, fbuf, t, x0, x1, z0, z1, pr0, pr1, vr0, vr1, ar0, ar1)
    return _emit(prm, last, out, g0, g1, u0, u1)


@numba.njit(cache=True, nogil=True)
def _scaled_model(model_p, p_s, flow_scale):  # type: ignore[no-untyped-def]  # numba kernel: types inferred at compile time
    """The model's packed parameters with ``V_f`` times ``flow_scale`` (``model_p`` itself for 1), as ``DynamicsModel.F``."""
    if flow_scale == 1.0:
        return model_p
    for i in range(model_p.shape[0]):
        p_s[i] = model_p[i]
    p_s[I_V_F] = model_p[I_V_F] * flow_scale
    return p_s


@numba.njit(cache=True, nogil=True)
def _model_f(model_p, p, free_contact, fbuf, t, x0, x1, z0, z1):  # type: ignore[no-untyped-def]  # numba kernel: types inferred at compile time
    """``DynamicsModel.F`` at ``(X, Z)``, time ``t``, on packed parameters ``p`` (m/s^2): the same doubles."""
    forces_into(t, x0, x1, z0, z1, 0.0, 0.0, free_contact, p, fbuf)
    m = model_p[I_MASS]
    return fbuf[7, 0] / m, fbuf[7, 1] / m


@numba.njit(cache=True, nogil=True)
def rests_on_lower_wall(t, pz, p):  # type: ignore[no-untyped-def]  # numba kernel: types inferred at compile time
    """Whether a reference at height ``pz`` (m) rests on the straight vessel's lower wall at ``t``: what
    ``wall_contact: carried`` asks before it leaves the vertical to the weight and the wall (law (24), the
    predictive controller)."""
    return pz <= p[I_R] - 0.5 * diameter_at(t, p)


@numba.njit(cache=True, nogil=True)
def _law(prm, model_p, p, free_contact, fbuf, t, x0, x1, z0, z1, pr0, pr1, vr0, vr1, ar0, ar1):  # type: ignore[no-untyped-def]  # numba kernel: types inferred at compile time
    """Eq. (24) with ``F`` on ``p``, mapped by ``B^-1`` and the duty compensation: ``(g x, g z, U x, U z)``."""
    k1 = prm[0]
    k2 = prm[1]
    s = k1 + k2
    c = 1.0 + k1 * k2
    h = prm[2]
    if h > 0.0:
        a0 = ar0 + s * vr0 + c * pr0 - c * x0 - s * z0 - 0.0
        a1 = ar1 + s * vr1 + c * pr1 - c * x1 - s * z1 - 0.0
        hh = 0.5 * h * h
        f0, f1 = _model_f(model_p, p, free_contact, fbuf, t + h, x0 + h * z0 + hh * a0, x1 + h * z1 + hh * a1,
                          z0 + h * a0, z1 + h * a1)
        u0 = a0 - f0
        u1 = a1 - f1
    else:
        f0, f1 = _model_f(model_p, p, free_contact, fbuf, t, x0, x1, z0, z1)
        u0 = ar0 + s * vr0 + c * pr0 - c * x0 - s * z0 - f0
        u1 = ar1 + s * vr1 + c * pr1 - c * x1 - s * z1 - f1
    if prm[11] > 0.5 and rests_on_lower_wall(t, pr1, model_p):
        u1 = 0.0  # the reference rests on the lower wall: the weight and the wall hold the bead there
    g0 = prm[5] * u0 + prm[6] * u1
    g1 = prm[7] * u0 + prm[8] * u1
    if prm[10] != 1.0:  # duty compensation
        g0 = g0 * prm[10]
        g1 = g1 * prm[10]
    return g0, g1, u0, u1


@numba.njit(cache=True, nogil=True)
def _emit(prm, last, out, g0, g1, u0, u1):  # type: ignore[no-untyped-def]  # numba kernel: types inferred at compile time
    """Write a command (or take the safe action if it is not finite); its status."""
    if not (math.isfinite(g0) and math.isfinite(g1)):
        return _safe_command(prm, last, out, STATUS_NONFINITE)
    last[0] = g0
    last[1] = g1
    out[0] = g0
    out[1] = g1
    out[2] = u0
    out[3] = u1
    return STATUS_OK


@numba.njit(cache=True, nogil=True)
def adaptive_command(prm, aprm, ast, last, model_p, p_s, free_contact, fbuf, t, x0, x1, z0, z1, age,  # type: ignore[no-untyped-def]  # numba kernel: types inferred at compile time
                     pr0, pr1, vr0, vr1, ar0, ar1, out):
    """Adaptive backstepping (:mod:`vesselbot_ros.control.adaptive`): adapt, then law (24) at the adapted scales.

    ``aprm`` from :func:`~vesselbot_ros.control.adaptive.adaptive_params`; ``ast`` (3,) ``[s_hat, m_hat,
    time of the last update]``, updated (:func:`~vesselbot_ros.control.adaptive.adapt_scales`);
    the rest as :func:`backstepping_command`.  A stale estimate pauses the adaptation.  The law
    uses ``F`` at ``s_hat`` and divides the gradient by ``m_hat``.  The same doubles as the Python
    reading in :class:`BacksteppingController` with a user's ``F``.
    """
    if not age <= prm[3]:
        ast[2] = t  # adaptation pauses while the estimate is stale
        return _safe_command(prm, last, out, STATUS_STALE)
    k1 = prm[0]
    e20 = z0 - vr0 + k1 * (x0 - pr0)
    e21 = z1 - vr1 + k1 * (x1 - pr1)
    h = aprm[4]
    fa0, fa1 = _model_f(model_p, _scaled_model(model_p, p_s, ast[0]), free_contact, fbuf, t, x0, x1, z0, z1)
    fb0, fb1 = _model_f(model_p, _scaled_model(model_p, p_s, ast[0] + h), free_contact, fbuf, t, x0, x1, z0, z1)
    phi_s0 = (fb0 - fa0) / h
    phi_s1 = (fb1 - fa1) / h
    phi_m0 = aprm[5] * last[0] + aprm[6] * last[1]  # B G of the gradient commanded since the last update
    phi_m1 = aprm[7] * last[0] + aprm[8] * last[1]
    adapt_scales(aprm, ast, t, e20, e21, phi_s0, phi_s1, phi_m0, phi_m1)
    flow_scale = ast[0]
    if not (math.isfinite(flow_scale) and flow_scale > 0.0):
        return FLOW_SCALE_INVALID
    g0, g1, u0, u1 = _law(prm, model_p, _scaled_model(model_p, p_s, flow_scale), free_contact, fbuf, t, x0, x1,
                          z0, z1, pr0, pr1, vr0, vr1, ar0, ar1)
    inv_m = 1.0 / ast[1]
    if inv_m != 1.0:
        g0 = g0 * inv_m
        g1 = g1 * inv_m
    return _emit(prm, last, out, g0, g1, u0, u1)



# ---- the compiled loop's form (control/compiled_stage.py): law (24) and the adaptive law behind one signature ----
# state: [last command x, z (T/m), memoryless contact (4, zeros)] + (adaptive) [s_hat, m_hat, time of the last update];
# prm: controller_params (12,) + (adaptive) adaptive_params (9,); work: the model's size (V_f-scaled copy)
def _backstepping_step(prm, state, model_p, work, fbuf, t, x0, x1, z0, z1, age, flow_scale,  # type: ignore[no-untyped-def]  # numba kernel: typed by CONTROLLER_STEP
                      pr0, pr1, vr0, vr1, ar0, ar1, out):
    """:func:`backstepping_command` as a compiled controller step (the observer's flow scale)."""
    status = backstepping_command(prm, state[0:2], model_p, work, state[2:6], fbuf, t, x0, x1, z0, z1, age,
                                  flow_scale, pr0, pr1, vr0, vr1, ar0, ar1, out)
    out[4] = flow_scale
    out[5] = 1.0
    return status


def _adaptive_step(prm, state, model_p, work, fbuf, t, x0, x1, z0, z1, age, flow_scale,  # type: ignore[no-untyped-def]  # numba kernel: typed by CONTROLLER_STEP
                  pr0, pr1, vr0, vr1, ar0, ar1, out):
    """:func:`adaptive_command` as a compiled controller step (its own adapted scales)."""
    status = adaptive_command(prm[0:12], prm[12:21], state[6:9], state[0:2], model_p, work, state[2:6], fbuf, t,
                              x0, x1, z0, z1, age, pr0, pr1, vr0, vr1, ar0, ar1, out)
    out[4] = state[6]  # the adapted scales after this tick's update
    out[5] = state[7]
    return status


backstepping_step = lazy_step(_backstepping_step)
adaptive_step = lazy_step(_adaptive_step)


class BacksteppingController:
    """Eq. (24) on the observer's estimate, mapped to a coil gradient.

    Ports: inputs ``estimate`` (x_hat, z_hat, time since measurement) and
    ``ref_sample`` (X_ref, Xd_ref, Xdd_ref); output :class:`ControlCommand`.

    Args:
        params: Gains and safe-behaviour settings.
        force_fn: ``F(t_s, X, Z) -> (2,)`` m/s^2, all forces but the motive one
            divided by the mass, with the controller's own model parameters.
        input_matrix: (2, 2) ``B`` with ``U = B G`` (m/s^2 per T/m).
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
        try:
            b_inv = mat2_inverse(mat2(input_matrix))
        except ModelInputError as exc:
            raise ModelInputError(f"input_matrix: {exc}") from None
        self.params = params
        self._f = force_fn
        # B^-1 as four floats: G = B^-1 U in fixed-order scalar arithmetic, not BLAS (vesselbot_ros.blas_free)
        self._b_inv = b_inv
        self._k1 = float(params.gains.k1)
        self._k2 = float(params.gains.k2)
        self._last = np.zeros(2)
        self._half = 0.5 * float(hold_period_s) if params.sample_hold == "midpoint" else 0.0
        self._compensate = params.flow_compensation == "estimate"
        self._b = mat2(input_matrix)
        # the adapted scales [s_hat, m_hat, time of the last update] (``kind: adaptive_backstepping``), else None
        self._ast: npt.NDArray[np.float64] | None = (np.array([1.0, 1.0, math.nan])
                                                     if params.kind == "adaptive_backstepping" else None)
        self._aprm = adaptive_params(params.adaptive, self._b) if self._ast is not None else np.zeros(9)
        if not (math.isfinite(duty_cycle) and 0.0 < duty_cycle <= 1.0):
            raise ModelInputError(f"duty_cycle must be in (0, 1], got {duty_cycle!r}")
        self._inv_duty = 1.0 / duty_cycle if params.duty_compensation == "sequence" else 1.0
        # F of a DynamicsModel is the kernel at its packed params: then the law runs compiled
        # (backstepping_command), as in the compiled loop; any other force_fn runs in Python.
        owner = getattr(force_fn, "__self__", None)
        model_p = getattr(owner, "p", None)
        # the compiled law takes flow and duty compensation and the adaptation (adaptive_command)
        self.model_params: npt.NDArray[np.float64] | None = (
            model_p if (getattr(owner, "F", None) == force_fn and isinstance(model_p, np.ndarray)) else None
        )
        self.params_vector = controller_params(params, b_inv, self._half, self._inv_duty)
        if params.wall_contact == "carried" and (self.model_params is None or self.model_params[I_NET_ON] > 0.5):
            raise ConfigError("controller.wall_contact 'carried' needs the model's F of a straight vessel "
                              "(physics.vessel.network empty)")
        self._p_s = np.empty_like(model_p) if self.model_params is not None else np.empty(0)
        self._out = np.zeros(4)
        self._free = np.zeros(4)
        self._fbuf = np.empty((8, 2))

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
        """``(aprm (9,), state (3,))`` of :func:`adaptive_command`, or None (not adaptive)."""
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
            return CompiledController(backstepping_step(), self.params_vector, state, self.model_params.shape[0])
        return CompiledController(adaptive_step(), np.concatenate([self.params_vector, self._aprm]),
                                  np.concatenate([state, self._ast]), self.model_params.shape[0])

    def _safe(self, status: str) -> ControlCommand:
        if self.params.stale_action != "hold":
            self._last[:] = 0.0
        return ControlCommand(self._last.copy(), np.zeros(2), status)

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
            x_hat: (2,) estimated position, m.
            z_hat: (2,) estimated velocity, m/s.
            time_since_measurement_s: Age of the last correction (s).
            p_ref: (2,) reference position, m.
            v_ref: (2,) reference velocity, m/s.
            a_ref: (2,) reference acceleration, m/s^2.
            flow_scale: Observer's blood-velocity scale ``s_hat`` (-); used
                only with ``flow_compensation: estimate``.

        Returns:
            The :class:`ControlCommand`.

        Raises:
            ModelInputError: if the estimate or the reference is not finite
                (the observer guarantees a finite estimate, so this is a bug
                upstream, not a run-time condition to hide).
        """
        # scalar checks: np.all(np.isfinite(.)) costs ~4 us per call on (2,) arrays
        if not (math.isfinite(x_hat[0]) and math.isfinite(x_hat[1]) and math.isfinite(z_hat[0]) and math.isfinite(z_hat[1])):
            raise ModelInputError(f"controller: non-finite estimate x_hat={x_hat!r}, z_hat={z_hat!r}")
        if not (math.isfinite(p_ref[0]) and math.isfinite(p_ref[1]) and math.isfinite(v_ref[0])
                and math.isfinite(v_ref[1]) and math.isfinite(a_ref[0]) and math.isfinite(a_ref[1])):
            raise ModelInputError("controller: non-finite reference sample")
        if self.model_params is not None and self._ast is not None:
            status = adaptive_command(
                self.params_vector, self._aprm, self._ast, self._last, self.model_params, self._p_s, self._free,
                self._fbuf, float(t_s), float(x_hat[0]), float(x_hat[1]), float(z_hat[0]), float(z_hat[1]),
                float(time_since_measurement_s), float(p_ref[0]), float(p_ref[1]), float(v_ref[0]), float(v_ref[1]),
                float(a_ref[0]), float(a_ref[1]), self._out,
            )
            if status == FLOW_SCALE_INVALID:
                raise ModelInputError(flow_scale_message(float(self._ast[0])))
            o = self._out
            return ControlCommand(o[:2].copy(), o[2:].copy(), _STATUS_NAMES[status])
        if self.model_params is not None:
            status = backstepping_command(
                self.params_vector, self._last, self.model_params, self._p_s, self._free, self._fbuf, float(t_s),
                float(x_hat[0]), float(x_hat[1]), float(z_hat[0]), float(z_hat[1]), float(time_since_measurement_s),
                float(flow_scale), float(p_ref[0]), float(p_ref[1]), float(v_ref[0]), float(v_ref[1]), float(a_ref[0]),
                float(a_ref[1]), self._out,
            )
            if status == FLOW_SCALE_INVALID:
                raise ModelInputError(flow_scale_message(flow_scale))
            o = self._out
            return ControlCommand(o[:2].copy(), o[2:].copy(), _STATUS_NAMES[status])
        # a user's F (not the model's kernel): the same law in Python
        if not time_since_measurement_s <= self.params.stale_timeout_s:
            if self._ast is not None:
                self._ast[2] = float(t_s)  # adaptation pauses while the estimate is stale
            return self._safe("stale")
        inv_m = 1.0
        if self._ast is not None:
            flow_scale = self._adapt(float(t_s), x_hat, z_hat, p_ref, v_ref)
            inv_m = 1.0 / float(self._ast[1])
        if self._compensate or self._ast is not None:
            if not (math.isfinite(flow_scale) and flow_scale > 0.0):
                raise ModelInputError(flow_scale_message(flow_scale))

            def force(t: float, x: npt.NDArray[np.float64], z: npt.NDArray[np.float64], /) -> npt.NDArray[np.float64]:
                return self._f(t, x, z, flow_scale)
        else:
            force = self._f
        if self._half > 0.0:
            h = self._half
            a = backstepping_u(self._k1, self._k2, x_hat, z_hat, np.zeros(2), p_ref, v_ref, a_ref)
            f = force(t_s + h, x_hat + h * z_hat + 0.5 * h * h * a, z_hat + h * a)
            u = a - f
        else:
            f = force(t_s, x_hat, z_hat)
            u = backstepping_u(self._k1, self._k2, x_hat, z_hat, f, p_ref, v_ref, a_ref)
        g = np.array(mat2_apply(self._b_inv, u[0], u[1]))
        if self._inv_duty != 1.0:
            g = g * self._inv_duty
        if inv_m != 1.0:
            g = g * inv_m
        if not (math.isfinite(g[0]) and math.isfinite(g[1])):
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
        b = self._b  # phi_m = B G of the gradient commanded since the last update (m = 1)
        adapt_scales(self._aprm, ast, t_s,
                     float(z_hat[0] - v_ref[0] + k1 * (x_hat[0] - p_ref[0])),
                     float(z_hat[1] - v_ref[1] + k1 * (x_hat[1] - p_ref[1])),
                     float((f1[0] - f0[0]) / h), float((f1[1] - f0[1]) / h),
                     b[0] * self._last[0] + b[1] * self._last[1], b[2] * self._last[0] + b[3] * self._last[1])
        return float(ast[0])
