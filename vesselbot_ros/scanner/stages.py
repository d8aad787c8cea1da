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

In a 3-D vessel tree :class:`SequencedImager3D` and :class:`SequencedCoil3D` do the same on three axes (the 3-D
imager's six draws per frame; the coil's norm over three axes), through :func:`seq_imager3d_frame` and
:func:`seq_coil3d_apply`, which the compiled 3-D loop calls too.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.actuator_limits import (
    CoilLimiter,
    CoilLimiter3D,
    CoilOutput,
    coil3d_apply,
    coil3d_saturate,
    coil_apply,
    coil_params,
    coil_saturate,
)
from vesselbot_ros.control.imager3d import Imager3D, imager3d_acquire, queue3d_deliver, queue3d_push
from vesselbot_ros.control.imager_model import (
    ImagerModel,
    Measurement,
    check_frame_inputs,
    imager_acquire,
    new_queue,
    queue_deliver,
    queue_push,
    queue_with_room,
)
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.scanner.sequence import (
    SequenceParams,
    limit_at,
    sequence_vector,
    target3_for,
    target_for,
    tracking_window_at,
)

__all__ = ["SequencedImager", "SequencedCoil", "seq_imager_frame", "seq_coil_apply", "SEQ_IMAGER_STATE_SIZE",
           "new_seq_imager_state", "SequencedImager3D", "SequencedCoil3D", "seq_imager3d_frame", "seq_coil3d_apply",
           "SEQ_IMAGER3D_STATE_SIZE", "new_seq_imager3d_state"]

_EPS_S = 1e-9

# ---- compiled stages ------------------------------------------------------------------------------
# imager state st (8,): [open window index (-1: none), sum x, sum z, ticks summed, window t_acq, window t_deliver,
#   queue head, queue tail]; queue (cap, 5): [t_deliver, t_acq, x, z, outlier] of frames waiting for delivery;
# acq (5,) scratch of imager_acquire; out (5,) as imager_frame: [delivered (0/1), t_acq, x, z, outlier]
SEQ_IMAGER_STATE_SIZE = 8


def new_seq_imager_state() -> npt.NDArray[np.float64]:
    """A fresh imager state (no window open, empty queue)."""
    st = np.zeros(SEQ_IMAGER_STATE_SIZE)
    st[0] = -1.0
    return st


