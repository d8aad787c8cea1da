"""MRI position-measurement model: noise, frame rate, latency, outliers, dropouts.

Section III-C: "the position measurement is with an accuracy to within
100 um [...], modeled by a white gaussian noise".  We read 100 um as the
standard deviation ``sigma`` of a zero-mean Gaussian on each axis
(``noise_sigma_m``); a bound would need a truncated law the paper does not
mention.  The paper's simulation measures quasi-continuously; real-time MRI
delivers about 50 frames/s (Uecker et al. 2010, paper ref. [2]), plus a
reconstruction latency.  Both are parameters.

Timing model, all on the caller's tick grid ``t_k``:

* a frame is *acquired* at the first tick ``t_k >= n / frame_rate_Hz``
  (``n = 0, 1, ...``), of the true position at that tick;
* it is *delivered* at the first tick ``t_k >= t_acq + latency_s``;
* ``frame(t_k, p_true)`` returns the frame delivered at ``t_k`` (the newest if
  several are due), or None.

Random draws: every acquired frame draws exactly four numbers from the
generator, in this order: two standard normals (noise on x, z), one uniform
(outlier direction) and one uniform (random dropout), whether or not the frame
is an outlier or dropped.  The random stream is therefore a pure function of
the seed and of the tick sequence, and injecting an outlier burst does not
shift the noise of later frames.

Outliers ("important aberrant values", Section III-C, at t = 0.5 s) add
``magnitude_m * (cos theta, sin theta)`` to frames acquired in
``[start, start + duration)``.  The direction is an option of each burst:
``direction: fixed`` uses ``theta = angle_rad`` for every frame of the burst
(a fixed offset, the paper's reading and the default of the paper scenarios in
``config/``); ``direction: random_per_frame`` draws a new ``theta`` for every
frame (zero-mean, much milder for the observer).  Dropouts drop frames acquired in a
window, or at random with ``dropout_probability``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, Literal, NamedTuple

import numba
import numpy as np
import numpy.typing as npt
from numba import types
from numba.extending import overload

from vesselbot_ros.config import ConfigError, check_choice, check_finite, check_nonnegative, check_positive, check_range
from vesselbot_ros.errors import ModelInputError

__all__ = ["OutlierBurst", "Dropout", "ImagerParams", "Measurement", "ImagerModel", "imager_arrays", "imager_frame",
           "imager_acquire", "check_frame_inputs", "draw_variates", "fill_variates", "VariateBuffer"]

_EPS_S = 1e-9  # tick-grid tolerance: a tick within 1 ns of a deadline counts as on time


@dataclasses.dataclass(frozen=True)
class OutlierBurst:
    """Aberrant measurements on frames acquired in ``[start_s, start_s + duration_s)``.

    Attributes:
        start_s: Start time (s).
        duration_s: Duration (s), > 0.
        magnitude_m: Offset added to the measured position (m), > 0.
        direction: ``fixed``: the same offset on every frame of the burst, at
            ``angle_rad``; ``random_per_frame``: a new uniform random angle
            per frame.
        angle_rad: Direction of a ``fixed`` offset in the (x, z) plane (rad):
            0 is +x (downstream, along the vessel axis), pi/2 is +z.
    """

    start_s: float = 0.5
    duration_s: float = 0.02
    magnitude_m: float = 1e-3
    direction: Literal["random_per_frame", "fixed"] = "random_per_frame"
    angle_rad: float = 0.0

    def __post_init__(self) -> None:
        check_nonnegative("start_s", self.start_s)
        check_positive("duration_s", self.duration_s)
        check_positive("magnitude_m", self.magnitude_m)
        check_choice("direction", self.direction, ("random_per_frame", "fixed"))
        check_finite("angle_rad", self.angle_rad)


@dataclasses.dataclass(frozen=True)
class Dropout:
    """No frame delivered for acquisitions in ``[start_s, start_s + duration_s)``."""

    start_s: float = 1.0
    duration_s: float = 0.1

    def __post_init__(self) -> None:
        check_nonnegative("start_s", self.start_s)
        check_positive("duration_s", self.duration_s)


@dataclasses.dataclass(frozen=True)
class ImagerParams:
    """Imager model parameters.

    Attributes:
        noise_sigma_m: Standard deviation of the Gaussian noise per axis (m).
            Paper: 100e-6 (read as sigma).
        frame_rate_Hz: Frames per second (Hz).
        latency_s: Delay from acquisition to delivery (s).
        outliers: Scheduled outlier bursts.
        dropouts: Scheduled dropout windows.
        dropout_probability: Probability that any frame is lost, in [0, 1).
        kind: The imager's stage kind (:mod:`vesselbot_ros.sim.kinds`): ``mri``.
    """

    noise_sigma_m: float = 100e-6
    frame_rate_Hz: float = 50.0
    latency_s: float = 0.0
    outliers: tuple[OutlierBurst, ...] = ()
    dropouts: tuple[Dropout, ...] = ()
    dropout_probability: float = 0.0
    kind: Literal["mri"] = "mri"

    def __post_init__(self) -> None:
        check_choice("kind", self.kind, ("mri",))
        check_nonnegative("noise_sigma_m", self.noise_sigma_m)
        check_positive("frame_rate_Hz", self.frame_rate_Hz)
        check_nonnegative("latency_s", self.latency_s)
        check_range("dropout_probability", self.dropout_probability, 0.0, 1.0, hi_open=True)
        for i, o in enumerate(self.outliers):
            if not isinstance(o, OutlierBurst):
                raise ConfigError(f"outliers[{i}] must be an OutlierBurst, got {o!r}")
        for i, d in enumerate(self.dropouts):
            if not isinstance(d, Dropout):
                raise ConfigError(f"dropouts[{i}] must be a Dropout, got {d!r}")


class Measurement(NamedTuple):
    """One delivered imager frame.

    Attributes:
        t_acq_s: Acquisition time (s).
        p: (2,) measured position, m, frame W.
        outlier: True if an aberrant offset was injected (ground-truth flag
            for analysis; an estimator must not read it).
    """

    t_acq_s: float
    p: npt.NDArray[np.float64]
    outlier: bool


def check_frame_inputs(t_s: float, p_true: npt.ArrayLike, t_last_s: float) -> npt.NDArray[np.float64]:
    """The true position as a (2,) array; ModelInputError unless it is finite and time does not go back."""
    p = np.asarray(p_true, dtype=np.float64)
    if p.shape != (2,) or not (math.isfinite(p[0]) and math.isfinite(p[1])):
        raise ModelInputError(f"imager: true position must be a finite (2,) array, got {p_true!r}")
    if not math.isfinite(t_s) or t_s < t_last_s:
        raise ModelInputError(f"imager: tick time must be finite and non-decreasing, got {t_s!r}")
    return p


class ImagerModel:
    """Stateful imager: call :meth:`frame` once per tick, in time order.

    Args:
        params: Imager parameters.
        rng: Seeded generator; the model owns it from now on.
    """

    def __init__(self, params: ImagerParams, rng: np.random.Generator) -> None:
        self.params = params
        self._variates = VariateBuffer(rng)
        self._prm, self._outliers, self._dropouts = imager_arrays(params)
        # compiled state: next frame slot, last tick time, queue head, queue tail (imager_frame)
        self._state = np.array([0.0, -math.inf, 0.0, 0.0])
        self._queue = new_queue()
        self._out = np.zeros(5)

    @property
    def rng(self) -> np.random.Generator:
        """The generator the imager draws from (owned by the model), exactly where its draws so far left it."""
        return self._variates.generator()

    def variates(self) -> npt.NDArray[np.float64]:
        """The variate buffer for one more acquisition (:class:`VariateBuffer`), for compiled callers."""
        return self._variates.ready()

    @property
    def frame_arrays(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """``(params, outliers, dropouts)`` of :func:`imager_acquire` now (injected bursts included), for compiled callers."""
        return self._prm, self._outliers, self._dropouts

    def inject_outliers(self, start_s: float, duration_s: float, magnitude_m: float,
                        angle_rad: float | None = None) -> None:
        """Add an outlier burst at run time (same effect as a scheduled one).

        ``angle_rad`` None draws a random direction per frame; a number gives a
        fixed offset in that direction.
        """
        burst = OutlierBurst(start_s=start_s, duration_s=duration_s, magnitude_m=magnitude_m,
                             direction="random_per_frame" if angle_rad is None else "fixed",
                             angle_rad=0.0 if angle_rad is None else angle_rad)
        row = np.array([[burst.start_s, burst.start_s + burst.duration_s, burst.magnitude_m,
                         math.nan if angle_rad is None else burst.angle_rad]])
        self._outliers = np.concatenate([self._outliers, row])

    def inject_dropout(self, start_s: float, duration_s: float) -> None:
        """Add a dropout window at run time (same effect as a scheduled one)."""
        d = Dropout(start_s=start_s, duration_s=duration_s)
        self._dropouts = np.concatenate([self._dropouts, np.array([[d.start_s, d.start_s + d.duration_s]])])

    def acquire(self, t_acq_s: float, p: npt.NDArray[np.float64]) -> Measurement | None:
        """One frame of position ``p`` (m) acquired at ``t_acq_s`` (s), or None if it is dropped.

        The acquisition of :func:`imager_frame` on its own (same four draws,
        same doubles), for imagers that decide themselves when to acquire (the
        scanner's :class:`~vesselbot_ros.scanner.stages.SequencedImager`).
        """
        o = self._out
        imager_acquire(self._prm, self._outliers, self._dropouts, self._variates.ready(), float(t_acq_s), float(p[0]),
                       float(p[1]), o)
        if o[0] < 0.5:
            return None
        return Measurement(float(t_acq_s), o[2:4].copy(), bool(o[4] > 0.5))

    def frame(self, t_s: float, p_true: npt.ArrayLike) -> Measurement | None:
        """Acquire (if due) and deliver (if due) at tick ``t_s`` (the compiled :func:`imager_frame`).

        Args:
            t_s: Tick time (s), non-decreasing across calls.
            p_true: (2,) true position at ``t_s``, m, frame W.

        Returns:
            The newest frame delivered at ``t_s``, or None.

        Raises:
            ModelInputError: on a non-finite time or position, a wrong shape or
                time going backwards.
        """
        p = check_frame_inputs(t_s, p_true, self._state[1])
        st = self._state
        self._queue = queue_with_room(self._queue, st, 2, 3)
        imager_frame(self._prm, self._outliers, self._dropouts, st, self._queue, self._variates.ready(), float(t_s),
                     float(p[0]), float(p[1]), self._out)
        o = self._out
        if o[0] < 0.5:
            return None
        return Measurement(float(o[1]), o[2:4].copy(), bool(o[4] > 0.5))


# ---- compiled stage -------------------------------------------------------------------------------
# params (4,): [frame period (s), noise sigma (m), latency (s), dropout probability]
# outliers (m, 4): [start, end, magnitude, fixed angle (rad) or NaN for a random angle per frame];
# dropouts (m, 2): [start, end]
# state (4,): [index of the next frame slot, time of the last call, queue head, queue tail]
# queue (cap, 5): the frame queue (below)
# out (5,): [delivered (0/1), t_acq, p x, p z, outlier]

# The frame queue of every imager kind (this one and the scanner's, scanner/stages.py): frames acquired and not yet
# delivered, a ring of rows [t_deliver, t_acq, p x, p z, outlier] whose head and tail counters live in the imager's
# state array (at the indices the caller gives).  queue_push adds a frame, queue_deliver hands out the due ones,
# queue_with_room grows the ring (Python, between ticks).
QUEUE_COLUMNS = 5


def new_queue() -> npt.NDArray[np.float64]:
    """An empty frame queue (16 rows; :func:`queue_with_room` grows it)."""
    return np.empty((16, QUEUE_COLUMNS))


def queue_with_room(queue: npt.NDArray[np.float64], state: npt.NDArray[np.float64], head: int,
                    tail: int) -> npt.NDArray[np.float64]:
    """``queue``, or a twice larger copy (waiting frames first, oldest first) when one more frame would not fit.

    ``state[head]`` and ``state[tail]`` count the frames taken out and put in; a copy resets them.
    """
    waiting = int(state[tail] - state[head])
    cap = queue.shape[0]
    if waiting + 1 < cap:
        return queue
    order = (int(state[head]) + np.arange(waiting)) % cap
    grown = np.empty((2 * cap, QUEUE_COLUMNS))
    grown[:waiting] = queue[order]
    state[head], state[tail] = 0.0, float(waiting)
    return grown


@numba.njit(cache=True, nogil=True)
def queue_push(queue, state, tail, t_deliver, t_acq, px, pz, outlier):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Put a frame at the ring's tail (the caller sized the ring: :func:`queue_with_room`)."""
    j = int(state[tail]) % queue.shape[0]
    queue[j, 0] = t_deliver
    queue[j, 1] = t_acq
    queue[j, 2] = px
    queue[j, 3] = pz
    queue[j, 4] = outlier
    state[tail] += 1.0


@numba.njit(cache=True, nogil=True)
def queue_deliver(queue, state, head, tail, t, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Take every frame due at ``t`` off the ring's head; ``out`` = the newest ([delivered, t_acq, x, z, outlier])."""
    out[0] = 0.0
    while state[head] < state[tail]:
        j = int(state[head]) % queue.shape[0]
        if not queue[j, 0] <= t + _EPS_S:
            break
        out[0] = 1.0
        out[1] = queue[j, 1]
        out[2] = queue[j, 2]
        out[3] = queue[j, 3]
        out[4] = queue[j, 4]
        state[head] += 1.0


def imager_arrays(params: ImagerParams) -> tuple[npt.NDArray[np.float64], ...]:
    """``(params (4,), outliers (m, 4), dropouts (m, 2))`` of :func:`imager_frame`."""
    prm = np.array([1.0 / params.frame_rate_Hz, float(params.noise_sigma_m), float(params.latency_s),
                    float(params.dropout_probability)])
    out = np.array([(o.start_s, o.start_s + o.duration_s, o.magnitude_m,
                     o.angle_rad if o.direction == "fixed" else math.nan) for o in params.outliers],
                   dtype=np.float64).reshape(-1, 4)
    drop = np.array([(d.start_s, d.start_s + d.duration_s) for d in params.dropouts], dtype=np.float64).reshape(-1, 2)
    return prm, out, drop


def draw_variates(src):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The four variates of one acquisition, in this order: two standard normals, two uniforms.

    Compiled code only.  ``src`` is a ``numpy.random.Generator`` (the compiled
    loop draws from it) or a :class:`VariateBuffer` array (the per-tick path: the
    same variates, drawn ahead in blocks, so that no call from Python passes a
    Generator, which numba types and unboxes on every call, about 8 us).
    """
    raise NotImplementedError("draw_variates runs in compiled code only")


@overload(draw_variates, jit_options={"nogil": True})
def _draw_variates(src):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if isinstance(src, types.NumPyRandomGeneratorType):
        def from_generator(src):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
            n0 = src.standard_normal()
            n1 = src.standard_normal()
            u0 = src.random()
            u1 = src.random()
            return n0, n1, u0, u1
        return from_generator
    if isinstance(src, types.Array):
        def from_buffer(src):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
            i = int(src[0])
            src[0] = i + 4
            return src[i + 1], src[i + 2], src[i + 3], src[i + 4]
        return from_buffer
    return None


@numba.njit(cache=True, nogil=True)
def fill_variates(rng, buf):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Draw ``buf[1:]`` from ``rng`` in :func:`draw_variates`' order; ``buf[0] = 0`` (none used)."""
    for i in range(1, buf.shape[0] - 3, 4):
        buf[i] = rng.standard_normal()
        buf[i + 1] = rng.standard_normal()
        buf[i + 2] = rng.random()
        buf[i + 3] = rng.random()
    buf[0] = 0.0


class VariateBuffer:
    """A Generator's acquisition variates, drawn ahead in blocks (the same stream, the same doubles).

    ``buf[0]`` counts the variates used, ``buf[1:]`` holds them.  :meth:`ready`
    refills when fewer than one acquisition's four remain; :meth:`generator`
    gives the Generator back exactly where the variates used so far left it
    (it rewinds to the last refill and draws only what was used).
    """

    #: Acquisitions per block.
    BLOCK = 256

    def __init__(self, rng: np.random.Generator, per: int = 4, fill: Any = None) -> None:
        self._rng = rng
        self._per = int(per)  # variates per acquisition (the 3-D imager draws 6: control/imager3d.py)
        self._fill = fill_variates if fill is None else fill  # draws them in the imager's order
        self.buf = np.zeros(1 + self._per * self.BLOCK)
        self.buf[0] = float(self.buf.shape[0] - 1)  # empty: the first use fills
        self._state_at_fill: Mapping[str, Any] | None = None

    def ready(self) -> npt.NDArray[np.float64]:
        """The buffer, with at least one acquisition's variates left."""
        b = self.buf
        if b[0] + self._per > b.shape[0] - 1:
            self._state_at_fill = self._rng.bit_generator.state
            self._fill(self._rng, b)
        return b

    def generator(self) -> np.random.Generator:
        """The Generator, advanced by exactly the variates used (the buffer is emptied)."""
        if self._state_at_fill is not None:
            used = int(self.buf[0])
            self._rng.bit_generator.state = self._state_at_fill
            if used:
                self._fill(self._rng, np.zeros(1 + used))
            self._state_at_fill = None
            self.buf[0] = float(self.buf.shape[0] - 1)
        return self._rng


@numba.njit(cache=True, nogil=True)
def imager_acquire(prm, outliers, dropouts, rng, t, px, pz, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Acquire one frame of ``(px, pz)`` at ``t``: ``out[0]`` 1 if kept (0 if dropped), ``out[2:5]`` = (x, z, outlier).

    Draws two standard normals (noise on x, z), one uniform (outlier
    direction) and one uniform (random dropout), in this order, always.
    """
    n0, n1, u_dir, u_drop = draw_variates(rng)
    m0 = px + prm[1] * n0
    m1 = pz + prm[1] * n1
    outlier = 0.0
    for i in range(outliers.shape[0]):
        if outliers[i, 0] - _EPS_S <= t < outliers[i, 1] - _EPS_S:
            th = 2.0 * math.pi * u_dir if math.isnan(outliers[i, 3]) else outliers[i, 3]
            m0 = m0 + outliers[i, 2] * math.cos(th)
            m1 = m1 + outliers[i, 2] * math.sin(th)
            outlier = 1.0
            break
    dropped = u_drop < prm[3]
    if not dropped:
        for i in range(dropouts.shape[0]):
            if dropouts[i, 0] - _EPS_S <= t < dropouts[i, 1] - _EPS_S:
                dropped = True
                break
    out[0] = 0.0 if dropped else 1.0
    out[1] = t
    out[2] = m0
    out[3] = m1
    out[4] = outlier


@numba.njit(cache=True, nogil=True)
def imager_frame(prm, outliers, dropouts, state, queue, rng, t, px, pz, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:meth:`ImagerModel.frame` over explicit state (same draws, same doubles).

    The caller checks that ``t`` and ``(px, pz)`` are finite and that time does
    not go backwards, and sizes ``queue`` for every frame that can wait
    (one row per tick is always enough).  Draws from ``rng`` (a
    ``numpy.random.Generator``) in the documented order: two standard normals,
    two uniforms per acquired frame.  Writes ``out``; allocates nothing.
    """
    state[1] = t
    period = prm[0]
    if t + _EPS_S >= state[0] * period:
        state[0] = float(int(math.floor((t + _EPS_S) / period)) + 1)
        imager_acquire(prm, outliers, dropouts, rng, t, px, pz, out)
        if out[0] > 0.5:
            queue_push(queue, state, 3, t + prm[2], t, out[2], out[3], out[4])
    queue_deliver(queue, state, 2, 3, t, out)
