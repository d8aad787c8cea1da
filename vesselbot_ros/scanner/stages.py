"""The imager and the coil driver as stages of a multiplexing scanner (drop-in for the continuous ones).

:class:`SequencedImager` has the port of
:class:`~vesselbot_ros.control.imager_model.ImagerModel` (``frame(t, p_true)``
once per tick) and :class:`SequencedCoil` the port of
:class:`~vesselbot_ros.control.actuator_limits.CoilLimiter` (``apply(t, G)``),
so the runner, the nodes and a user's code call them exactly as before.

Imaging.  One frame per tracking window: the robot's mean true position over
the window's ticks (motion blur), plus the imager's noise (and its scheduled
outliers and dropouts), stamped at the window's middle and delivered at the
first tick at or after ``window end + latency``.  The random draws per frame
are those of ``ImagerModel`` (two normals, one uniform for the outlier
direction, one for random dropout, in this order).

Propulsion.  The controller's gradient passes to the coil only inside
propulsion windows, through
:func:`~vesselbot_ros.scanner.sequence.propulsion_target`, so the slew-limited
output is exactly zero in every tracking window and dead time and the
saturation and slew limits hold across window edges.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.actuator_limits import CoilLimiter, CoilOutput, coil_params, coil_saturate
from vesselbot_ros.control.imager_model import ImagerModel, Measurement, check_frame_inputs
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.scanner.sequence import SequenceParams, propulsion_limit, propulsion_target, tracking_window_of

__all__ = ["SequencedImager", "SequencedCoil"]

_EPS_S = 1e-9


class SequencedImager:
    """An imager that acquires only in tracking windows (see module docstring).

    Args:
        imager: The imager model (noise, outliers, dropouts, seeded generator).
        sequence: The navigation sequence (``mode: multiplexed``).
    """

    def __init__(self, imager: ImagerModel, sequence: SequenceParams) -> None:
        if sequence.mode != "multiplexed":
            raise ModelInputError("SequencedImager needs a multiplexed sequence")
        self.inner = imager
        self.sequence = sequence
        self._window: Any = None
        self._sum = [0.0, 0.0]
        self._count = 0
        self._queue: deque[tuple[float, Measurement]] = deque()
        self._t_last = -math.inf

    def inject_outliers(self, start_s: float, duration_s: float, magnitude_m: float) -> None:
        """As :meth:`ImagerModel.inject_outliers` (by acquisition time)."""
        self.inner.inject_outliers(start_s, duration_s, magnitude_m)

    def inject_dropout(self, start_s: float, duration_s: float) -> None:
        """As :meth:`ImagerModel.inject_dropout` (by acquisition time)."""
        self.inner.inject_dropout(start_s, duration_s)

    def _close_window(self) -> None:
        w = self._window
        self._window = None
        if self._count == 0:
            return
        p = np.array([self._sum[0] / self._count, self._sum[1] / self._count])
        meas = self.inner.acquire(w.t_acq_s, p)
        if meas is not None:
            self._queue.append((w.t_deliver_s, meas))

    def frame(self, t_s: float, p_true: npt.ArrayLike) -> Measurement | None:
        """Accumulate (inside a tracking window) and deliver (when due) at tick ``t_s``.

        Returns:
            The newest frame delivered at ``t_s``, or None.
        """
        p = check_frame_inputs(t_s, p_true, self._t_last)
        self._t_last = t_s
        w = tracking_window_of(self.sequence, t_s)
        if self._window is not None and (w is None or w.index != self._window.index):
            self._close_window()
        if w is not None:
            if self._window is None:
                self._window, self._sum, self._count = w, [0.0, 0.0], 0
            self._sum[0] += float(p[0])
            self._sum[1] += float(p[1])
            self._count += 1
        out: Measurement | None = None
        while self._queue and self._queue[0][0] <= t_s + _EPS_S:
            out = self._queue.popleft()[1]
        return out


class SequencedCoil:
    """A coil driver that propels only in propulsion windows (see module docstring).

    Args:
        coil: The saturation/slew limiter.
        sequence: The navigation sequence.
        hold_s: Control period: each output is held for it (s).
    """

    def __init__(self, coil: CoilLimiter, sequence: SequenceParams, hold_s: float) -> None:
        if not (math.isfinite(hold_s) and hold_s > 0.0):
            raise ModelInputError(f"hold_s must be finite and > 0, got {hold_s!r}")
        self.inner = coil
        self.sequence = sequence
        self.limits = coil.limits
        self._hold = float(hold_s)
        self._slew = float(coil.limits.slew_rate_T_per_m_per_s)
        self._sat = float(coil.limits.saturation_T_per_m)
        self._prm = coil_params(coil.limits)

    @property
    def applied(self) -> npt.NDArray[np.float64]:
        """(2,) last applied gradient, T/m."""
        return self.inner.applied

    def apply(self, t_s: float, commanded_T_per_m: npt.ArrayLike) -> CoilOutput:
        """Saturate the command in the coil's norm, gate it by the sequence, then slew-limit it."""
        g = np.asarray(commanded_T_per_m, dtype=np.float64)
        if g.shape != (2,):
            raise ModelInputError(f"commanded gradient must have shape (2,), got {g.shape}")
        prev = self.inner.applied
        finite = math.isfinite(g[0]) and math.isfinite(g[1])
        if not finite:  # the coil's own rejection rule, then the gate (it must not hold into a tracking window)
            g = prev if self.limits.on_reject == "hold" else np.zeros(2)
        lim = propulsion_limit(self.sequence, t_s, self._hold, self._slew, self._sat)
        sx, sz, k = coil_saturate(self._prm, float(g[0]), float(g[1]))  # the coil's own norm and k
        target = propulsion_target((float(prev[0]), float(prev[1])), (sx, sz), lim, self._slew * self._hold)
        out = self.inner.apply(t_s, np.array(target))
        return out._replace(k_scale=float(k), saturated=k > 1.0, rejected=not finite)

    def watchdog(self, t_now_s: float) -> CoilOutput | None:
        """As :meth:`CoilLimiter.watchdog` (a ramp to zero is always allowed)."""
        return self.inner.watchdog(t_now_s)
