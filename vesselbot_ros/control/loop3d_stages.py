"""The law (24) on three axes: the 3-D tree's controller stage (observer (25) is the planar one on three axes,
:class:`~vesselbot_ros.control.high_gain_observer.HighGainObserver`).

It is the planar law's rule axis by axis (its module's docstring says why each rule is what it is):

* :class:`Backstepping3D`: (24) on the estimate, ``U = a_ref + (k1 + k2) (v_ref - Z) + (1 + k1 k2) (p_ref - X)
  - F``, ``F`` the model's at the tick or at the middle of the hold (``sample_hold: midpoint``), with the
  model's ``V_f`` scaled by the estimate's flow scale (``flow_compensation: estimate``); ``G = U / b``; stale
  estimates and non-finite commands take the safe action (``stale_action``);
* the coil: :class:`~vesselbot_ros.control.actuator_limits.CoilLimiter` with ``dims=3`` (one coil for both).

With the model of a 3-D tree (:class:`~vesselbot_ros.control.model3d.DynamicsModel3D`) the stage runs its
compiled step (:func:`law3d_command`), the very function the compiled 3-D loop calls
(:mod:`vesselbot_ros.sim.compiled_loop3d`), so the two loops give the same doubles; with any other model (a
user's ``propagate`` and ``F``) the same rules run in Python.

Not on three axes yet (a scenario that names them over a 3-D tree is refused in one line): the extended Kalman
observer, the adaptive law and the predictive controller (the scanner's sequence and the dB/dt limit are:
``scanner/stages.py``, ``scanner/hardware.py``).
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.backstepping import (
    FLOW_SCALE_INVALID,
    STATUS_NONFINITE,
    STATUS_OK,
    STATUS_STALE,
    ControlCommand,
    ControllerParams,
    flow_scale_message,
)
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.kernel import I_MASS, I_V_F
from vesselbot_ros.physics.plant3d import forces3d_at

__all__ = ["Backstepping3D", "law3d_command", "law3d_params", "STATUS_NAMES"]

#: The law's statuses by code (:func:`law3d_command`).
STATUS_NAMES = ("ok", "stale", "nonfinite")


# ---- compiled steps -----------------------------------------------------------------------------------
# law3d_command: prm (8,) [k1, k2, T/2 (midpoint hold, 0: none), stale timeout (s), hold (1) / zero (0),
# flow compensation (1: estimate), 1 / b, 1 / duty cycle (1: no duty compensation)]; last (3,) last command;
# the model's p, a scratch p_s of its size, W, F,
# fh; free (4,) zeros; fbuf (8, 3), sc (4, 3), ys (6,) and z3 (3,) scratch; out (6,) [G (3) T/m, U (3) m/s^2].
def law3d_params(params: ControllerParams, b: float, hold_period_s: float, inv_duty: float = 1.0) -> npt.NDArray[np.float64]:
    """(8,) parameter vector of :func:`law3d_command`."""
    half = 0.5 * float(hold_period_s) if params.sample_hold == "midpoint" else 0.0
    return np.array([float(params.gains.k1), float(params.gains.k2), half, float(params.stale_timeout_s),
                     1.0 if params.stale_action == "hold" else 0.0, 1.0 if params.flow_compensation == "estimate" else 0.0,
                     1.0 / float(b), float(inv_duty)])


@numba.njit(cache=True, nogil=True)
def _model_f3(p, W, F, fh, free, fbuf, sc, ys, z3, t, x0, x1, x2, v0, v1, v2):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    ys[0] = x0
    ys[1] = x1
    ys[2] = x2
    ys[3] = v0
    ys[4] = v1
    ys[5] = v2
    forces3d_at(t, ys, z3, free, p, W, F, fh, fbuf, sc)
    m = p[I_MASS]
    return fbuf[7, 0] / m, fbuf[7, 1] / m, fbuf[7, 2] / m


@numba.njit(cache=True, nogil=True)
def _safe3(prm, last, out, status):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The safe action: hold the last command (``stale_action: hold``) or zero; no acceleration; ``status``."""
    if prm[4] < 0.5:
        last[0] = 0.0
        last[1] = 0.0
        last[2] = 0.0
    for c in range(3):
        out[c] = last[c]
        out[3 + c] = 0.0
    return status


