"""Adaptive backstepping: on-line estimates of the linear parameters of law (24).

Section III-D of Arcese et al. (2012) points to their adaptive backstepping
(ref. [39], ICRA 2011) for parameters that enter the dynamics linearly, e.g. the
magnetisation ``M`` or ``q^2 / eps``.  This module is that law for the two
parameters whose error our scenarios carry:

* the **blood-velocity scale** ``s`` (true ``V_f`` = ``s`` x the model's): the
  drag, linear in the relative velocity in the Stokes regime, is then nearly
  linear in ``s``, with regressor ``phi_s = dF/ds`` (a finite difference of the
  model's ``F`` at the current ``s_hat``, since the drag coefficient of eq. (8)
  is not exactly Stokes);
* the **magnetisation scale** ``m`` (true ``M`` = ``m`` x the model's): the
  motive acceleration is ``m B G``, with regressor ``phi_m = B G``.

With ``e1 = X - X_ref``, the stabilising function ``alpha = Xd_ref - k1 e1`` and
``e2 = Z - alpha``, law (24) is the backstepping law
``U = alphad - e1 - k2 e2 - F`` and ``V = |e1|^2/2 + |e2|^2/2`` decreases as
``-k1 |e1|^2 - k2 |e2|^2 + e2 . (F_true - F_model)``.  With the parameter
errors ``s~ = s - s_hat``, ``m~ = m - m_hat``, ``F_true - F_model ~ phi_s s~ +
phi_m m~``, and the update laws::

    s_hat' = gamma_s  phi_s . e2          m_hat' = gamma_m  phi_m . e2

cancel the cross terms of ``V + s~^2/(2 gamma_s) + m~^2/(2 gamma_m)``, whose
derivative is then ``-k1 |e1|^2 - k2 |e2|^2 <= 0``.  The controller then uses
``F`` at ``s_hat`` and divides its gradient by ``m_hat``.  The estimates are
projected onto ``[scale_min, scale_max]`` (projection keeps the Lyapunov
argument and bounds the drift that noise on the estimated state ``e2`` would
otherwise cause); adaptation pauses while the estimate is stale.  The update
is explicit Euler over the time since the last command.
"""

from __future__ import annotations

import dataclasses
import math

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.config import ConfigError, check_finite, check_positive

__all__ = ["AdaptiveParams", "AdaptiveState", "adaptation_step", "adaptive_params", "adapt_scales"]


@dataclasses.dataclass(frozen=True)
class AdaptiveParams:
    """Adaptation gains and bounds of ``kind: adaptive_backstepping``.

    Attributes:
        flow_scale_gain_s3_per_m2: ``gamma_s`` of ``s_hat' = gamma_s phi_s . e2``
            (``phi_s`` in m/s^2, ``e2`` in m/s); 0 = do not adapt ``s``.
        magnetization_gain_s3_per_m2: ``gamma_m`` of ``m_hat' = gamma_m phi_m . e2``
            (``phi_m = B G`` in m/s^2); 0 = do not adapt ``m``.
        scale_min: Lower bound of both scales (projection), > 0.
        scale_max: Upper bound of both scales (projection), > ``scale_min``.
        regressor_step: Step of the finite difference ``dF/ds`` (-).
    """

    flow_scale_gain_s3_per_m2: float = 50.0
    magnetization_gain_s3_per_m2: float = 0.0
    scale_min: float = 0.5
    scale_max: float = 2.0
    regressor_step: float = 1.0e-3

    def __post_init__(self) -> None:
        for name in ("flow_scale_gain_s3_per_m2", "magnetization_gain_s3_per_m2"):
            value = getattr(self, name)
            check_finite(name, value)
            if value < 0.0:
                raise ConfigError(f"{name} must be >= 0, got {value!r}")
        check_positive("scale_min", self.scale_min)
        check_finite("scale_max", self.scale_max)
        if not self.scale_max > self.scale_min:
            raise ConfigError(f"scale_max must be > scale_min ({self.scale_min!r}), got {self.scale_max!r}")
        check_positive("regressor_step", self.regressor_step)
        if not self.scale_min <= 1.0 or not self.scale_max >= 1.0:
            raise ConfigError(f"scale_min..scale_max must contain 1 (the model's own value), got "
                              f"{self.scale_min!r}..{self.scale_max!r}")


@dataclasses.dataclass
class AdaptiveState:
    """The adapted scales and the time of the last update (mutable, owned by the controller)."""

    flow_scale: float = 1.0
    magnetization_scale: float = 1.0
    t_last_s: float = math.nan


def adaptive_params(params: AdaptiveParams, input_matrix: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """(5 + d^2,) vector of :func:`adapt_scales` and ``backstepping.adaptive_command``: ``[gamma_s, gamma_m,
    scale_min, scale_max, regressor_step, B (d x d, row-major)]``."""
    return np.array([float(params.flow_scale_gain_s3_per_m2), float(params.magnetization_gain_s3_per_m2),
                     float(params.scale_min), float(params.scale_max), float(params.regressor_step),
                     *np.asarray(input_matrix, dtype=np.float64).ravel()])


@numba.njit(cache=True, nogil=True)
def _dot(a, b):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    acc = a[0] * b[0]
    for i in range(1, a.shape[0]):
        acc = acc + a[i] * b[i]
    return acc


@numba.njit(cache=True, nogil=True)
def adapt_scales(aprm, ast, t, e2, phi_s, phi_m):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The update laws on arrays: ``ast`` (3,) ``[s_hat, m_hat, time of the last update]``, in place; ``e2``,
    ``phi_s``, ``phi_m`` (d,).

    ``aprm`` from :func:`adaptive_params`.  Explicit Euler over the time since the
    last update, projected onto ``[scale_min, scale_max]``; the first call (time
    nan) and a repeated tick only record the time.  Every reading of the law
    (:func:`adaptation_step`, the controller in Python or compiled) runs this.
    """
    dt = t - ast[2]
    ast[2] = t
    if not dt > 0.0:
        return
    lo = aprm[2]
    hi = aprm[3]
    if aprm[0] > 0.0:
        ds = dt * aprm[0] * _dot(phi_s, e2)
        ast[0] = min(hi, max(lo, ast[0] + ds))
    if aprm[1] > 0.0:
        dm = dt * aprm[1] * _dot(phi_m, e2)
        ast[1] = min(hi, max(lo, ast[1] + dm))


def adaptation_step(
    prm: AdaptiveParams,
    state: AdaptiveState,
    t_s: float,
    e2: npt.ArrayLike,
    phi_s: npt.ArrayLike,
    phi_m: npt.ArrayLike,
) -> None:
    """Advance the estimates to ``t_s`` (explicit Euler, projected), in place.

    Args:
        prm: Gains and bounds.
        state: Estimates, updated.
        t_s: Time of this command (s); the first call only records it.
        e2: ``Z - Xd_ref + k1 (X - X_ref)`` on the estimate (m/s).
        phi_s: ``dF/ds`` at ``s_hat`` (m/s^2).
        phi_m: ``B G`` of the gradient applied since the last update (m/s^2).
    """
    ast = np.array([state.flow_scale, state.magnetization_scale, state.t_last_s], dtype=np.float64)
    e = np.asarray(e2, dtype=np.float64)
    adapt_scales(adaptive_params(prm, np.eye(e.shape[0])), ast, float(t_s), e, np.asarray(phi_s, dtype=np.float64),
                 np.asarray(phi_m, dtype=np.float64))
    state.flow_scale, state.magnetization_scale, state.t_last_s = float(ast[0]), float(ast[1]), float(ast[2])
