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

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.config import check_nonnegative, check_positive
from vesselbot_ros.control.high_gain_observer import ObserverParams, linearised_error_matrix
from vesselbot_ros.physics.kernel import accel_no_motive
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.vessels.cfd import packed_params

__all__ = ["observer_error_jacobian", "observer_error_matrices", "observer_unstable_gap_m", "wall_safe_delta_m"]


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
    """(4, 4) linearised observer error matrix at centre height ``z_m`` (m), robot moving at ``vx`` (m/s): the
    kernel's acceleration without motive force, differentiated centrally (steps 1 nm, 1 um/s)."""
    return observer_error_matrices(physics, t_s, np.array([z_m], dtype=np.float64), vx_m_per_s, observer)[0]


@numba.njit(cache=True)
def _jacobians(t, z, vx, p, jac):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The central differences of the acceleration without motive force at each centre height ``z`` (n,) (robot at
    ``x`` = 0, moving at ``vx``) into ``jac`` (n, 2, 4): by x, z (steps 1 nm), then by vx, vz (1 um/s)."""
    c = np.zeros(4)
    sp, sm = np.empty(4), np.empty(4)
    for k in range(z.shape[0]):
        for i in range(4):
            h = 1e-9 if i < 2 else 1e-6
            sp[0], sp[1], sp[2], sp[3] = 0.0, z[k], vx, 0.0
            sm[:] = sp
            sp[i] += h
            sm[i] -= h
            ap = accel_no_motive(t, sp[0], sp[1], sp[2], sp[3], c, p)
            am = accel_no_motive(t, sm[0], sm[1], sm[2], sm[3], c, p)
            jac[k, 0, i] = (ap[0] - am[0]) / (2 * h)
            jac[k, 1, i] = (ap[1] - am[1]) / (2 * h)


def observer_error_matrices(physics: PhysicsParams, t_s: float, z_m: npt.ArrayLike, vx_m_per_s: float,
                            observer: ObserverParams) -> npt.NDArray[np.float64]:
    """(n, 4, 4) linearised observer error matrices ``A``
    (:func:`~vesselbot_ros.control.high_gain_observer.linearised_error_matrix`) at each centre height of ``z_m``
    (n,), robot moving at ``vx`` (m/s)."""
    z = np.ascontiguousarray(z_m, dtype=np.float64)
    jac = np.empty((z.size, 2, 4))
    _jacobians(float(t_s), z, float(vx_m_per_s), packed_params(physics), jac)
    return linearised_error_matrix(observer, jac[:, :, :2], jac[:, :, 2:])


def observer_unstable_gap_m(
    physics: PhysicsParams,
    observer: ObserverParams,
    vx_m_per_s: float = 0.01,
    gap_max_m: float = 1e-3,
    n: int = 2000,
) -> float:
    """Widest gap (m) to the upper wall at which the observer error is unstable.

    Scans ``n`` gaps in ``(0, gap_max_m]`` (geometric spacing from 10 nm) at
    the narrowest diameter; returns 0 if it is stable everywhere.  The scan's matrices come from one compiled loop
    and their eigenvalues from one stacked call (:func:`observer_error_matrices`; the Python loop it replaced, a
    matrix per gap, gave the same doubles in about 16 times the time).

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
    gaps = np.geomspace(1e-8, gap_max_m, n)
    a = observer_error_matrices(physics, t, half - r - gaps, vx_m_per_s, observer)
    unstable = np.max(np.linalg.eigvals(a).real, axis=1) > 0.0
    return float(gaps[unstable].max()) if unstable.any() else 0.0


def wall_safe_delta_m(physics: PhysicsParams, observer: ObserverParams, margin_m: float, vx_m_per_s: float = 0.01) -> float:
    """Largest centre height ``Delta`` (m) keeping ``margin_m`` outside the unstable band at the narrowest D.

    ``D (1 - pulsation)/2 - r - observer_unstable_gap_m - margin_m``.
    """
    check_nonnegative("margin_m", margin_m)
    band = observer_unstable_gap_m(physics, observer, vx_m_per_s)
    half = 0.5 * physics.vessel.diameter_m * (1.0 - physics.flow.diameter_pulsation)
    return half - physics.robot.radius_m - band - margin_m