@numba.njit(cache=True, nogil=True)
def law3d_command(prm, last, model_p, p_s, W, F, fh, free, fbuf, sc, ys, z3, t, x0, x1, x2, z0, z1, z2, age,  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
                  flow_scale, pr0, pr1, pr2, vr0, vr1, vr2, ar0, ar1, ar2, out):
    """:meth:`Backstepping3D.command_arrays` over explicit state; returns a status code (or ``FLOW_SCALE_INVALID``)."""
    if not age <= prm[3]:
        return _safe3(prm, last, out, STATUS_STALE)
    p = model_p
    if prm[5] > 0.5:
        if not (math.isfinite(flow_scale) and flow_scale > 0.0):
            return FLOW_SCALE_INVALID
        if flow_scale != 1.0:
            for i in range(model_p.shape[0]):
                p_s[i] = model_p[i]
            p_s[I_V_F] = model_p[I_V_F] * flow_scale
            p = p_s
    k1 = prm[0]
    k2 = prm[1]
    s = k1 + k2
    c = 1.0 + k1 * k2
    a0 = ar0 + s * vr0 + c * pr0 - c * x0 - s * z0
    a1 = ar1 + s * vr1 + c * pr1 - c * x1 - s * z1
    a2 = ar2 + s * vr2 + c * pr2 - c * x2 - s * z2
    h = prm[2]
    if h > 0.0:
        hh = 0.5 * h * h
        f0, f1, f2 = _model_f3(p, W, F, fh, free, fbuf, sc, ys, z3, t + h, x0 + h * z0 + hh * a0, x1 + h * z1 + hh * a1,
                               x2 + h * z2 + hh * a2, z0 + h * a0, z1 + h * a1, z2 + h * a2)
    else:
        f0, f1, f2 = _model_f3(p, W, F, fh, free, fbuf, sc, ys, z3, t, x0, x1, x2, z0, z1, z2)
    u0 = a0 - f0
    u1 = a1 - f1
    u2 = a2 - f2
    g0 = u0 * prm[6]
    g1 = u1 * prm[6]
    g2 = u2 * prm[6]
    if prm[7] != 1.0:  # duty compensation
        g0 = g0 * prm[7]
        g1 = g1 * prm[7]
        g2 = g2 * prm[7]
    if not (math.isfinite(g0) and math.isfinite(g1) and math.isfinite(g2)):
        return _safe3(prm, last, out, STATUS_NONFINITE)
    last[0] = g0
    last[1] = g1
    last[2] = g2
    out[0] = g0
    out[1] = g1
    out[2] = g2
    out[3] = u0
    out[4] = u1
    out[5] = u2
    return STATUS_OK


def _finite3(a: Any) -> bool:
    return bool(math.isfinite(a[0]) and math.isfinite(a[1]) and math.isfinite(a[2]))


