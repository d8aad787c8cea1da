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

from vesselbot_ros.config import ConfigError, check_finite, check_positive

__all__ = ["AdaptiveParams", "AdaptiveState", "adaptation_step"]


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
        if not 1.0 >= self.scale_min or not self.scale_max >= 1.0:
            raise ConfigError(f"scale_min..scale_max must contain 1 (the model's own value), got "
                              f"{self.scale_min!r}..{self.scale_max!r}")


@dataclasses.dataclass
class AdaptiveState:
    """The adapted scales and the time of the last update (mutable, owned by the controller)."""

    flow_scale: float = 1.0
    magnetization_scale: float = 1.0
    t_last_s: float = math.nan


def adaptation_step(
    prm: AdaptiveParams,
    state: AdaptiveState,
    t_s: float,
    e2: tuple[float, float],
    phi_s: tuple[float, float],
    phi_m: tuple[float, float],
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
    dt = t_s - state.t_last_s
    state.t_last_s = t_s
    if not dt > 0.0:  # first call (nan) or a repeated tick
        return
    lo, hi = prm.scale_min, prm.scale_max
    if prm.flow_scale_gain_s3_per_m2 > 0.0:
        ds = dt * prm.flow_scale_gain_s3_per_m2 * (phi_s[0] * e2[0] + phi_s[1] * e2[1])
        state.flow_scale = min(hi, max(lo, state.flow_scale + ds))
    if prm.magnetization_gain_s3_per_m2 > 0.0:
        dm = dt * prm.magnetization_gain_s3_per_m2 * (phi_m[0] * e2[0] + phi_m[1] * e2[1])
        state.magnetization_scale = min(hi, max(lo, state.magnetization_scale + dm))
