"""High-gain observer, eq. (25) of Arcese et al. (2012), for sampled measurements.

Continuous form (25), frame W, ``X = (x, z)`` position, ``Z`` velocity::

    Xd_hat = Z_hat + L G_x (X_hat - Y)
    Zd_hat = F(X_hat, Z_hat) + U + L^2 G_z (X_hat - Y)

Gain layout (the paper prints ``L, g1..g4 = 5, -6, -13, -12, -4`` and says
only that ``G_x, G_z`` are "conveniently chosen" after Gauthier et al.).  We
read them as diagonal matrices, one ``(g_x, g_z)`` pair per axis:

* ``per_axis`` (default): ``G_x = diag(g1, g3)``, ``G_z = diag(g2, g4)``,
  i.e. the x-axis uses ``(g1, g2)`` and the z-axis ``(g3, g4)``;
* ``per_equation``: ``G_x = diag(g1, g2)``, ``G_z = diag(g3, g4)``.

Each axis decouples (``F`` aside) into ``e1d = e2 + L g_x e1``,
``e2d = L^2 g_z e1`` with characteristic polynomial
``s^2 - L g_x s - L^2 g_z``, Hurwitz iff ``g_x < 0`` and ``g_z < 0``.  With
``per_axis`` and Table III: x-axis ``s^2 + 30 s + 325`` (roots ``-15 +/- 10j``),
z-axis ``s^2 + 60 s + 100`` (roots ``-1.72`` and ``-58.3``): stable in free
flow, where the drag only adds damping (``dF/dZ`` negative definite) and
``dF/dX`` is small.  Near a wall the attractive electrostatic and van der Waals
forces have a large positive gradient ``dF_z/dz``; the linearised error is
unstable where ``dF_z/dz > L^2 |g_z| + L |g_x| |dF_z/dv_z|`` (determinant of the
z block changes sign), see :func:`linearised_error_matrix` and
``docs/control.md`` for where that happens.

Sampled implementation.  Between measurements the observer *predicts*: it
integrates ``Xd = Z, Zd = F(X, Z) + B G_applied`` with the model's integrator
(same adaptive scheme as the plant, so model contact forces do not blow up).
A fresh measurement ``Y`` taken ``T_m`` after the previous one applies the
correction of (25) integrated over ``T_m`` with the innovation held
(``X_hat += T_m L G_x (X_hat - Y)``, ``Z_hat += T_m L^2 G_z (X_hat - Y)``).
As ``T_m -> 0`` this is (25); for finite ``T_m`` the error map is
``C(T_m) Phi(T_m)``, whose spectral radius :func:`sampled_error_radius` checks.

Latency.  With ``delay_compensation`` the innovation uses the estimate stored
at the acquisition tick (``X_hat(t_acq) - Y``) rather than the current one.

Safe handling.  A non-finite measurement is rejected (not used, counted in
``rejected``): the observer keeps predicting.  An optional innovation gate
(``innovation_gate_m > 0``) rejects measurements whose innovation norm exceeds
it; the paper has none (``0``, default).
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from typing import Any, Literal, Protocol

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.blas_free import hypot_axes
from vesselbot_ros.config import ConfigError, check_choice, check_finite, check_nonnegative, check_positive
from vesselbot_ros.control.compiled_stage import CompiledObserver, flat_view, lazy_step, observer_step_type
from vesselbot_ros.control.ekf_params import EkfParams
from vesselbot_ros.control.estimate import Estimate
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics.integrator import (
    G_ROW,
    OK,
    U_ROW,
    axes_of,
    failure_message,
    integrate,
    integrator_vector,
    new_workspace,
)

#: Estimates kept for delay compensation (one per update).
HISTORY_LEN = 4096

__all__ = [
    "ObserverParams",
    "Estimate",
    "HighGainObserver",
    "axis_gains",
    "linearised_error_matrix",
    "sampled_error_radius",
    "check_frame_period",
    "ObserverModel",
    "HISTORY_LEN",
    "observer_params",
    "observer_out_size",
    "input_accel",
    "integrator_vector",
    "observer_update",
    "hgo_step",
]


class ObserverModel(Protocol):
    """What the observer needs from the dynamics model (see :mod:`vesselbot_ros.control.model`)."""

    input_matrix: npt.NDArray[np.float64]

    def new_contact_state(self) -> npt.NDArray[np.float64]: ...

    def propagate(
        self,
        t0_s: float,
        t1_s: float,
        y: npt.NDArray[np.float64],
        u_m_per_s2: npt.NDArray[np.float64],
        contact: npt.NDArray[np.float64],
    ) -> None: ...


@dataclasses.dataclass(frozen=True)
class ObserverParams:
    """High-gain observer parameters (Table III: ``L, g1..g4 = 5, -6, -13, -12, -4``).

    Attributes:
        high_gain: ``L`` (1/s), > 0.
        g1: Gain g1 (-), < 0.
        g2: Gain g2 (-), < 0.
        g3: Gain g3 (-), < 0.
        g4: Gain g4 (-), < 0.
        gain_layout: ``per_axis`` or ``per_equation`` (see module docstring).
        init_from_first_measurement: Set ``X_hat`` to the first measurement
            (``Z_hat`` stays at its prior) instead of correcting from the prior.
        delay_compensation: Form the innovation with the estimate stored at
            the acquisition time of the frame.
        innovation_gate_m: Reject a measurement whose innovation norm exceeds
            this (m); 0 disables the gate (paper).
        kind: ``high_gain``: observer (25) with the gains above (paper);
            ``ekf``: the extended Kalman filter of
            :mod:`vesselbot_ros.control.ekf_observer` with the settings in ``ekf``
            (estimates the blood-velocity scale, chi-square gate, delay compensation).
        ekf: Extended Kalman filter settings (``kind: ekf`` only).
    """

    high_gain: float = 5.0
    g1: float = -6.0
    g2: float = -13.0
    g3: float = -12.0
    g4: float = -4.0
    gain_layout: Literal["per_axis", "per_equation"] = "per_axis"
    init_from_first_measurement: bool = True
    delay_compensation: bool = False
    innovation_gate_m: float = 0.0
    kind: Literal["high_gain", "ekf"] = "high_gain"
    ekf: EkfParams = dataclasses.field(default_factory=EkfParams)

    def __post_init__(self) -> None:
        check_choice("kind", self.kind, ("high_gain", "ekf"))
        check_positive("high_gain", self.high_gain)
        for name in ("g1", "g2", "g3", "g4"):
            v = getattr(self, name)
            check_finite(name, v)
            if v >= 0.0:
                raise ConfigError(f"{name} must be < 0 (Hurwitz error dynamics), got {v!r}")
        check_choice("gain_layout", self.gain_layout, ("per_axis", "per_equation"))
        check_nonnegative("innovation_gate_m", self.innovation_gate_m)


def axis_gains(params: ObserverParams, dims: int = 2) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Diagonals of ``G_x`` and ``G_z``: ``(gx, gz)``, each (dims,): over (x, z), or (x, y, z) where y, across the
    scanner's bore as z is, takes z's pair (so a tree in the plane y = 0 sees the planar gains on x and z)."""
    if params.gain_layout == "per_axis":
        gx, gz = np.array([params.g1, params.g3]), np.array([params.g2, params.g4])
    else:
        gx, gz = np.array([params.g1, params.g2]), np.array([params.g3, params.g4])
    if dims == 3:  # axis count: y, across the bore as z is, takes z's pair
        return np.array([gx[0], gx[1], gx[1]]), np.array([gz[0], gz[1], gz[1]])
    return gx, gz