class Backstepping3D:
    """Law (24) on three axes (module docstring); ports as :class:`~vesselbot_ros.control.backstepping.BacksteppingController`.

    Args:
        params: Gains and safe-behaviour settings (``kind: backstepping``).
        model: The 3-D dynamics model (``F``, ``input_gain``).
        hold_period_s: The coil's hold period (s), for ``sample_hold: midpoint``.
    """

    dims = 3

    def __init__(self, params: ControllerParams, model: Any, hold_period_s: float = 0.0, duty_cycle: float = 1.0) -> None:
        if not (math.isfinite(hold_period_s) and hold_period_s >= 0.0):
            raise ModelInputError(f"hold_period_s must be finite and >= 0, got {hold_period_s!r}")
        if not (math.isfinite(duty_cycle) and 0.0 < duty_cycle <= 1.0):
            raise ModelInputError(f"duty_cycle must be in (0, 1], got {duty_cycle!r}")
        self._inv_duty = 1.0 / duty_cycle if params.duty_compensation == "sequence" else 1.0
        self.params = params
        self.model = model
        self._inv_b = 1.0 / float(model.input_gain)
        self._k1 = float(params.gains.k1)
        self._k2 = float(params.gains.k2)
        self._half = 0.5 * float(hold_period_s) if params.sample_hold == "midpoint" else 0.0
        self._compensate = params.flow_compensation == "estimate"
        self._last = np.zeros(3)
        self._compiled = hasattr(model, "packed")  # the model of a 3-D tree: the compiled step
        if self._compiled:
            self.params_vector = law3d_params(params, float(model.input_gain), hold_period_s, self._inv_duty)
            self._p_s = np.empty_like(model.p)
            self._free = np.zeros(4)
            self._fbuf = np.empty((8, 3))
            self._sc = np.zeros((4, 3))
            self._ys = np.zeros(6)
            self._z3 = np.zeros(3)
            self._out = np.zeros(6)

    def reset(self) -> None:
        """Forget the last command (the ``hold`` action then holds zero)."""
        self._last[:] = 0.0

    def _safe(self, status: str) -> ControlCommand:
        if self.params.stale_action != "hold":
            self._last[:] = 0.0
        return ControlCommand(self._last.copy(), np.zeros(3), status)

    def command(self, t_s: float, estimate: Any, ref: Any) -> ControlCommand:
        """The gradient command from an :class:`Estimate` and a reference sample (``p``, ``v``, ``a``)."""
        return self.command_arrays(t_s, estimate.x_hat, estimate.z_hat, estimate.time_since_measurement_s, ref.p, ref.v,
                                   ref.a, estimate.flow_scale)

    def command_arrays(self, t_s: float, x_hat: npt.NDArray[np.float64], z_hat: npt.NDArray[np.float64],
                       time_since_measurement_s: float, p_ref: npt.NDArray[np.float64], v_ref: npt.NDArray[np.float64],
                       a_ref: npt.NDArray[np.float64], flow_scale: float = 1.0) -> ControlCommand:
        """:meth:`command` on arrays (3,).

        Raises:
            ModelInputError: a non-finite estimate or reference, or a flow scale the compensation cannot use.
        """
        if not (_finite3(x_hat) and _finite3(z_hat)):
            raise ModelInputError(f"controller: non-finite estimate x_hat={x_hat!r}, z_hat={z_hat!r}")
        if not (_finite3(p_ref) and _finite3(v_ref) and _finite3(a_ref)):
            raise ModelInputError("controller: non-finite reference sample")
        if self._compiled:
            m = self.model
            k = m.packed
            status = law3d_command(self.params_vector, self._last, m.p, self._p_s, k.W, k.F, k.fh, self._free, self._fbuf,
                                   self._sc, self._ys, self._z3, float(t_s), float(x_hat[0]), float(x_hat[1]),
                                   float(x_hat[2]), float(z_hat[0]), float(z_hat[1]), float(z_hat[2]),
                                   float(time_since_measurement_s), float(flow_scale), float(p_ref[0]), float(p_ref[1]),
                                   float(p_ref[2]), float(v_ref[0]), float(v_ref[1]), float(v_ref[2]), float(a_ref[0]),
                                   float(a_ref[1]), float(a_ref[2]), self._out)
            if status == FLOW_SCALE_INVALID:
                raise ModelInputError(flow_scale_message(flow_scale))
            o = self._out
            return ControlCommand(o[:3].copy(), o[3:].copy(), STATUS_NAMES[status])
        if not time_since_measurement_s <= self.params.stale_timeout_s:
            return self._safe("stale")
        scale = 1.0
        if self._compensate:
            if not (math.isfinite(flow_scale) and flow_scale > 0.0):
                raise ModelInputError(flow_scale_message(flow_scale))
            scale = float(flow_scale)
        s = self._k1 + self._k2
        c = 1.0 + self._k1 * self._k2
        a = (np.asarray(a_ref, dtype=np.float64) + s * np.asarray(v_ref, dtype=np.float64) + c * np.asarray(p_ref, dtype=np.float64)
             - c * np.asarray(x_hat, dtype=np.float64) - s * np.asarray(z_hat, dtype=np.float64))
        h = self._half
        if h > 0.0:
            f = self.model.F(t_s + h, x_hat + h * z_hat + 0.5 * h * h * a, z_hat + h * a, scale)
        else:
            f = self.model.F(t_s, x_hat, z_hat, scale)
        u = a - f
        g = u * self._inv_b
        if self._inv_duty != 1.0:
            g = g * self._inv_duty
        if not _finite3(g):
            return self._safe("nonfinite")
        self._last[:] = g
        return ControlCommand(g, u, "ok")