@numba.njit(cache=True, nogil=True)
def seq_imager_frame(sv, prm, outliers, dropouts, rng, st, queue, acq, t, px, pz, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:meth:`SequencedImager.frame` over explicit state (same draws, same doubles).

    The caller checks the inputs (finite, time not going back) and sizes
    ``queue`` for every frame that can wait (one row per tick is enough; the
    head and tail only grow).  Writes ``out``; allocates nothing.
    """
    w, _start, _end, w_acq, w_del = tracking_window_at(sv, t)
    if st[0] >= 0.0 and (w < 0 or w != st[0]):  # the open window ended: acquire its frame
        st[0] = -1.0
        if st[3] > 0.0:
            imager_acquire(prm, outliers, dropouts, rng, st[4], st[1] / st[3], st[2] / st[3], acq)
            if acq[0] > 0.5:
                queue_push(queue, st, 7, st[5], st[4], acq[2], acq[3], acq[4])
    if w >= 0:
        if st[0] < 0.0:
            st[0] = float(w)
            st[1] = 0.0
            st[2] = 0.0
            st[3] = 0.0
            st[4] = w_acq
            st[5] = w_del
        st[1] += px
        st[2] += pz
        st[3] += 1.0
    queue_deliver(queue, st, 6, 7, t, out)


@numba.njit(cache=True, nogil=True)
def seq_coil_apply(prm, sv, hold, state, t, gx, gz, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:meth:`SequencedCoil.apply` over the coil's explicit state (:func:`coil_apply`'s ``prm``, ``state``, ``out``).

    Saturates the command in the coil's norm, gates it by the sequence
    (:func:`~vesselbot_ros.scanner.sequence.limit_at`, ``target_for``), then
    slew-limits it; ``out[2]`` is the saturation factor of the command,
    ``out[6]`` 1 if the command was rejected (non-finite).  The caller checks
    that time does not go back.
    """
    p0 = state[0]
    p1 = state[1]
    finite = math.isfinite(gx) and math.isfinite(gz)
    if not finite:  # the coil's own rejection rule (towards zero at the slew limit), then the gate
        gx = 0.0
        gz = 0.0
    lim = limit_at(sv, t, hold, prm[1], prm[0])
    sx, sz, k = coil_saturate(prm, gx, gz)
    tx, tz = target_for(p0, p1, sx, sz, lim, prm[1] * hold)
    coil_apply(prm, state, t, tx, tz, out)
    out[2] = k
    out[3] = 1.0 if k > 1.0 else 0.0
    out[6] = 0.0 if finite else 1.0


class SequencedImager:
    """An imager that acquires only in tracking windows (see module docstring).

    Each tick is one call of the compiled :func:`seq_imager_frame` (which the
    compiled closed loop calls too).

    Args:
        imager: The imager model (noise, outliers, dropouts, seeded generator).
        sequence: The navigation sequence (``mode: multiplexed``).
    """

    def __init__(self, imager: ImagerModel, sequence: SequenceParams) -> None:
        if sequence.mode != "multiplexed":
            raise ModelInputError("SequencedImager needs a multiplexed sequence")
        self.inner = imager
        self.sequence = sequence
        self.sv = sequence_vector(sequence)
        self._st = new_seq_imager_state()
        self._queue = new_queue()
        self._acq = np.zeros(5)
        self._out = np.zeros(5)
        self._t_last = -math.inf

    @property
    def rng(self) -> np.random.Generator:
        """The generator the imager draws from (the inner model's)."""
        return self.inner.rng

    def inject_outliers(self, start_s: float, duration_s: float, magnitude_m: float) -> None:
        """As :meth:`ImagerModel.inject_outliers` (by acquisition time)."""
        self.inner.inject_outliers(start_s, duration_s, magnitude_m)

    def inject_dropout(self, start_s: float, duration_s: float) -> None:
        """As :meth:`ImagerModel.inject_dropout` (by acquisition time)."""
        self.inner.inject_dropout(start_s, duration_s)

    def frame(self, t_s: float, p_true: npt.ArrayLike) -> Measurement | None:
        """Accumulate (inside a tracking window) and deliver (when due) at tick ``t_s``.

        Returns:
            The newest frame delivered at ``t_s``, or None.
        """
        p = check_frame_inputs(t_s, p_true, self._t_last)
        self._t_last = t_s
        st = self._st
        self._queue = queue_with_room(self._queue, st, 6, 7)
        inner = self.inner
        seq_imager_frame(self.sv, *inner.frame_arrays, inner.variates(), st, self._queue, self._acq,
                         float(t_s), float(p[0]), float(p[1]), self._out)
        o = self._out
        if o[0] < 0.5:
            return None
        return Measurement(float(o[1]), o[2:4].copy(), bool(o[4] > 0.5))


class SequencedCoil:
    """A coil driver that propels only in propulsion windows (see module docstring).

    Each command is one call of the compiled :func:`seq_coil_apply` on the
    inner coil's state (which the compiled closed loop calls too).

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
        self.hold_s = float(hold_s)
        self.sv = sequence_vector(sequence)
        self._prm = coil_params(coil.limits)

    @property
    def applied(self) -> npt.NDArray[np.float64]:
        """(2,) last applied gradient, T/m."""
        return self.inner.applied

    @property
    def state(self) -> npt.NDArray[np.float64]:
        """(4,) copy of the inner coil's compiled state (:attr:`CoilLimiter.state`)."""
        return self.inner.state

    def apply(self, t_s: float, commanded_T_per_m: npt.ArrayLike) -> CoilOutput:
        """Saturate the command in the coil's norm, gate it by the sequence, then slew-limit it."""
        g = np.asarray(commanded_T_per_m, dtype=np.float64)
        if g.shape != (2,):
            raise ModelInputError(f"commanded gradient must have shape (2,), got {g.shape}")
        prm, sv, hold_s, t, gx, gz = self._prm, self.sv, self.hold_s, float(t_s), float(g[0]), float(g[1])
        return self.inner.step(t, lambda state, out: seq_coil_apply(prm, sv, hold_s, state, t, gx, gz, out))

    def reject(self, t_s: float) -> CoilOutput:
        """As :meth:`CoilLimiter.reject`: not a command; the output ramps towards zero within the slew limit."""
        return self.apply(t_s, np.full(2, np.nan))

    def hold(self, t_s: float) -> CoilOutput:
        """As :meth:`CoilLimiter.hold` (holding the output is always allowed: outside propulsion it is zero)."""
        return self.inner.hold(t_s)

    def watchdog(self, t_now_s: float) -> CoilOutput | None:
        """As :meth:`CoilLimiter.watchdog` (a ramp to zero is always allowed)."""
        return self.inner.watchdog(t_now_s)


# ---- three axes (3-D vessel trees) --------------------------------------------------------------------
# st (9,): [open window (-1: none), sum x, sum y, sum z, ticks, its t_acq, its t_deliver, queue head, queue tail];
# queue (rows, 6) ring of [t_deliver, t_acq, x, y, z, outlier]; acq, out (6,) as imager3d_frame's.
SEQ_IMAGER3D_STATE_SIZE = 9


def new_seq_imager3d_state() -> npt.NDArray[np.float64]:
    """A fresh 3-D imager state (no window open, empty queue)."""
    st = np.zeros(SEQ_IMAGER3D_STATE_SIZE)
    st[0] = -1.0
    return st


@numba.njit(cache=True, nogil=True)
def seq_imager3d_frame(sv, prm, outliers, dropouts, rng, st, queue, acq, t, px, py, pz, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:meth:`SequencedImager3D.frame` over explicit state: :func:`seq_imager_frame` on three axes."""
    w, _start, _end, w_acq, w_del = tracking_window_at(sv, t)
    if st[0] >= 0.0 and (w < 0 or w != st[0]):  # the open window ended: acquire its frame
        st[0] = -1.0
        if st[4] > 0.0:
            imager3d_acquire(prm, outliers, dropouts, rng, st[5], st[1] / st[4], st[2] / st[4], st[3] / st[4], acq)
            if acq[0] > 0.5:
                queue3d_push(queue, st, 8, st[6], acq)
    if w >= 0:
        if st[0] < 0.0:
            st[0] = float(w)
            st[1] = 0.0
            st[2] = 0.0
            st[3] = 0.0
            st[4] = 0.0
            st[5] = w_acq
            st[6] = w_del
        st[1] += px
        st[2] += py
        st[3] += pz
        st[4] += 1.0
    queue3d_deliver(queue, st, 7, 8, t, out)


@numba.njit(cache=True, nogil=True)
def seq_coil3d_apply(prm, sv, hold, state, t, gx, gy, gz, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:meth:`SequencedCoil3D.apply` over the 3-D coil's state: :func:`seq_coil_apply` on three axes
    (:func:`~vesselbot_ros.control.actuator_limits.coil3d_apply`'s ``prm``, ``state``, ``out``)."""
    p0 = state[0]
    p1 = state[1]
    p2 = state[2]
    finite = math.isfinite(gx) and math.isfinite(gy) and math.isfinite(gz)
    if not finite:  # rejected: towards zero at the slew limit
        gx = 0.0
        gy = 0.0
        gz = 0.0
    lim = limit_at(sv, t, hold, prm[1], prm[0])
    sx, sy, sz, k = coil3d_saturate(prm, gx, gy, gz)
    tx, ty, tz = target3_for(p0, p1, p2, sx, sy, sz, lim, prm[1] * hold)
    coil3d_apply(prm, state, t, tx, ty, tz, out)
    out[3] = k
    out[4] = 1.0 if k > 1.0 else 0.0
    out[8] = 0.0 if finite else 1.0


class SequencedImager3D:
    """:class:`SequencedImager` on three axes (a 3-D vessel tree's imager).

    Args:
        imager: The 3-D imager (noise, outliers, dropouts, seeded generator).
        sequence: The navigation sequence (``mode: multiplexed``).
    """

    dims = 3

    def __init__(self, imager: Imager3D, sequence: SequenceParams) -> None:
        if sequence.mode != "multiplexed":
            raise ModelInputError("SequencedImager3D needs a multiplexed sequence")
        self.inner = imager
        self.params = imager.params
        self.sequence = sequence
        self.sv = sequence_vector(sequence)
        self._st = new_seq_imager3d_state()
        self._queue = np.zeros((seq_queue_rows(sequence, imager.params), 6))
        self._acq = np.zeros(6)
        self._out = np.zeros(6)
        self._t_last = -math.inf

    @property
    def rng(self) -> np.random.Generator:
        """The generator the imager draws from (the inner imager's)."""
        return self.inner.rng

    @property
    def frame_arrays(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """The inner imager's ``(params, outliers, dropouts)``."""
        return self.inner.frame_arrays

    def inject_outliers(self, start_s: float, duration_s: float, magnitude_m: float) -> None:
        """As :meth:`Imager3D.inject_outliers` (by acquisition time)."""
        self.inner.inject_outliers(start_s, duration_s, magnitude_m)

    def inject_dropout(self, start_s: float, duration_s: float) -> None:
        """As :meth:`Imager3D.inject_dropout` (by acquisition time)."""
        self.inner.inject_dropout(start_s, duration_s)

    def frame(self, t_s: float, p_true: npt.ArrayLike) -> Measurement | None:
        """Accumulate (inside a tracking window) and deliver (when due) at tick ``t_s``: the newest frame, or None.

        Raises:
            ModelInputError: on a non-finite time or position, a wrong shape or time going backwards.
        """
        p = np.asarray(p_true, dtype=np.float64)
        if p.shape != (3,) or not (math.isfinite(p[0]) and math.isfinite(p[1]) and math.isfinite(p[2])):
            raise ModelInputError(f"imager: true position must be a finite (3,) array, got {p_true!r}")
        if not math.isfinite(t_s) or t_s < self._t_last:
            raise ModelInputError(f"imager: tick time must be finite and non-decreasing, got {t_s!r}")
        self._t_last = t_s
        inner = self.inner
        seq_imager3d_frame(self.sv, *inner.frame_arrays, inner.variates(), self._st, self._queue, self._acq, float(t_s),
                           float(p[0]), float(p[1]), float(p[2]), self._out)
        o = self._out
        if o[0] < 0.5:
            return None
        return Measurement(float(o[1]), o[2:5].copy(), bool(o[5] > 0.5))


def seq_queue_rows(sequence: SequenceParams, params: Any) -> int:
    """Rows of a 3-D sequenced imager's delivery ring: the frames that can wait for their delivery, and some."""
    period = sequence.tracking_window_s + 2.0 * sequence.dead_time_s + sequence.propulsion_window_s
    return int(math.ceil((sequence.latency_s + period) / max(period, 1e-6))) + 4


class SequencedCoil3D:
    """:class:`SequencedCoil` on three axes (a 3-D vessel tree's coil).

    Args:
        coil: The 3-D saturation/slew limiter.
        sequence: The navigation sequence.
        hold_s: Control period: each output is held for it (s).
    """

    dims = 3

    def __init__(self, coil: CoilLimiter3D, sequence: SequenceParams, hold_s: float) -> None:
        if not (math.isfinite(hold_s) and hold_s > 0.0):
            raise ModelInputError(f"hold_s must be finite and > 0, got {hold_s!r}")
        self.inner = coil
        self.sequence = sequence
        self.limits = coil.limits
        self.hold_s = float(hold_s)
        self.sv = sequence_vector(sequence)
        self._prm = coil_params(coil.limits)

    @property
    def applied(self) -> npt.NDArray[np.float64]:
        """(3,) last applied gradient, T/m."""
        return self.inner.applied

    @property
    def state(self) -> npt.NDArray[np.float64]:
        """(5,) copy of the inner coil's compiled state."""
        return self.inner.state

    def apply(self, t_s: float, commanded_T_per_m: npt.ArrayLike) -> CoilOutput:
        """Saturate the command in the coil's norm, gate it by the sequence, then slew-limit it (three axes)."""
        g = np.asarray(commanded_T_per_m, dtype=np.float64)
        if g.shape != (3,):
            raise ModelInputError(f"commanded gradient must have shape (3,), got {g.shape}")
        prm, sv, hold_s, t, gx, gy, gz = self._prm, self.sv, self.hold_s, float(t_s), float(g[0]), float(g[1]), float(g[2])
        return self.inner.step(t, lambda state, out: seq_coil3d_apply(prm, sv, hold_s, state, t, gx, gy, gz, out))

    def reject(self, t_s: float) -> CoilOutput:
        """As :meth:`CoilLimiter.reject` on three axes."""
        return self.apply(t_s, np.full(3, np.nan))

    def hold(self, t_s: float) -> CoilOutput:
        """As :meth:`CoilLimiter3D.hold`."""
        return self.inner.hold(t_s)

    def watchdog(self, t_now_s: float) -> CoilOutput | None:
        """As :meth:`CoilLimiter3D.watchdog`."""
        return self.inner.watchdog(t_now_s)