def input_accel(b: npt.NDArray[np.float64], g: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """``U = B G`` by fixed-order scalar sums, row by row (not BLAS: :mod:`vesselbot_ros.blas_free`); (d,)."""
    d = g.shape[0]
    u = np.empty(d)
    for i in range(d):
        acc = float(b[i, 0]) * float(g[0])
        for j in range(1, d):
            acc = acc + float(b[i, j]) * float(g[j])
        u[i] = acc
    return u


def linearised_error_matrix(
    params: ObserverParams,
    dF_dX: npt.ArrayLike | None = None,
    dF_dZ: npt.ArrayLike | None = None,
) -> npt.NDArray[np.float64]:
    """(4, 4) matrix ``A`` of the linearised error ``ed = A e``, ``e = (X_hat - X, Z_hat - Z)``; (..., 4, 4) for
    stacked Jacobians (..., 2, 2), one matrix per pair.

    ``A = [[L G_x, I], [L^2 G_z + dF/dX, dF/dZ]]``.

    Args:
        params: Observer gains.
        dF_dX: (2, 2) or (..., 2, 2) Jacobian of ``F`` w.r.t. position (1/s^2); zero if None.
        dF_dZ: (2, 2) or (..., 2, 2) Jacobian of ``F`` w.r.t. velocity (1/s); zero if None.
    """
    gx, gz = axis_gains(params)
    L = params.high_gain
    jx = np.zeros((2, 2)) if dF_dX is None else np.asarray(dF_dX, dtype=np.float64)
    jz = np.zeros((2, 2)) if dF_dZ is None else np.asarray(dF_dZ, dtype=np.float64)
    a = np.zeros((*np.broadcast_shapes(jx.shape[:-2], jz.shape[:-2]), 4, 4))
    a[..., :2, :2] = L * np.diag(gx)
    a[..., :2, 2:] = np.eye(2)
    a[..., 2:, :2] = L**2 * np.diag(gz) + jx
    a[..., 2:, 2:] = jz
    return a


def check_frame_period(params: ObserverParams, period_s: float, frame_rate_Hz: float | None = None) -> None:
    """Raise ConfigError unless observer (25) with ``params`` is stable at one frame per ``period_s``: the sampled
    error map's spectral radius (:func:`sampled_error_radius`) must be < 1.  The frames come at the imager's
    ``frame_rate_Hz`` (given: the message names it), else one per sequence period (the message names the
    sequence's keys)."""
    rho = sampled_error_radius(params, period_s)
    if rho < 1.0:
        return
    if frame_rate_Hz is None:
        raise ConfigError(
            f"observer gains are unstable at the sequence's frame rate: with sequence.mode 'multiplexed' "
            f"observer (25) gets one frame per sequence period (sequence.tracking_window_s + 2 dead_time_s + "
            f"propulsion_window_s = {period_s:.6g} s, {1.0 / period_s:.4g} frames/s; imager.frame_rate_Hz is "
            f"unused): sampled error map has spectral radius {rho:.3f} >= 1, the rule is < 1 (lower "
            f"observer.high_gain, shorten the sequence's windows or use observer.kind 'ekf')")
    raise ConfigError(
        f"observer gains are unstable at imager.frame_rate_Hz={frame_rate_Hz!r}: "
        f"sampled error map has spectral radius {rho:.3f} >= 1 (lower observer.high_gain or raise the rate)")


def sampled_error_radius(params: ObserverParams, period_s: float) -> float:
    """Spectral radius of the sampled error map ``C(T) Phi(T)`` (free flow, F = 0).

    ``Phi(T) = [[I, T I], [0, I]]`` is the prediction over one measurement
    period and ``C(T) = [[I + T L G_x, 0], [T L^2 G_z, I]]`` the correction.
    The sampled observer converges in free flow iff the radius is < 1.
    """
    if not period_s > 0.0:
        raise ConfigError(f"measurement period must be > 0, got {period_s!r}")
    gx, gz = axis_gains(params)
    L = params.high_gain
    phi = np.block([[np.eye(2), period_s * np.eye(2)], [np.zeros((2, 2)), np.eye(2)]])
    c = np.block([[np.eye(2) + period_s * L * np.diag(gx), np.zeros((2, 2))], [period_s * L**2 * np.diag(gz), np.eye(2)]])
    return float(np.max(np.abs(np.linalg.eigvals(c @ phi))))


class HighGainObserver:
    """Sampled high-gain observer (25) on the model's axes (two in the plane, three in a 3-D tree); call
    :meth:`update` once per tick.

    Ports: inputs ``measurement`` (or None) and ``applied_gradient_prev`` (the
    gradient the coil actually applied over the last tick, T/m); output
    :class:`Estimate`.

    Args:
        params: Observer gains and options.
        model: Dynamics model with the controller's (possibly wrong) parameters.
        x_hat0: (d,) prior position, m (its length is the axis count).
        z_hat0: (d,) prior velocity, m/s (zero if None).
        t0_s: Time of the prior (s).
    """

    def __init__(
        self,
        params: ObserverParams,
        model: Any,
        x_hat0: npt.ArrayLike,
        z_hat0: npt.ArrayLike | None = None,
        t0_s: float = 0.0,
    ) -> None:
        x0 = np.asarray(x_hat0, dtype=np.float64)
        z0 = np.zeros_like(x0) if z_hat0 is None else np.asarray(z_hat0, dtype=np.float64)
        d = x0.shape[0] if x0.ndim == 1 else 0
        y = np.concatenate([x0.ravel(), z0.ravel()])
        if d not in (2, 3) or y.shape != (2 * d,) or not np.all(np.isfinite(y)):
            raise ModelInputError(f"observer prior must be finite (d,) + (d,), d = 2 or 3, got {x_hat0!r}, {z_hat0!r}")
        self.dims = d
        self.params = params
        self.model = model
        gx, gz = axis_gains(params, d)
        self._kx = params.high_gain * gx
        self._kz = params.high_gain**2 * gz
        self._b = np.array(model.input_matrix, dtype=np.float64).reshape(d, d)  # U = B G, fixed-order sums
        self._y = y
        self._t = float(t0_s)
        self._contact = model.new_contact_state()
        self._t_meas = -math.inf
        self._initialised = False
        self._history: deque[tuple[float, npt.NDArray[np.float64]]] = deque(maxlen=HISTORY_LEN)
        self.rejected = 0
        # A DynamicsModel (planar or 3-D) is the kernel at packed params: then update() runs the compiled
        # observer_update (as the compiled loop does); any other ObserverModel runs in Python.
        self._compiled = all(hasattr(model, a) for a in ("geom", "integrator", "stats", "_work", "_fbuf", "_sc"))
        if self._compiled:
            self.params_vector = observer_params(params, self._b)
            self._ig = integrator_vector(model.integrator)
            self._scal = np.array([self._t, -math.inf, 0.0, model.integrator.max_step_s])
            self._hist = np.empty((HISTORY_LEN, 1 + d))
            self._hist_n = np.zeros(2, dtype=np.int64)
            self._out = np.zeros(observer_out_size(d))
            self._g = np.zeros(d)
            self._m = np.zeros(d)

    @property
    def state(self) -> npt.NDArray[np.float64]:
        """(2 d,) ``(x_hat, z_hat)`` copy: position (m) then velocity (m/s)."""
        return self._y.copy()

    def compiled(self) -> CompiledObserver:
        """This observer in the compiled loop's form (:mod:`vesselbot_ros.control.compiled_stage`), now.

        Raises:
            ModelInputError: its model is not a compiled one (a user's ``propagate``).
        """
        if not self._compiled:
            raise ModelInputError("the compiled loop needs the observer's model to be a DynamicsModel")
        d = self.dims
        work, fbuf, sc = new_workspace(d)
        state = np.concatenate([self._scal, self._y, self._contact, self._hist.ravel()])
        return CompiledObserver(hgo_step, np.concatenate([self.params_vector, self._ig]), state, self._hist_n,
                                np.concatenate([work.ravel(), fbuf.ravel(), sc.ravel()]), self.model.geom, _failure)

    def update(
        self,
        t_s: float,
        measurement: Any | None,
        applied_gradient_prev: npt.ArrayLike,
    ) -> Estimate:
        """Predict to ``t_s`` under the applied gradient, then correct if a frame arrived.

        Args:
            t_s: Tick time (s), non-decreasing.
            measurement: A :class:`~vesselbot_ros.scanner.imager_model.Measurement`
                (``t_acq_s``, ``p``) delivered at this tick, or None.
            applied_gradient_prev: (d,) gradient applied by the coil since the
                previous tick (T/m).

        Returns:
            The :class:`Estimate` at ``t_s``.

        Raises:
            ModelInputError: on a non-finite or backwards time or a non-finite
                applied gradient (the coil output is always finite).
        """
        d = self.dims
        g = np.asarray(applied_gradient_prev, dtype=np.float64)
        if g.shape != (d,) or not bool(np.isfinite(g).all()):
            raise ModelInputError(f"observer: applied gradient must be a finite ({d},) array, got {applied_gradient_prev!r}")
        if not math.isfinite(t_s) or t_s < self._t - 1e-12:
            raise ModelInputError(f"observer: time must be finite and non-decreasing, got {t_s!r} after {self._t!r}")
        if self._compiled:
            return self._update_compiled(float(t_s), measurement, g)
        if t_s > self._t:
            self.model.propagate(self._t, t_s, self._y, input_accel(self._b, g), self._contact)
            if not bool(np.isfinite(self._y).all()):
                raise ModelInputError(f"observer: prediction became non-finite at t={t_s!r}")
        self._t = float(t_s)
        if self.params.delay_compensation:
            self._history.append((self._t, self._y[:d].copy()))
        used = False
        rejected = False
        innov = np.zeros(d)
        if measurement is not None:
            yp = np.asarray(measurement.p, dtype=np.float64)
            t_acq = float(measurement.t_acq_s)
            if yp.shape != (d,) or not (bool(np.isfinite(yp).all()) and math.isfinite(t_acq)):
                rejected = True
            elif not self._initialised and self.params.init_from_first_measurement:
                self._y[:d] = yp
                self._t_meas = t_acq
                self._initialised = True
                used = True
            else:
                x_ref = self._estimate_at(t_acq) if self.params.delay_compensation else self._y[:d]
                innov = x_ref - yp
                gate = self.params.innovation_gate_m
                if gate > 0.0 and math.hypot(*innov) > gate:
                    rejected = True
                    innov = np.zeros(d)
                else:
                    tm = t_acq - self._t_meas if math.isfinite(self._t_meas) else 0.0
                    if tm > 0.0:
                        self._y[:d] += tm * self._kx * innov
                        self._y[d:] += tm * self._kz * innov
                    self._t_meas = t_acq
                    self._initialised = True
                    used = True
            if rejected:
                self.rejected += 1
        age = self._t - self._t_meas
        return Estimate(self._t, self._y[:d].copy(), self._y[d:].copy(), age, innov, used, rejected)

    def _update_compiled(self, t_s: float, measurement: Any | None, g: npt.NDArray[np.float64]) -> Estimate:
        d = self.dims
        has, t_acq, m = False, math.nan, self._m
        m[:] = math.nan
        if measurement is not None:
            has, t_acq = True, float(measurement.t_acq_s)
            mp = np.asarray(measurement.p, dtype=np.float64)
            if mp.shape == (d,):  # a wrong shape travels as NaN: rejected like any non-finite frame
                m[:] = mp
        md = self.model
        t0 = self._t
        self._g[:] = g
        code = observer_update(self.params_vector, self._scal, self._y, self._contact, self._hist, self._hist_n, self._ig,
                               md.geom, md.stats, md._work, md._fbuf, md._sc, t_s, self._g, has, t_acq, m, self._out)
        if code != OK:
            raise ModelInputError(failure_message("observer model", t0, t_s, code, self._y.tolist()))
        self._t = t_s
        self._t_meas = float(self._scal[1])
        self._initialised = bool(self._scal[2] > 0.5)
        o = self._out
        rejected = bool(o[3 * d + 2] > 0.5)
        self.rejected += int(rejected)
        return Estimate(self._t, o[0:d].copy(), o[d:2 * d].copy(), float(o[2 * d]), o[2 * d + 1:3 * d + 1].copy(),
                        bool(o[3 * d + 1] > 0.5), rejected)

    def _estimate_at(self, t_acq: float) -> npt.NDArray[np.float64]:
        best = self._y[:self.dims]
        for t, x in reversed(self._history):
            best = x
            if t <= t_acq + 1e-9:
                break
        return best.copy()


# ---- compiled stage -------------------------------------------------------------------------------
# On d axes (2: x, z; 3: x, y, z), read from the gradient array's length:
# params (2 d + d^2 + 3,): [kx (d), kz (d), B (d x d, row-major), delay_compensation, innovation_gate_m, init_from_first]
# scal (4,): [t (s), t of the last accepted measurement (s, -inf before), initialised (0/1), next integrator step (s)]
# y (2 d,) estimate (X, Z); contact (4,) model contact state; hist (HISTORY_LEN, 1 + d) ring of (t, X) and
# hist_n (2,) int64 [count, next slot]; ig (7,) from integrator_vector; geom the model's vessel (physics.integrator);
# stats (4,) int64 model integrator counters; work, fbuf, sc the model's integrator workspace
# out (3 d + 3,): [X (d), Z (d), time since measurement, innovation (d), used (0/1), rejected (0/1)]


def observer_out_size(dims: int) -> int:
    """Length of :func:`observer_update`'s ``out`` on ``dims`` axes."""
    return 3 * int(dims) + 3


def observer_params(params: ObserverParams, b: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Parameter vector of :func:`observer_update` (gains as :class:`HighGainObserver` forms them; ``b`` the model's
    input matrix, (d, d))."""
    bm = np.asarray(b, dtype=np.float64)
    d = int(round(math.sqrt(bm.size)))
    gx, gz = axis_gains(params, d)
    kx = params.high_gain * gx
    kz = params.high_gain**2 * gz
    return np.array([*kx, *kz, *bm.reshape(-1), 1.0 if params.delay_compensation else 0.0,
                     float(params.innovation_gate_m), 1.0 if params.init_from_first_measurement else 0.0])


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on the views it passes (physics.integrator)
def observer_update(prm, scal, y, contact, hist, hist_n, ig, geom, stats, work, fbuf, sc,  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
                    t, g, has_meas, t_acq, m, out):
    """:meth:`HighGainObserver.update` over explicit state (same doubles), on the axes of ``g`` (d,).

    Predicts ``y`` from ``scal[0]`` to ``t`` under ``U = B g`` with the
    model's integrator in the vessel ``geom``, then corrects with the measurement
    ``m`` (d,) acquired at ``t_acq`` if ``has_meas``.  The caller checks that ``t`` is
    finite and not before ``scal[0]`` and that the gradient is finite.

    Returns:
        The model integrator's code (``OK`` = 0); on failure ``y`` holds the
        state reached and nothing else changed.
    """
    d = axes_of(geom)  # the axes, a constant at compile time (the loops below unroll); g's length
    ob = 2 * d  # B's offset in prm
    oo = ob + d * d  # the options' offset
    if t > scal[0]:
        gz = work[G_ROW, :d]  # no gradient: the model's input is the acceleration U = B g
        u = work[U_ROW, :d]
        for i in range(d):
            gz[i] = 0.0
            acc = prm[ob + i * d] * g[0]
            for j in range(1, d):
                acc = acc + prm[ob + i * d + j] * g[j]
            u[i] = acc
        code, h = integrate(scal[0], t, y, gz, u, contact, geom, scal[3], ig, stats, work, fbuf, sc)
        scal[3] = h
        if code != OK:
            return code
    scal[0] = t
    if prm[oo] > 0.5:
        j = hist_n[1]
        hist[j, 0] = t
        for c in range(d):
            hist[j, 1 + c] = y[c]
        hist_n[1] = (j + 1) % hist.shape[0]
        if hist_n[0] < hist.shape[0]:
            hist_n[0] += 1
    used = 0.0
    rejected = 0.0
    innov = out[2 * d + 1:3 * d + 1]
    for c in range(d):
        innov[c] = 0.0
    if has_meas:
        finite = math.isfinite(t_acq)
        for c in range(d):
            finite = finite and math.isfinite(m[c])
        if not finite:
            rejected = 1.0
        elif scal[2] < 0.5 and prm[oo + 2] > 0.5:
            for c in range(d):
                y[c] = m[c]
            scal[1] = t_acq
            scal[2] = 1.0
            used = 1.0
        else:
            for c in range(d):
                innov[c] = y[c]
            if prm[oo] > 0.5:  # the newest estimate stored at or before t_acq (else the oldest)
                for i in range(hist_n[0]):
                    j = (hist_n[1] - 1 - i) % hist.shape[0]
                    for c in range(d):
                        innov[c] = hist[j, 1 + c]
                    if hist[j, 0] <= t_acq + 1e-9:
                        break
            for c in range(d):
                innov[c] = innov[c] - m[c]
            if prm[oo + 1] > 0.0 and hypot_axes(innov) > prm[oo + 1]:
                rejected = 1.0
                for c in range(d):
                    innov[c] = 0.0
            else:
                tm = t_acq - scal[1] if math.isfinite(scal[1]) else 0.0
                if tm > 0.0:
                    for c in range(d):
                        y[c] = y[c] + tm * prm[c] * innov[c]
                    for c in range(d):
                        y[d + c] = y[d + c] + tm * prm[d + c] * innov[c]
                scal[1] = t_acq
                scal[2] = 1.0
                used = 1.0
    for c in range(2 * d):
        out[c] = y[c]
    out[2 * d] = scal[0] - scal[1]
    out[3 * d + 1] = used
    out[3 * d + 2] = rejected
    return OK


# ---- the compiled loop's form (control/compiled_stage.py's observer signature) -------------------------------------
# prm: observer_params | integrator vector (7); state: scal (4) | y (2 d) | contact (4) | hist (HISTORY_LEN x (1 + d));
# istate: hist_n (2); work: the integrator workspace (work (12 x 2 d) | fbuf (8 x d) | sc (4 x d))
def _hgo_step(prm, state, istate, geom, work, stats, t, g, has_meas, t_acq, m, out, err):  # type: ignore[no-untyped-def]  # numba kernel: typed by observer_step_type
    """:func:`observer_update` as a compiled observer step: err = [t0, t, integrator code, the state reached]."""
    d = axes_of(geom)  # the axes, a constant at compile time (the loops unroll)
    n_prm = 2 * d + d * d + 3
    scal = state[0:4]
    y = state[4:4 + 2 * d]
    contact = state[4 + 2 * d:8 + 2 * d]
    hist = flat_view(state, 8 + 2 * d, (HISTORY_LEN, 1 + d))
    w = flat_view(work, 0, (12, 2 * d))
    fbuf = flat_view(work, 24 * d, (8, d))
    sc = flat_view(work, 32 * d, (4, d))
    t0 = scal[0]
    code = observer_update(prm[0:n_prm], scal, y, contact, hist, istate[0:2], prm[n_prm:n_prm + 7], geom, stats, w, fbuf,
                           sc, t, g, has_meas, t_acq, m, out)
    out[3 * d + 3] = 1.0  # observer (25) does not estimate the blood-velocity scale
    if code != OK:
        err[0] = t0
        err[1] = t
        err[2] = code
        for i in range(2 * d):
            err[3 + i] = y[i]
    return code


hgo_step = lazy_step(_hgo_step, observer_step_type)


def _failure(err: npt.NDArray[np.float64]) -> str:
    """The per-tick loop's error of a failed prediction (:func:`_hgo_step`'s ``err``)."""
    d = (len(err) - 4) // 2
    return failure_message("observer model", float(err[0]), float(err[1]), int(err[2]), err[3:3 + 2 * d].tolist())
