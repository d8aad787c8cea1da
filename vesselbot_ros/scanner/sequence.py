"""MRI navigation sequence: tracking and propulsion windows multiplexed on one gradient system.

A clinical scanner's gradient coils both image and propel (Tamaz et al., IEEE
TBME 2008, the paper's ref. [23]), so the two alternate.  One period::

    | tracking (imaging) | dead | propulsion | dead | tracking | ...
    0                    T_t    T_t+T_d      T_t+T_d+T_p       T = T_t+2T_d+T_p

* tracking window: the gradients image; no propulsion gradient may be applied;
  one frame per window, of the robot's mean position over the window (motion
  blur), stamped at the window's middle, delivered ``latency_s`` after the
  window ends (reconstruction and localisation);
* dead time: switching between the two (gradient ramps, eddy currents);
  neither imaging nor propulsion;
* propulsion window: the controller's gradient is applied; it must be back
  at zero when the window ends, so the coil starts ramping down early enough
  (:func:`propulsion_limit`).

``mode: continuous`` is the paper's idealised loop (imaging at every control
tick, propulsion all the time, no latency): today's behaviour, unchanged.

Everything here is a pure function of time and the parameters, shared by the
ROS nodes and the ROS-free runner.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal, NamedTuple

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.blas_free import hypot2, hypot3, hypot_axes
from vesselbot_ros.config import ConfigError, check_choice, check_nonnegative, check_positive

__all__ = [
    "SequenceParams",
    "Phase",
    "PHASE_CODES",
    "phase_at",
    "propulsion_limit",
    "tracking_window_of",
    "duty_cycle",
    "TrackingWindow",
    "propulsion_target",
    "sequence_vector",
    "phase_code",
    "phase_codes",
    "cycle_at",
    "tracking_window_at",
    "PhaseWindow",
    "window_at",
    "limit_at",
    "target_into",
]

_EPS_S = 1e-9

#: Numeric codes of the phases (recorded and published).
PHASE_CODES = {"continuous": 0, "tracking": 1, "dead": 2, "propulsion": 3}
Phase = Literal["continuous", "tracking", "dead", "propulsion"]


@dataclasses.dataclass(frozen=True)
class SequenceParams:
    """Navigation sequence timing.

    Attributes:
        mode: ``continuous`` (paper: image every tick, propel always) or
            ``multiplexed`` (the windows below).
        tracking_window_s: Imaging window per period (s).
        dead_time_s: Switching time between windows, at each switch (s).
        propulsion_window_s: Propulsion window per period (s).
        latency_s: Reconstruction and localisation delay after a tracking
            window ends (s).
        start_s: Time of the first tracking window's start (s).
    """

    mode: Literal["continuous", "multiplexed"] = "continuous"
    tracking_window_s: float = 0.02
    dead_time_s: float = 0.002
    propulsion_window_s: float = 0.03
    latency_s: float = 0.02
    start_s: float = 0.0

    def __post_init__(self) -> None:
        check_choice("mode", self.mode, ("continuous", "multiplexed"))
        check_positive("tracking_window_s", self.tracking_window_s)
        check_nonnegative("dead_time_s", self.dead_time_s)
        check_positive("propulsion_window_s", self.propulsion_window_s)
        check_nonnegative("latency_s", self.latency_s)
        check_nonnegative("start_s", self.start_s)
        for name in ("tracking_window_s", "dead_time_s", "propulsion_window_s", "latency_s"):
            if getattr(self, name) > 60.0:
                raise ConfigError(f"{name} must be <= 60 s, got {getattr(self, name)!r}")

    @property
    def period_s(self) -> float:
        """One tracking + dead + propulsion + dead cycle (s)."""
        return self.tracking_window_s + 2.0 * self.dead_time_s + self.propulsion_window_s


class TrackingWindow(NamedTuple):
    """One tracking window: ``[start_s, end_s)``; its frame is stamped ``t_acq_s`` and delivered at ``t_deliver_s``."""

    index: int  # type: ignore[assignment]  # the field's name shadows tuple.index on purpose
    start_s: float
    end_s: float
    t_acq_s: float
    t_deliver_s: float


def duty_cycle(params: SequenceParams) -> float:
    """Fraction of the time the propulsion gradient may be on (1 in continuous mode)."""
    if params.mode == "continuous":
        return 1.0
    return params.propulsion_window_s / params.period_s


# ---- compiled forms (the Python functions below call them; so do the compiled loop and the scanner's stages) ----
# sequence vector sv (7,): [multiplexed (0/1), tracking_window_s, dead_time_s, propulsion_window_s, latency_s,
# start_s, period_s]
_CODE_CONTINUOUS, _CODE_TRACKING, _CODE_DEAD, _CODE_PROPULSION = (PHASE_CODES[k] for k in ("continuous", "tracking",
                                                                                         "dead", "propulsion"))
_PHASE_NAMES: tuple[Phase, ...] = ("continuous", "tracking", "dead", "propulsion")


def sequence_vector(params: SequenceParams) -> npt.NDArray[np.float64]:
    """(7,) the sequence as the compiled functions read it."""
    return np.array([1.0 if params.mode == "multiplexed" else 0.0, params.tracking_window_s, params.dead_time_s,
                     params.propulsion_window_s, params.latency_s, params.start_s, params.period_s])


@numba.njit(cache=True, nogil=True)
def cycle_at(sv, t_s):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(period index, time into that period (s))`` at ``t_s``; index -1 before ``start_s``."""
    rel = t_s - sv[5]
    if rel < -_EPS_S:
        return -1, rel
    n = int(math.floor((rel + _EPS_S) / sv[6]))
    return n, rel - n * sv[6]


