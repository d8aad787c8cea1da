"""The imager and the coil driver as stages of a multiplexing scanner (drop-in for the continuous ones).

:class:`SequencedImager` has the port of
:class:`~vesselbot_ros.scanner.imager_model.ImagerModel` (``frame(t, p_true)``
once per tick) and :class:`SequencedCoil` the port of
:class:`~vesselbot_ros.scanner.actuator_limits.CoilLimiter` (``apply(t, G)``),
so the runner, the nodes and a user's code call them exactly as before.

Imaging.  One frame per tracking window: the robot's mean true position over
the window's ticks (motion blur), plus the imager's noise (and its scheduled
outliers and dropouts), stamped at the window's middle and delivered at the
first tick at or after ``window end + latency``.  The random draws per frame
are those of ``ImagerModel`` (in the plane: two normals, one uniform for the
outlier direction, one for random dropout, in this order).

Propulsion.  The controller's gradient passes to the coil only inside
propulsion windows, through
:func:`~vesselbot_ros.scanner.sequence.propulsion_target`, so the slew-limited
output is exactly zero in every tracking window and dead time and the
saturation and slew limits hold across window edges.

Both run on their inner stage's axes: two in the plane, three in a 3-D tree (the imager's draws per frame on
those axes; the coil's norm over them).
"""

from __future__ import annotations

import math
from typing import TypeVar

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.scanner.actuator_limits import (
    CoilLimiter,
    CoilOutput,
    CompiledCoil,
    coil_apply,
    coil_params,
    coil_saturate,
)
from vesselbot_ros.scanner.imager_model import (
    CompiledImager,
    ImagerModel,
    Measurement,
    check_frame_inputs,
    frame_out_size,
    imager_acquire,
    new_queue,
    queue_deliver,
    queue_push,
    queue_with_room,
)
from vesselbot_ros.scanner.sequence import (
    SequenceParams,
    limit_at,
    sequence_vector,
    target_into,
    tracking_window_at,
)

__all__ = ["SequencedImager", "SequencedCoil", "seq_imager_frame", "seq_coil_apply", "seq_imager_state_size",
           "new_seq_imager_state"]

_EPS_S = 1e-9

# ---- compiled stages ------------------------------------------------------------------------------
# On d position axes (2: x, z; 3: x, y, z), read from the position array's length:
# imager state st (d + 6,): [open window index (-1: none), sum of the position (d), ticks summed, window t_acq,
#   window t_deliver, queue head, queue tail]; queue (cap, 3 + d): the imager's frame queue (imager_model);
# acq (3 + d,) scratch of imager_acquire; out (3 + d,) as imager_frame: [delivered (0/1), t_acq, p (d), outlier]
def seq_imager_state_size(dims: int) -> int:
    """Length of a sequenced imager's state on ``dims`` axes."""
    return int(dims) + 6


