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
* the coil: :class:`~vesselbot_ros.control.actuator_limits.CoilLimiter3D`.

Not on three axes yet (a scenario that names them over a 3-D tree is refused in one line): the extended Kalman
observer, the adaptive law, the predictive controller, the scanner's multiplexed sequence and the dB/dt limit.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.backstepping import ControlCommand, ControllerParams
from vesselbot_ros.control.estimate import Estimate
from vesselbot_ros.control.high_gain_observer import HISTORY_LEN, ObserverParams, axis_gains
from vesselbot_ros.errors import ModelInputError

__all__ = ["HighGainObserver3D", "Backstepping3D", "axis_gains3d"]


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
                if gate > 0.0 and math.sqrt(innov[0] ** 2 + innov[1] ** 2 + innov[2] ** 2) > gate:
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

    def __init__(self, params: ControllerParams, model: Any, hold_period_s: float = 0.0) -> None:
        if not (math.isfinite(hold_period_s) and hold_period_s >= 0.0):
            raise ModelInputError(f"hold_period_s must be finite and >= 0, got {hold_period_s!r}")
        self.params = params
        self.model = model
        self._inv_b = 1.0 / float(model.input_gain)
        self._k1 = float(params.gains.k1)
        self._k2 = float(params.gains.k2)
        self._half = 0.5 * float(hold_period_s) if params.sample_hold == "midpoint" else 0.0
        self._compensate = params.flow_compensation == "estimate"
        self._last = np.zeros(3)

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
        if not time_since_measurement_s <= self.params.stale_timeout_s:
            return self._safe("stale")
        scale = 1.0
        if self._compensate:
            if not (math.isfinite(flow_scale) and flow_scale > 0.0):
                raise ModelInputError(f"controller: flow scale must be finite and > 0, got {flow_scale!r}")
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
        if not _finite3(g):
            return self._safe("nonfinite")
        self._last[:] = g
        return ControlCommand(g, u, "ok")