@numba.njit(cache=True, nogil=True)
def phase_code(sv, t_s):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:data:`PHASE_CODES` of the phase at ``t_s`` (finite); see :func:`phase_at`."""
    if sv[0] < 0.5:
        return _CODE_CONTINUOUS
    n, tau = cycle_at(sv, t_s)
    if n < 0:
        return _CODE_DEAD
    t_t = sv[1]
    t_d = sv[2]
    t_p = sv[3]
    if tau < t_t - _EPS_S:
        return _CODE_TRACKING
    if tau < t_t + t_d - _EPS_S:
        return _CODE_DEAD
    if tau < t_t + t_d + t_p - _EPS_S:
        return _CODE_PROPULSION
    return _CODE_DEAD


@numba.njit(cache=True, nogil=True)
def phase_codes(sv, ts):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`phase_code` at every time of ``ts``, int8."""
    out = np.empty(ts.shape[0], dtype=np.int8)
    for i in range(ts.shape[0]):
        out[i] = phase_code(sv, ts[i])
    return out


@numba.njit(cache=True, nogil=True)
def tracking_window_at(sv, t_s):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(index, start, end, t_acq, t_deliver)`` of the tracking window containing ``t_s``; index -1 if none."""
    if sv[0] < 0.5 or phase_code(sv, t_s) != _CODE_TRACKING:
        return -1, 0.0, 0.0, 0.0, 0.0
    n, _tau = cycle_at(sv, t_s)
    start = sv[5] + n * sv[6]
    end = start + sv[1]
    return n, start, end, 0.5 * (start + end), end + sv[4]


@numba.njit(cache=True, nogil=True)
def limit_at(sv, t_s, hold_s, slew, sat):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`propulsion_limit` for valid arguments (compiled)."""
    if sv[0] < 0.5:
        return sat
    n, tau = cycle_at(sv, t_s)
    if n < 0:
        return 0.0
    p0 = sv[1] + sv[2]
    p1 = p0 + sv[3]
    if tau < p0 - _EPS_S or tau + hold_s > p1 + _EPS_S:
        return 0.0
    rem = p1 - tau - hold_s
    if rem <= _EPS_S:  # within the 1 ns tick tolerance of the window's end: exactly zero
        return 0.0
    # 1e-9 relative margin: rounding in tau must not leave the last step a hair above S dt, or
    # the slew-scaled step would land 1e-18 T/m short of exactly zero
    v = slew * rem * (1.0 - 1e-9)
    return sat if not v < sat else v


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on the views it passes (physics.integrator)
def target_into(p, c, limit, max_step):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:func:`propulsion_target` (compiled) on any number of gradient axes: the coil's output ``p`` and the finite
    command ``c`` (T/m, (d,), d = 2 or 3); ``c`` becomes the target.  Norms by CPython's ``math.hypot``
    (``hypot2`` / ``hypot3``: the plane's doubles for ``(x, 0, z)``)."""
    d = c.shape[0]
    n = hypot_axes(c)
    if n > limit:
        for i in range(d):
            c[i] = 0.0 if limit <= 0.0 else c[i] * (limit / n)
    biggest = 0.0
    for i in range(d):
        a = abs(c[i] - p[i])
        if a > biggest:
            biggest = a
    # the coil's own step, S times the tick as it measures it, may be a rounding larger: the endpoint
    # estimated with a slightly smaller step lies on the same segment, so inside the disc means inside
    step = max_step * (1.0 - 1e-9)
    last = d - 1  # z: the second axis of the plane, the third in space
    if biggest > step:
        f = step / biggest
        e0 = p[0] + (c[0] - p[0]) * f
        e1 = p[1] + (c[1] - p[1]) * f
        e2 = p[last] + (c[last] - p[last]) * f
    else:
        e0 = c[0]
        e1 = c[1]
        e2 = c[last]
    if (hypot2(e0, e1) if d == 2 else hypot3(e0, e1, e2)) <= limit:  # axis count: the endpoint's norm, no scratch
        return
    m = hypot_axes(p)
    if m <= limit or m == 0.0:
        for i in range(d):
            c[i] = p[i]
        return
    for i in range(d):
        c[i] = p[i] * (limit / m)


def _check_time(t_s: float) -> None:
    if not math.isfinite(t_s):
        raise ConfigError(f"sequence time must be finite, got {t_s!r}")


def phase_at(params: SequenceParams, t_s: float) -> Phase:
    """The sequence phase at time ``t_s`` (s).  Before ``start_s`` the scanner is in dead time."""
    if params.mode == "continuous":
        return "continuous"
    _check_time(t_s)
    return _PHASE_NAMES[phase_code(sequence_vector(params), float(t_s))]


class PhaseWindow(NamedTuple):
    """The window of the sequence containing a time: ``phase`` holds on ``[start_s, end_s)``.

    ``index`` is the period (0 for the first tracking window's period, -1
    before ``start_s`` and in continuous mode).  In continuous mode the one
    window is ``[0, inf)``; before ``start_s`` the dead time is ``[-inf, start_s)``.
    """

    phase: Phase
    index: int  # type: ignore[assignment]  # the field's name shadows tuple.index on purpose
    start_s: float
    end_s: float


def window_at(params: SequenceParams, t_s: float) -> PhaseWindow:
    """The phase window containing ``t_s`` (what the coil driver publishes on the sequence-phase port)."""
    if params.mode == "continuous":
        return PhaseWindow("continuous", -1, 0.0, math.inf)
    _check_time(t_s)
    n, tau = cycle_at(sequence_vector(params), float(t_s))
    if n < 0:
        return PhaseWindow("dead", -1, -math.inf, params.start_s)
    t0 = params.start_s + n * params.period_s
    t_t, t_d, t_p = params.tracking_window_s, params.dead_time_s, params.propulsion_window_s
    edges = (0.0, t_t, t_t + t_d, t_t + t_d + t_p, params.period_s)
    phases: tuple[Phase, ...] = ("tracking", "dead", "propulsion", "dead")
    for i, ph in enumerate(phases):
        if tau < edges[i + 1] - _EPS_S or i == len(phases) - 1:
            return PhaseWindow(ph, n, t0 + edges[i], t0 + edges[i + 1])
    raise AssertionError("unreachable")  # pragma: no cover


def tracking_window_of(params: SequenceParams, t_s: float) -> TrackingWindow | None:
    """The tracking window containing ``t_s``, or None (continuous mode or another phase)."""
    if params.mode == "continuous":
        return None
    _check_time(t_s)
    n, start, end, t_acq, t_deliver = tracking_window_at(sequence_vector(params), float(t_s))
    return None if n < 0 else TrackingWindow(int(n), start, end, t_acq, t_deliver)


def propulsion_limit(params: SequenceParams, t_s: float, hold_s: float, slew_T_per_m_per_s: float,
                     saturation_T_per_m: float) -> float:
    """Largest gradient norm (T/m) the coil may apply from ``t_s`` and hold for ``hold_s``.

    Zero unless the whole hold ``[t_s, t_s + hold_s]`` lies in a propulsion
    window.  Inside, the limit falls at the slew rate towards the window's end,
    ``S (t_end - t_s - hold_s)``, so a slew-limited coil can always be back at
    zero before the next dead time and tracking window.  In continuous mode it
    is the saturation.

    Args:
        params: The sequence.
        t_s: Start of the hold (s).
        hold_s: Duration of the hold (s), >= 0 (the control period).
        slew_T_per_m_per_s: Slew rate ``S`` (T/m/s), > 0.
        saturation_T_per_m: Amplitude limit (T/m), > 0.
    """
    if params.mode == "continuous":
        return saturation_T_per_m
    if not (hold_s >= 0.0 and slew_T_per_m_per_s > 0.0 and saturation_T_per_m > 0.0):
        raise ConfigError(f"propulsion_limit needs hold_s >= 0, S > 0, saturation > 0, got "
                          f"{hold_s!r}, {slew_T_per_m_per_s!r}, {saturation_T_per_m!r}")
    _check_time(t_s)
    return float(limit_at(sequence_vector(params), float(t_s), float(hold_s), float(slew_T_per_m_per_s),
                          float(saturation_T_per_m)))


def propulsion_target(applied_prev: tuple[float, ...], commanded: tuple[float, ...], limit_T_per_m: float,
                      max_step_T_per_m: float) -> tuple[float, ...]:
    """The command to hand a slew-limited coil so its output stays within ``limit_T_per_m``.

    The coil (:class:`~vesselbot_ros.scanner.actuator_limits.CoilLimiter`) moves
    from ``applied_prev`` towards its command by at most ``max_step_T_per_m`` per
    axis, scaling the whole step.  The commanded gradient is first scaled into
    the disc of radius ``limit``; if the coil could not get inside the disc in
    one step that way (the command points elsewhere), the target is the
    previous output scaled onto the disc, which is within one step because
    :func:`propulsion_limit` falls by at most the slew per tick.

    Args:
        applied_prev: (gx, gz) or (gx, gy, gz): the coil's output over the previous tick (T/m).
        commanded: the controller's command on the same axes (T/m), finite.
        limit_T_per_m: :func:`propulsion_limit` for this tick (T/m), >= 0.
        max_step_T_per_m: Slew rate times the tick (T/m).

    Returns:
        The target to hand the coil (T/m), on the same axes.
    """
    c = np.array(commanded, dtype=np.float64)
    target_into(np.array(applied_prev, dtype=np.float64), c, float(limit_T_per_m), float(max_step_T_per_m))
    return tuple(float(v) for v in c)