def new_seq_imager_state(dims: int = 2) -> npt.NDArray[np.float64]:
    """A fresh imager state (no window open, empty queue)."""
    st = np.zeros(seq_imager_state_size(dims))
    st[0] = -1.0
    return st


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on the views it passes (physics.integrator)
def seq_imager_frame(sv, prm, outliers, dropouts, rng, st, queue, acq, t, p, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:meth:`SequencedImager.frame` over explicit state (same draws, same doubles), on the axes of ``p`` (d,).

    The caller checks the inputs (finite, time not going back) and sizes
    ``queue`` for every frame that can wait (one row per tick is enough; the
    head and tail only grow).  Writes ``out``; allocates nothing.
    """
    d = p.shape[0]
    w, _start, _end, w_acq, w_del = tracking_window_at(sv, t)
    if st[0] >= 0.0 and (w < 0 or w != st[0]):  # the open window ended: acquire its frame
        st[0] = -1.0
        ticks = st[1 + d]
        if ticks > 0.0:
            mean = acq[2:2 + d]  # the window's mean position, where imager_acquire writes the measured one
            for c in range(d):
                mean[c] = st[1 + c] / ticks
            imager_acquire(prm, outliers, dropouts, rng, st[2 + d], mean, acq)
            if acq[0] > 0.5:
                queue_push(queue, st, d + 5, st[3 + d], acq)
    if w >= 0:
        if st[0] < 0.0:
            st[0] = float(w)
            for c in range(d + 1):
                st[1 + c] = 0.0
            st[2 + d] = w_acq
            st[3 + d] = w_del
        for c in range(d):
            st[1 + c] += p[c]
        st[1 + d] += 1.0
    queue_deliver(queue, st, d + 4, d + 5, t, out)


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on the views it passes (physics.integrator)
def seq_coil_apply(prm, sv, hold, state, t, g, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:meth:`SequencedCoil.apply` over the coil's explicit state (:func:`coil_apply`'s ``prm``, ``state``, ``out``),
    on the command's axes (``g`` (d,), T/m).

    Saturates the command in the coil's norm, gates it by the sequence
    (:func:`~vesselbot_ros.scanner.sequence.limit_at`, ``target_into``), then
    slew-limits it; ``out[d]`` is the saturation factor of the command,
    ``out[2 d + 2]`` 1 if the command was rejected (non-finite).  The caller checks
    that time does not go back.  ``g`` may be ``out[:d]``.
    """
    d = g.shape[0]
    finite = True
    for c in range(d):
        if not math.isfinite(g[c]):
            finite = False
    cmd = out[:d]  # the target, in the slots the coil writes last (no allocation on the loop's path)
    for c in range(d):  # a rejected command: the coil's own rule (towards zero at the slew limit), then the gate
        cmd[c] = g[c] if finite else 0.0
    lim = limit_at(sv, t, hold, prm[1], prm[0])
    k = coil_saturate(prm, cmd, cmd)
    target_into(state[:d], cmd, lim, prm[1] * hold)
    coil_apply(prm, state, t, cmd, out)
    out[d] = k
    out[d + 1] = 1.0 if k > 1.0 else 0.0
    out[2 * d + 2] = 0.0 if finite else 1.0


_Form = TypeVar("_Form", CompiledImager, CompiledCoil)


def _inner_form(inner: object, form_type: type[_Form], what: str) -> _Form:
    """The compiled form of the part a sequenced stage wraps, of ``form_type``.

    Raises:
        ModelInputError: the part has none (a user's part the compiled loop cannot run).
    """
    form = getattr(inner, "compiled", None)
    out = form() if callable(form) else None
    if not isinstance(out, form_type):
        raise ModelInputError(f"the sequenced {what}'s {type(inner).__name__} has no compiled form")
    return out


class SequencedImager:
    """An imager that acquires only in tracking windows (see module docstring), on the inner imager's axes.

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
        self.dims = imager.dims
        self.params = imager.params
        self.sequence = sequence
        self.sv = sequence_vector(sequence)
        self._st = new_seq_imager_state(self.dims)
        self._queue = new_queue(self.dims)
        self._acq = np.zeros(frame_out_size(self.dims))
        self._out = np.zeros(frame_out_size(self.dims))
        self._t_last = -math.inf

    @property
    def rng(self) -> np.random.Generator:
        """The generator the imager draws from (the inner model's)."""
        return self.inner.rng

    @property
    def frame_arrays(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """The inner imager's ``(params, outliers, dropouts)``."""
        return self.inner.frame_arrays

    def compiled(self) -> CompiledImager:
        """The inner imager's compiled form on this sequence.

        Raises:
            ModelInputError: the inner imager has none (a user's imager the compiled loop cannot run).
        """
        return _inner_form(self.inner, CompiledImager, "imager")._replace(sv=self.sv)

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

        Raises:
            ModelInputError: on a non-finite time or position, a wrong shape or time going backwards.
        """
        d = self.dims
        p = check_frame_inputs(t_s, p_true, self._t_last, d)
        self._t_last = t_s
        st = self._st
        self._queue = queue_with_room(self._queue, st, d + 4, d + 5)
        inner = self.inner
        seq_imager_frame(self.sv, *inner.frame_arrays, inner.variates(), st, self._queue, self._acq,
                         float(t_s), p, self._out)
        o = self._out
        if o[0] < 0.5:
            return None
        return Measurement(float(o[1]), o[2:2 + d].copy(), bool(o[2 + d] > 0.5))


class SequencedCoil:
    """A coil driver that propels only in propulsion windows (see module docstring), on the inner coil's axes.

    Each command is one call of the compiled :func:`seq_coil_apply` on the
    inner coil's state (which the compiled closed loop calls too).

    Args:
        coil: The saturation/slew limiter (its ``dims`` axes).
        sequence: The navigation sequence.
        hold_s: Control period: each output is held for it (s).
    """

    def __init__(self, coil: CoilLimiter, sequence: SequenceParams, hold_s: float) -> None:
        if not (math.isfinite(hold_s) and hold_s > 0.0):
            raise ModelInputError(f"hold_s must be finite and > 0, got {hold_s!r}")
        self.inner = coil
        self.dims = coil.dims
        self.sequence = sequence
        self.limits = coil.limits
        self.hold_s = float(hold_s)
        self.sv = sequence_vector(sequence)
        self._prm = coil_params(coil.limits)

    @property
    def applied(self) -> npt.NDArray[np.float64]:
        """(dims,) last applied gradient, T/m."""
        return self.inner.applied

    @property
    def state(self) -> npt.NDArray[np.float64]:
        """(dims + 2,) copy of the inner coil's compiled state (:attr:`CoilLimiter.state`)."""
        return self.inner.state

    def compiled(self) -> CompiledCoil:
        """The inner coil's compiled form, gated on this sequence.

        Raises:
            ModelInputError: the inner coil has none (a user's coil the compiled loop cannot run).
        """
        return _inner_form(self.inner, CompiledCoil, "coil")._replace(sv=self.sv, hold_s=self.hold_s)

    def apply(self, t_s: float, commanded_T_per_m: npt.ArrayLike) -> CoilOutput:
        """Saturate the command in the coil's norm, gate it by the sequence, then slew-limit it."""
        g = np.array(commanded_T_per_m, dtype=np.float64)
        if g.shape != (self.dims,):
            raise ModelInputError(f"commanded gradient must have shape ({self.dims},), got {g.shape}")
        prm, sv, hold_s, t = self._prm, self.sv, self.hold_s, float(t_s)
        return self.inner.step(t, lambda state, out: seq_coil_apply(prm, sv, hold_s, state, t, g, out))

    def reject(self, t_s: float) -> CoilOutput:
        """As :meth:`CoilLimiter.reject`: not a command; the output ramps towards zero within the slew limit."""
        return self.apply(t_s, np.full(self.dims, np.nan))

    def hold(self, t_s: float) -> CoilOutput:
        """As :meth:`CoilLimiter.hold` (holding the output is always allowed: outside propulsion it is zero)."""
        return self.inner.hold(t_s)

    def watchdog(self, t_now_s: float) -> CoilOutput | None:
        """As :meth:`CoilLimiter.watchdog` (a ramp to zero is always allowed)."""
        return self.inner.watchdog(t_now_s)
