"""Where the reference may run: the wall band in which the observer (25) is unstable.

Section III-A2 puts the reference "near the upper wall" of an artery, where
``F_m/F_tot`` is largest.  Two things bound how near:

* the linearised error of the high-gain observer (25),
  ``A = [[L G_x, I], [L^2 G_z + dF/dX, dF/dZ]]``
  (:func:`~vesselbot_ros.control.high_gain_observer.linearised_error_matrix`),
  loses stability where the attractive wall forces grow faster towards the
  wall than the observer's ``L^2 |g_z|`` can correct (``dF_z/dz`` large and
  positive);
* the vessel breathes, eq. (13): the upper wall comes down to
  ``D (1 - pulsation) / 2`` once per heartbeat.

:func:`observer_unstable_gap_m` scans the kernel's Jacobian (central
differences) along ``z`` at the narrowest diameter and returns the widest gap
at which ``A`` has an eigenvalue with a positive real part.
:func:`wall_safe_delta_m` turns it into the largest ``Delta`` (centre height)
the reference may use: ``D_min/2 - r - band - margin``.  Feed it to
:func:`~vesselbot_ros.control.bspline_reference.propose_anchors` as the bound
of ``delta_grid_m``.
"""

from __future__ import annotations

import math

import numpy as np

from vesselbot_ros.config import check_nonnegative, check_positive
from vesselbot_ros.control.high_gain_observer import ObserverParams, linearised_error_matrix
from vesselbot_ros.physics.kernel import accel_no_motive
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.vessels.cfd import packed_params

__all__ = ["observer_error_jacobian", "observer_unstable_gap_m", "wall_safe_delta_m"]


def _narrowest_time_s(physics: PhysicsParams) -> float:
    """First t >= 0 (s) at which D(t) = D (1 - pulsation), i.e. sin(w t + phi) = -1."""
    f = physics.flow
    if f.angular_frequency_rad_per_s == 0.0:
        return 0.0
    t = (1.5 * math.pi - f.phase_rad) / f.angular_frequency_rad_per_s
    period = 2.0 * math.pi / f.angular_frequency_rad_per_s
    return t % period


def observer_error_jacobian(
    physics: PhysicsParams, t_s: float, z_m: float, vx_m_per_s: float, observer: ObserverParams
) -> np.ndarray:
    """(4, 4) linearised observer error matrix at centre height ``z_m`` (m), robot moving at ``vx`` (m/s)."""
    p = packed_params(physics)
    c = np.zeros(4)
    hz, hv = 1e-9, 1e-6
    state = [0.0, z_m, vx_m_per_s, 0.0]

    def accel(s: list[float]) -> np.ndarray:
        """The compiled acceleration at state ``s`` = (x, z, vx, vz) with no motive force."""
        return np.array(accel_no_motive(t_s, s[0], s[1], s[2], s[3], c, p))

    jx = np.zeros((2, 2))
    jv = np.zeros((2, 2))
    for j, (idx, h) in enumerate(((0, hz), (1, hz))):
        sp, sm = list(state), list(state)
        sp[idx] += h
        sm[idx] -= h
        jx[:, j] = (accel(sp) - accel(sm)) / (2 * h)
    for j, (idx, h) in enumerate(((2, hv), (3, hv))):
        sp, sm = list(state), list(state)
        sp[idx] += h
        sm[idx] -= h
        jv[:, j] = (accel(sp) - accel(sm)) / (2 * h)
    return linearised_error_matrix(observer, jx, jv)


def observer_unstable_gap_m(
    physics: PhysicsParams,
    observer: ObserverParams,
    vx_m_per_s: float = 0.01,
    gap_max_m: float = 1e-3,
    n: int = 2000,
) -> float:
    """Widest gap (m) to the upper wall at which the observer error is unstable.

    Scans ``n`` gaps in ``(0, gap_max_m]`` (geometric spacing from 10 nm) at
    the narrowest diameter; returns 0 if it is stable everywhere.

    Args:
        physics: The observer's model physics.
        observer: Observer gains.
        vx_m_per_s: Axial robot velocity of the linearisation (m/s).
        gap_max_m: Widest gap scanned (m).
        n: Number of gaps.
    """
    check_positive("gap_max_m", gap_max_m)
    t = _narrowest_time_s(physics)
    half = 0.5 * physics.vessel.diameter_m * (1.0 - physics.flow.diameter_pulsation)
    r = physics.robot.radius_m
    worst = 0.0
    for gap in np.geomspace(1e-8, gap_max_m, n):
        a = observer_error_jacobian(physics, t, half - r - gap, vx_m_per_s, observer)
        if np.max(np.linalg.eigvals(a).real) > 0.0:
            worst = max(worst, float(gap))
    return worst


def wall_safe_delta_m(physics: PhysicsParams, observer: ObserverParams, margin_m: float, vx_m_per_s: float = 0.01) -> float:
    """Largest centre height ``Delta`` (m) keeping ``margin_m`` outside the unstable band at the narrowest D.

    ``D (1 - pulsation)/2 - r - observer_unstable_gap_m - margin_m``.
    """
    check_nonnegative("margin_m", margin_m)
    band = observer_unstable_gap_m(physics, observer, vx_m_per_s)
    half = 0.5 * physics.vessel.diameter_m * (1.0 - physics.flow.diameter_pulsation)
    return half - physics.robot.radius_m - band - margin_m
