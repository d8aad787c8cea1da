"""The observer (25) and the law (24) on three axes: the 3-D tree's loop stages.

Each is its planar stage's rule axis by axis (their modules' docstrings say why each rule is what it is):

* :class:`HighGainObserver3D`: (25) sampled; between frames the model (:class:`~vesselbot_ros.control.model3d.
  DynamicsModel3D`) predicts under ``U = B G_applied``; a frame taken ``T_m`` after the previous one corrects
  ``X_hat += T_m L g_x (X_hat - Y)``, ``Z_hat += T_m L^2 g_z (X_hat - Y)`` per axis.  Gains: x, along the
  scanner's bore, takes the planar x-axis's pair; y and z, across it, both take the planar z-axis's pair (the
  ``gain_layout`` reading of :func:`~vesselbot_ros.control.high_gain_observer.axis_gains`), so a tree in the
  plane y = 0 sees the planar gains on x and z.  Options: ``init_from_first_measurement``,
  ``delay_compensation`` (the estimate stored at the acquisition tick), ``innovation_gate_m`` (the
  innovation's Euclidean norm);
* :class:`Backstepping3D`: (24) on the estimate, ``U = a_ref + (k1 + k2) (v_ref - Z) + (1 + k1 k2) (p_ref - X)
  - F``, ``F`` the model's at the tick or at the middle of the hold (``sample_hold: midpoint``), with the
  model's ``V_f`` scaled by the estimate's flow scale (``flow_compensation: estimate``); ``G = U / b``; stale
  estimates and non-finite commands take the safe action (``stale_action``);
* the coil: :class:`~vesselbot_ros.control.actuator_limits.CoilLimiter` with ``dims=3`` (one coil for both).

With the model of a 3-D tree (:class:`~vesselbot_ros.control.model3d.DynamicsModel3D`) each stage runs its
compiled step (:func:`hgo3d_update`, :func:`law3d_command`), the very function the compiled 3-D loop calls
(:mod:`vesselbot_ros.sim.compiled_loop3d`), so the two loops give the same doubles; with any other model (a
user's ``propagate`` and ``F``) the same rules run in Python.

Not on three axes yet (a scenario that names them over a 3-D tree is refused in one line): the extended Kalman
observer, the adaptive law and the predictive controller (the scanner's sequence and the dB/dt limit are:
``scanner/stages.py``, ``scanner/hardware.py``).
"""

from __future__ import annotations

import math
from collections import deque
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
from vesselbot_ros.control.estimate import Estimate
from vesselbot_ros.control.high_gain_observer import HISTORY_LEN, ObserverParams, axis_gains, integrator_vector
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.integrator import OK, failure_message, integrate, new_workspace
from vesselbot_ros.physics.kernel import I_MASS, I_V_F
from vesselbot_ros.physics.plant3d import forces3d_at

__all__ = ["HighGainObserver3D", "Backstepping3D", "axis_gains3d", "hgo3d_update", "law3d_command", "observer3d_params",
           "law3d_params", "STATUS_NAMES"]

#: The law's statuses by code (:func:`law3d_command`).
STATUS_NAMES = ("ok", "stale", "nonfinite")


# ---- compiled steps -----------------------------------------------------------------------------------
# hgo3d_update: prm (11,) [kx (3), kz (3), b, delay_compensation, gate (m), init_from_first, -]; scal (4,) [t, t of
# the last accepted frame (-inf before), initialised, next integrator step]; y (6,) estimate; contact (4,);
# hist (HISTORY_LEN, 4) ring of (t, x, y, z), hist_n (2,) int64 [count, next slot]; ig (7,); the model's p, W, F,
# fh, stats, work, fbuf, sc; gu (2, 3) scratch (row 0 zeros: no gradient; row 1 the input U = b G);
# out (12,) [X (3), Z (3), age, innovation (3), used, rejected].
def observer3d_params(params: ObserverParams, b: float) -> npt.NDArray[np.float64]:
    """(11,) parameter vector of :func:`hgo3d_update`."""
    gx, gz = axis_gains3d(params)
    kx = params.high_gain * gx
    kz = params.high_gain ** 2 * gz
    return np.array([*kx, *kz, float(b), 1.0 if params.delay_compensation else 0.0, float(params.innovation_gate_m),
                     1.0 if params.init_from_first_measurement else 0.0, 0.0])


