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

One imager on the position's axes: two in the plane (x, z), three in a 3-D tree (x, y, z); the axis count is
the imager's ``dims``, read by the compiled steps from the arrays they get.

Random draws: every acquired frame on ``d`` axes draws exactly ``2 d`` numbers
from the generator, in this order: ``d`` standard normals (the noise on each
axis), one uniform (outlier direction), one uniform (random dropout) and, in
space, one uniform (the direction's polar cosine), whether or not the frame is
an outlier or dropped.  In the plane that is two normals and two uniforms.  The
random stream is therefore a pure function of the seed and of the tick
sequence, and injecting an outlier burst does not shift the noise of later frames.

Outliers ("important aberrant values", Section III-C, at t = 0.5 s) add
``magnitude_m * (cos theta, sin theta)`` in the scanner's XZ plane to frames
acquired in ``[start, start + duration)``.  The direction is an option of each
burst: ``direction: fixed`` uses ``theta = angle_rad`` for every frame of the
burst (a fixed offset, the paper's reading and the default of the paper
scenarios in ``config/``); ``direction: random_per_frame`` draws a new direction
for every frame, uniform on the circle in the plane and on the sphere in space
(zero-mean, much milder for the observer).  Dropouts drop frames acquired in a
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
           "imager_acquire", "check_frame_inputs", "next_normal", "next_uniform", "fill_variates", "VariateBuffer",
           "queue_push", "queue_deliver", "new_queue", "queue_with_room", "queue_columns", "frame_out_size"]

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
        p: (dims,) measured position, m, frame W: (x, z) in the plane, (x, y, z) in space.
        outlier: True if an aberrant offset was injected (ground-truth flag
            for analysis; an estimator must not read it).
    """

    t_acq_s: float
    p: npt.NDArray[np.float64]
    outlier: bool


def check_frame_inputs(t_s: float, p_true: npt.ArrayLike, t_last_s: float, dims: int = 2) -> npt.NDArray[np.float64]:
    """The true position as a fresh contiguous (dims,) array, what the compiled frame takes; ModelInputError unless
    it is finite and time does not go back."""
    p = np.array(p_true, dtype=np.float64)
    if p.shape != (dims,) or not bool(np.isfinite(p).all()):
        raise ModelInputError(f"imager: true position must be a finite ({dims},) array, got {p_true!r}")
    if not math.isfinite(t_s) or t_s < t_last_s:
        raise ModelInputError(f"imager: tick time must be finite and non-decreasing, got {t_s!r}")
    return p


class CompiledImager(NamedTuple):
    """An imager as the compiled loop runs it: the arrays of :func:`imager_acquire` (``prm``, ``outliers``,
    ``dropouts``, injected bursts included) and the scanner's sequence vector ``sv`` it acquires on (None: a frame
    every imaging period, no sequence)."""

    prm: npt.NDArray[np.float64]
    outliers: npt.NDArray[np.float64]
    dropouts: npt.NDArray[np.float64]
    sv: npt.NDArray[np.float64] | None = None


class ImagerModel:
    """Stateful imager on ``dims`` axes: call :meth:`frame` once per tick, in time order.

    Args:
        params: Imager parameters.
        rng: Seeded generator; the model owns it from now on.
        dims: Position axes: 2 (the plane's x, z) or 3 (x, y, z).
    """

    def __init__(self, params: ImagerParams, rng: np.random.Generator, dims: int = 2) -> None:
        if dims not in (2, 3):
            raise ModelInputError(f"an imager has 2 or 3 axes, got {dims!r}")
        self.params = params
        self.dims = int(dims)
        self._variates = VariateBuffer(rng, dims)
        self._prm, self._outliers, self._dropouts = imager_arrays(params)
        # compiled state: next frame slot, last tick time, queue head, queue tail (imager_frame)
        self._state = np.array([0.0, -math.inf, 0.0, 0.0])
        self._queue = new_queue(dims)
        self._out = np.zeros(frame_out_size(dims))

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

    def compiled(self) -> CompiledImager:
        """This imager's compiled form (its kind's :attr:`~vesselbot_ros.sim.kinds.StageKind.compile`)."""
        return CompiledImager(*self.frame_arrays)

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

    def _measurement(self) -> Measurement | None:
        o, d = self._out, self.dims
        if o[0] < 0.5:
            return None
        return Measurement(float(o[1]), o[2:2 + d].copy(), bool(o[2 + d] > 0.5))

    def acquire(self, t_acq_s: float, p: npt.NDArray[np.float64]) -> Measurement | None:
        """One frame of position ``p`` (m, (dims,)) acquired at ``t_acq_s`` (s), or None if it is dropped.

        The acquisition of :func:`imager_frame` on its own (same draws, same
        doubles), for imagers that decide themselves when to acquire (the
        scanner's :class:`~vesselbot_ros.scanner.stages.SequencedImager`).
        """
        imager_acquire(self._prm, self._outliers, self._dropouts, self._variates.ready(), float(t_acq_s),
                       np.array(p, dtype=np.float64), self._out)
        return self._measurement()

    def frame(self, t_s: float, p_true: npt.ArrayLike) -> Measurement | None:
        """Acquire (if due) and deliver (if due) at tick ``t_s`` (the compiled :func:`imager_frame`).

        Args:
            t_s: Tick time (s), non-decreasing across calls.
            p_true: (dims,) true position at ``t_s``, m, frame W.

        Returns:
            The newest frame delivered at ``t_s``, or None.

        Raises:
            ModelInputError: on a non-finite time or position, a wrong shape or
                time going backwards.
        """
        p = check_frame_inputs(t_s, p_true, self._state[1], self.dims)
        st = self._state
        self._queue = queue_with_room(self._queue, st, 2, 3)
        imager_frame(self._prm, self._outliers, self._dropouts, st, self._queue, self._variates.ready(), float(t_s), p,
                     self._out)
        return self._measurement()


# ---- compiled stage -------------------------------------------------------------------------------
# On d position axes (2: x, z; 3: x, y, z), read from the position array's length:
# params (4,): [frame period (s), noise sigma (m), latency (s), dropout probability]
# outliers (m, 4): [start, end, magnitude, fixed angle (rad) or NaN for a random direction per frame];
# dropouts (m, 2): [start, end]
# state (4,): [index of the next frame slot, time of the last call, queue head, queue tail]
# queue (cap, 3 + d): the frame queue (below)
# out (3 + d,): [delivered (0/1), t_acq, p (d), outlier]
def frame_out_size(dims: int) -> int:
    """Length of an imager's ``out`` (and of a queue row) on ``dims`` axes."""
    return 3 + int(dims)


def queue_columns(dims: int) -> int:
    """Columns of the frame queue on ``dims`` axes: [t_deliver, t_acq, p (dims), outlier]."""
    return frame_out_size(dims)


# The frame queue of every imager kind (this one and the scanner's, scanner/stages.py): frames acquired and not yet
# delivered, a ring of rows [t_deliver, t_acq, p (d), outlier] whose head and tail counters live in the imager's
# state array (at the indices the caller gives).  queue_push adds a frame, queue_deliver hands out the due ones,
# queue_with_room grows the ring (Python, between ticks).
def new_queue(dims: int = 2) -> npt.NDArray[np.float64]:
    """An empty frame queue (16 rows; :func:`queue_with_room` grows it)."""
    return np.empty((16, queue_columns(dims)))


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
    grown = np.empty((2 * cap, queue.shape[1]))
    grown[:waiting] = queue[order]
    state[head], state[tail] = 0.0, float(waiting)
    return grown


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on the views it passes (physics.integrator)
def queue_push(queue, state, tail, t_deliver, frame):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Put ``frame[1:]`` (an imager's ``out``: t_acq, p, outlier), due at ``t_deliver``, at the ring's tail (the
    caller sized the ring: :func:`queue_with_room`)."""
    j = int(state[tail]) % queue.shape[0]
    queue[j, 0] = t_deliver
    for c in range(1, queue.shape[1]):
        queue[j, c] = frame[c]
    state[tail] += 1.0


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on the views it passes (physics.integrator)
def queue_deliver(queue, state, head, tail, t, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Take every frame due at ``t`` off the ring's head; ``out`` = the newest ([delivered, t_acq, p, outlier])."""
    out[0] = 0.0
    while state[head] < state[tail]:
        j = int(state[head]) % queue.shape[0]
        if not queue[j, 0] <= t + _EPS_S:
            break
        out[0] = 1.0
        for c in range(1, queue.shape[1]):
            out[c] = queue[j, c]
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


def next_normal(src):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The next standard normal of an acquisition's draws (compiled code only).

    ``src`` is a ``numpy.random.Generator`` (the compiled loop draws from it) or a
    :class:`VariateBuffer` array (the per-tick path: the same variates, drawn
    ahead in blocks, so that no call from Python passes a Generator, which numba
    types and unboxes on every call, about 8 us).
    """
    raise NotImplementedError("next_normal runs in compiled code only")


def next_uniform(src):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The next uniform on [0, 1) of an acquisition's draws (compiled code only; ``src`` as :func:`next_normal`)."""
    raise NotImplementedError("next_uniform runs in compiled code only")


def _from_buffer(src):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    i = int(src[0])
    src[0] = i + 1
    return src[i + 1]


@overload(next_normal, jit_options={"nogil": True})
def _next_normal(src):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if isinstance(src, types.NumPyRandomGeneratorType):
        return lambda src: src.standard_normal()
    if isinstance(src, types.Array):
        return _from_buffer
    return None


@overload(next_uniform, jit_options={"nogil": True})
def _next_uniform(src):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if isinstance(src, types.NumPyRandomGeneratorType):
        return lambda src: src.random()
    if isinstance(src, types.Array):
        return _from_buffer
    return None


@numba.njit(cache=True, nogil=True)
def fill_variates(rng, buf, dims):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Draw ``buf[1:]`` from ``rng`` in the acquisitions' order on ``dims`` axes (``dims`` normals, then ``dims``
    uniforms, per acquisition); ``buf[0] = 0`` (none used)."""
    per = 2 * dims
    for i in range(1, buf.shape[0] - per + 1, per):
        for c in range(dims):
            buf[i + c] = rng.standard_normal()
        for c in range(dims):
            buf[i + dims + c] = rng.random()
    buf[0] = 0.0


class VariateBuffer:
    """A Generator's acquisition variates on ``dims`` axes, drawn ahead in blocks (the same stream, the same doubles).

    ``buf[0]`` counts the variates used, ``buf[1:]`` holds them.  :meth:`ready`
    refills when fewer than one acquisition's ``2 dims`` remain; :meth:`generator`
    gives the Generator back exactly where the variates used so far left it
    (it rewinds to the last refill and draws only what was used).
    """

    #: Acquisitions per block.
    BLOCK = 256

    def __init__(self, rng: np.random.Generator, dims: int = 2, buf: npt.NDArray[np.float64] | None = None) -> None:
        """``buf``: the array to hold the variates (a row of a bank of buffers, one per copy of a loop stepped in
        one call; float64, of ``1 + 2 dims * BLOCK``); None: its own."""
        self._rng = rng
        self._dims = int(dims)
        self._per = 2 * self._dims  # variates per acquisition
        self.buf = np.zeros(1 + self._per * self.BLOCK) if buf is None else buf
        if self.buf.shape != (1 + self._per * self.BLOCK,) or self.buf.dtype != np.float64:
            raise ModelInputError(f"VariateBuffer: buf of shape {self.buf.shape} ({self.buf.dtype}), expected "
                             f"({1 + self._per * self.BLOCK},) float64")
        self.buf[0] = float(self.buf.shape[0] - 1)  # empty: the first use fills
        self._state_at_fill: Mapping[str, Any] | None = None

    def ready(self) -> npt.NDArray[np.float64]:
        """The buffer, with at least one acquisition's variates left."""
        b = self.buf
        if b[0] + self._per > b.shape[0] - 1:
            self._state_at_fill = self._rng.bit_generator.state
            fill_variates(self._rng, b, self._dims)
        return b

    def generator(self) -> np.random.Generator:
        """The Generator, advanced by exactly the variates used (the buffer is emptied)."""
        if self._state_at_fill is not None:
            used = int(self.buf[0])
            self._rng.bit_generator.state = self._state_at_fill
            if used:
                fill_variates(self._rng, np.zeros(1 + used), self._dims)
            self._state_at_fill = None
            self.buf[0] = float(self.buf.shape[0] - 1)
        return self._rng


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on the views it passes (physics.integrator)
def imager_acquire(prm, outliers, dropouts, rng, t, p, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Acquire one frame of position ``p`` (d,) at ``t``: ``out[0]`` 1 if kept (0 if dropped), ``out[1]`` = t,
    ``out[2:2 + d]`` the measured position, ``out[2 + d]`` the outlier flag.

    Draws ``d`` standard normals (the noise per axis), one uniform (outlier
    direction), one uniform (random dropout) and, in space, one uniform (the
    direction's polar cosine), in this order, always.  ``p`` may be ``out[2:2 + d]``.
    """
    d = p.shape[0]
    for c in range(d):
        out[2 + c] = p[c] + prm[1] * next_normal(rng)
    u_dir = next_uniform(rng)
    u_drop = next_uniform(rng)
    u_pol = next_uniform(rng) if d == 3 else 0.0  # axis count: the plane draws no polar variate (its stream stays)
    outlier = 0.0
    last = d - 1  # z: the plane's second axis, space's third
    for i in range(outliers.shape[0]):
        if outliers[i, 0] - _EPS_S <= t < outliers[i, 1] - _EPS_S:
            mag = outliers[i, 2]
            if math.isnan(outliers[i, 3]) and d == 3:  # a direction uniform on the sphere
                phi = 2.0 * math.pi * u_dir
                cz = 2.0 * u_pol - 1.0
                sz = math.sqrt(max(0.0, 1.0 - cz * cz))
                out[2] = out[2] + mag * (sz * math.cos(phi))
                out[3] = out[3] + mag * (sz * math.sin(phi))
                out[4] = out[4] + mag * cz
            else:  # in the scanner's XZ plane: the burst's fixed angle, or one uniform on the circle
                th = 2.0 * math.pi * u_dir if math.isnan(outliers[i, 3]) else outliers[i, 3]
                out[2] = out[2] + mag * math.cos(th)
                out[2 + last] = out[2 + last] + mag * math.sin(th)
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
    out[2 + d] = outlier


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on the views it passes (physics.integrator)
def imager_frame(prm, outliers, dropouts, state, queue, rng, t, p, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:meth:`ImagerModel.frame` over explicit state (same draws, same doubles), on the axes of ``p`` (d,).

    The caller checks that ``t`` and ``p`` are finite and that time does
    not go backwards, and sizes ``queue`` (cap, 3 + d) for every frame that can wait
    (one row per tick is always enough).  Draws from ``rng`` (a
    ``numpy.random.Generator`` or a :class:`VariateBuffer` array) in the documented order.
    Writes ``out`` (3 + d,); allocates nothing.
    """
    state[1] = t
    period = prm[0]
    if t + _EPS_S >= state[0] * period:
        state[0] = float(int(math.floor((t + _EPS_S) / period)) + 1)
        imager_acquire(prm, outliers, dropouts, rng, t, p, out)
        if out[0] > 0.5:
            queue_push(queue, state, 3, t + prm[2], out)
    queue_deliver(queue, state, 2, 3, t, out)