@numba.njit(cache=True, nogil=True)
def hgo3d_update(prm, scal, y, contact, hist, hist_n, ig, model_p, W, F, fh, stats, work, fbuf, sc, gu,  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
                 t, g0, g1, g2, has_meas, t_acq, m0, m1, m2, out):
    """:meth:`HighGainObserver3D.update` over explicit state: predict to ``t`` under ``U = b G``, then correct.

    Returns the model integrator's code (``OK``); on failure ``y`` holds the state reached.
    """
    if t > scal[0]:
        b = prm[6]
        gu[1, 0] = b * g0
        gu[1, 1] = b * g1
        gu[1, 2] = b * g2
        code, h = integrate(scal[0], t, y, gu[0], gu[1], contact, (model_p, W, F, fh), scal[3], ig, stats, work, fbuf, sc)
        scal[3] = h
        if code != OK:
            return code
    scal[0] = t
    if prm[7] > 0.5:
        j = hist_n[1]
        hist[j, 0] = t
        hist[j, 1] = y[0]
        hist[j, 2] = y[1]
        hist[j, 3] = y[2]
        hist_n[1] = (j + 1) % hist.shape[0]
        if hist_n[0] < hist.shape[0]:
            hist_n[0] += 1
    used = 0.0
    rejected = 0.0
    i0 = 0.0
    i1 = 0.0
    i2 = 0.0
    if has_meas:
        if not (math.isfinite(m0) and math.isfinite(m1) and math.isfinite(m2) and math.isfinite(t_acq)):
            rejected = 1.0
        elif scal[2] < 0.5 and prm[9] > 0.5:
            y[0] = m0
            y[1] = m1
            y[2] = m2
            scal[1] = t_acq
            scal[2] = 1.0
            used = 1.0
        else:
            r0 = y[0]
            r1 = y[1]
            r2 = y[2]
            if prm[7] > 0.5:  # the newest estimate stored at or before t_acq (else the oldest)
                for i in range(hist_n[0]):
                    j = (hist_n[1] - 1 - i) % hist.shape[0]
                    r0 = hist[j, 1]
                    r1 = hist[j, 2]
                    r2 = hist[j, 3]
                    if hist[j, 0] <= t_acq + 1e-9:
                        break
            i0 = r0 - m0
            i1 = r1 - m1
            i2 = r2 - m2
            if prm[8] > 0.0 and math.sqrt(i0 * i0 + i1 * i1 + i2 * i2) > prm[8]:
                rejected = 1.0
                i0 = 0.0
                i1 = 0.0
                i2 = 0.0
            else:
                tm = t_acq - scal[1] if math.isfinite(scal[1]) else 0.0
                if tm > 0.0:
                    y[0] = y[0] + tm * prm[0] * i0
                    y[1] = y[1] + tm * prm[1] * i1
                    y[2] = y[2] + tm * prm[2] * i2
                    y[3] = y[3] + tm * prm[3] * i0
                    y[4] = y[4] + tm * prm[4] * i1
                    y[5] = y[5] + tm * prm[5] * i2
                scal[1] = t_acq
                scal[2] = 1.0
                used = 1.0
    for c in range(6):
        out[c] = y[c]
    out[6] = scal[0] - scal[1]
    out[7] = i0
    out[8] = i1
    out[9] = i2
    out[10] = used
    out[11] = rejected
    return OK


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


def axis_gains3d(params: ObserverParams) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """``(g_x, g_z)`` diagonals over (x, y, z): y takes the planar z-axis's pair (module docstring)."""
    gx, gz = axis_gains(params)
    return np.array([gx[0], gx[1], gx[1]]), np.array([gz[0], gz[1], gz[1]])


def _finite3(a: Any) -> bool:
    return bool(math.isfinite(a[0]) and math.isfinite(a[1]) and math.isfinite(a[2]))


class HighGainObserver3D:
    """Sampled high-gain observer (25) on three axes; call :meth:`update` once per tick.

    Args:
        params: Observer gains and options.
        model: The 3-D dynamics model (``propagate``, ``input_gain``, ``new_contact_state``).
        x_hat0: (3,) prior position (m).  z_hat0: (3,) prior velocity (m/s).  t0_s: time of the prior (s).
    """

    dims = 3

    def __init__(self, params: ObserverParams, model: Any, x_hat0: npt.ArrayLike, z_hat0: npt.ArrayLike = (0.0, 0.0, 0.0),
                 t0_s: float = 0.0) -> None:
        y = np.concatenate([np.asarray(x_hat0, dtype=np.float64), np.asarray(z_hat0, dtype=np.float64)])
        if y.shape != (6,) or not np.all(np.isfinite(y)):
            raise ModelInputError(f"observer prior must be finite (3,) + (3,), got {x_hat0!r}, {z_hat0!r}")
        self.params = params
        self.model = model
        gx, gz = axis_gains3d(params)
        self._kx = params.high_gain * gx
        self._kz = params.high_gain ** 2 * gz
        self._b = float(model.input_gain)
        self._y = y
        self._t = float(t0_s)
        self._contact = model.new_contact_state()
        self._t_meas = -math.inf
        self._initialised = False
        self._history: deque[tuple[float, npt.NDArray[np.float64]]] = deque(maxlen=HISTORY_LEN)
        self.rejected = 0
        # the model of a 3-D tree: the compiled step (as the compiled 3-D loop); any other model: Python
        self._compiled = hasattr(model, "packed")
        if self._compiled:
            self.params_vector = observer3d_params(params, self._b)
            self._ig = integrator_vector(model.integrator)
            self._scal = np.array([self._t, -math.inf, 0.0, model.integrator.max_step_s])
            self._hist = np.empty((HISTORY_LEN, 4))
            self._hist_n = np.zeros(2, dtype=np.int64)
            self._work, self._fbuf, self._sc = new_workspace(3)
            self._gu = np.zeros((2, 3))
            self._out = np.zeros(12)

    @property
    def state(self) -> npt.NDArray[np.float64]:
        """(6,) ``(x_hat, z_hat)`` copy."""
        return self._y.copy()

    def update(self, t_s: float, measurement: Any | None, applied_gradient_prev: npt.ArrayLike) -> Estimate:
        """Predict to ``t_s`` under the applied gradient (3,), then correct if a frame arrived.

        Raises:
            ModelInputError: a non-finite or backwards time, a non-finite gradient, a prediction that fails.
        """
        g = np.asarray(applied_gradient_prev, dtype=np.float64)
        if g.shape != (3,) or not _finite3(g):
            raise ModelInputError(f"observer: applied gradient must be a finite (3,) array, got {applied_gradient_prev!r}")
        if not math.isfinite(t_s) or t_s < self._t - 1e-12:
            raise ModelInputError(f"observer: time must be finite and non-decreasing, got {t_s!r} after {self._t!r}")
        if self._compiled:
            return self._update_compiled(float(t_s), measurement, g)
        if t_s > self._t:
            b = self._b
            self.model.propagate(self._t, t_s, self._y, np.array((b * g[0], b * g[1], b * g[2])), self._contact)
        self._t = float(t_s)
        if self.params.delay_compensation:
            self._history.append((self._t, self._y[:3].copy()))
        used = rejected = False
        innov = np.zeros(3)
        if measurement is not None:
            yp = np.asarray(measurement.p, dtype=np.float64)
            t_acq = float(measurement.t_acq_s)
            if yp.shape != (3,) or not (_finite3(yp) and math.isfinite(t_acq)):
                rejected = True
            elif not self._initialised and self.params.init_from_first_measurement:
                self._y[:3] = yp
                self._t_meas = t_acq
                self._initialised = used = True
            else:
                x_ref = self._estimate_at(t_acq) if self.params.delay_compensation else self._y[:3]
                innov = x_ref - yp
                gate = self.params.innovation_gate_m
                if gate > 0.0 and math.sqrt(innov[0] * innov[0] + innov[1] * innov[1] + innov[2] * innov[2]) > gate:
                    rejected = True
                    innov = np.zeros(3)
                else:
                    tm = t_acq - self._t_meas if math.isfinite(self._t_meas) else 0.0
                    if tm > 0.0:
                        self._y[:3] = self._y[:3] + tm * self._kx * innov
                        self._y[3:] = self._y[3:] + tm * self._kz * innov
                    self._t_meas = t_acq
                    self._initialised = used = True
            if rejected:
                self.rejected += 1
        return Estimate(self._t, self._y[:3].copy(), self._y[3:].copy(), self._t - self._t_meas, innov, used, rejected)

    def _update_compiled(self, t_s: float, measurement: Any | None, g: npt.NDArray[np.float64]) -> Estimate:
        has, t_acq, m = False, math.nan, (math.nan, math.nan, math.nan)
        if measurement is not None:
            has, t_acq = True, float(measurement.t_acq_s)
            mp = np.asarray(measurement.p, dtype=np.float64)
            m = (float(mp[0]), float(mp[1]), float(mp[2])) if mp.shape == (3,) else m  # a wrong shape is rejected
        md = self.model
        k = md.packed
        t0 = self._t
        code = hgo3d_update(self.params_vector, self._scal, self._y, self._contact, self._hist, self._hist_n, self._ig, md.p,
                            k.W, k.F, k.fh, md.stats, self._work, self._fbuf, self._sc, self._gu, t_s, float(g[0]),
                            float(g[1]), float(g[2]), has, t_acq, m[0], m[1], m[2], self._out)
        if code != OK:
            raise ModelInputError(failure_message("observer model", t0, t_s, code, self._y.tolist()))
        self._t = t_s
        self._t_meas = float(self._scal[1])
        self._initialised = bool(self._scal[2] > 0.5)
        o = self._out
        rejected = bool(o[11] > 0.5)
        self.rejected += int(rejected)
        return Estimate(self._t, o[0:3].copy(), o[3:6].copy(), float(o[6]), o[7:10].copy(), bool(o[10] > 0.5), rejected)

    def _estimate_at(self, t_acq: float) -> npt.NDArray[np.float64]:
        best = self._y[:3]
        for t, x in reversed(self._history):
            best = x
            if t <= t_acq + 1e-9:
                break
        return best.copy()


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
