"""The MRI position measurement in three dimensions: the planar imager's model with a noise per axis of space.

:class:`~vesselbot_ros.control.imager_model.ImagerModel`'s parameters (:class:`ImagerParams`) and timing, word
for word (its module docstring): a frame is acquired at the first tick at or after each ``n / frame_rate_Hz``,
delivered at the first tick at or after ``t_acq + latency_s``, the newest of the frames due.  In space:

* noise: a zero-mean Gaussian of standard deviation ``noise_sigma_m`` on each of x, y and z;
* outliers: ``magnitude_m`` along a direction: ``direction: fixed`` keeps the burst's ``angle_rad`` in the
  scanner's XZ plane, ``(cos a, 0, sin a)`` (the planar imager's offset); ``random_per_frame`` draws a
  direction uniform on the sphere for each frame;
* draws per acquired frame, always, in this order: three standard normals (x, y, z), one uniform (the
  direction's azimuth), one uniform (random dropout) and one uniform (the direction's polar cosine), so one
  seed gives one stream whatever the bursts and the dropouts.

The stage (:class:`Imager3D`) and the compiled 3-D loop (:mod:`vesselbot_ros.sim.compiled_loop3d`) call the same
compiled :func:`imager3d_frame`; the stage draws through a
:class:`~vesselbot_ros.control.imager_model.VariateBuffer` (the same stream, drawn ahead in blocks).
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt
from numba import types
from numba.extending import overload

from vesselbot_ros.control.imager_model import ImagerParams, Measurement, VariateBuffer, imager_arrays
from vesselbot_ros.errors import ModelInputError

__all__ = ["Imager3D", "DRAWS_PER_FRAME", "imager3d_frame", "imager3d_acquire", "fill_variates3d", "draw_variates3d",
           "queue_rows", "queue3d_push", "queue3d_deliver"]

_EPS_S = 1e-9  # the planar imager's tick-grid tolerance
#: Variates drawn per acquired frame.
DRAWS_PER_FRAME = 6


def draw_variates3d(src):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The six variates of one acquisition (module docstring); compiled code only, from a Generator or a buffer."""
    raise NotImplementedError("draw_variates3d runs in compiled code only")


@overload(draw_variates3d, jit_options={"nogil": True})
def _draw_variates3d(src):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    if isinstance(src, types.NumPyRandomGeneratorType):
        def from_generator(src):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
            n0 = src.standard_normal()
            n1 = src.standard_normal()
            n2 = src.standard_normal()
            u0 = src.random()
            u1 = src.random()
            u2 = src.random()
            return n0, n1, n2, u0, u1, u2
        return from_generator
    if isinstance(src, types.Array):
        def from_buffer(src):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
            i = int(src[0])
            src[0] = i + 6
            return src[i + 1], src[i + 2], src[i + 3], src[i + 4], src[i + 5], src[i + 6]
        return from_buffer
    return None


@numba.njit(cache=True, nogil=True)
def fill_variates3d(rng, buf):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Draw ``buf[1:]`` from ``rng`` in :func:`draw_variates3d`'s order; ``buf[0] = 0`` (none used)."""
    for i in range(1, buf.shape[0] - 5, 6):
        buf[i] = rng.standard_normal()
        buf[i + 1] = rng.standard_normal()
        buf[i + 2] = rng.standard_normal()
        buf[i + 3] = rng.random()
        buf[i + 4] = rng.random()
        buf[i + 5] = rng.random()
    buf[0] = 0.0


@numba.njit(cache=True, nogil=True)
def imager3d_acquire(prm, outliers, dropouts, rng, t, px, py, pz, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Acquire one frame of ``(px, py, pz)`` at ``t``: ``out[0]`` 1 if kept, ``out[2:6]`` = (x, y, z, outlier).

    ``prm``, ``outliers``, ``dropouts``: :func:`~vesselbot_ros.control.imager_model.imager_arrays`.  Six draws, always.
    """
    n0, n1, n2, u_dir, u_drop, u_pol = draw_variates3d(rng)
    m0 = px + prm[1] * n0
    m1 = py + prm[1] * n1
    m2 = pz + prm[1] * n2
    outlier = 0.0
    for i in range(outliers.shape[0]):
        if outliers[i, 0] - _EPS_S <= t < outliers[i, 1] - _EPS_S:
            if math.isnan(outliers[i, 3]):
                phi = 2.0 * math.pi * u_dir
                c = 2.0 * u_pol - 1.0
                s = math.sqrt(max(0.0, 1.0 - c * c))
                d0 = s * math.cos(phi)
                d1 = s * math.sin(phi)
                d2 = c
            else:
                d0 = math.cos(outliers[i, 3])
                d1 = 0.0
                d2 = math.sin(outliers[i, 3])
            m0 = m0 + outliers[i, 2] * d0
            m1 = m1 + outliers[i, 2] * d1
            m2 = m2 + outliers[i, 2] * d2
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
    out[4] = m2
    out[5] = outlier


@numba.njit(cache=True, nogil=True)
def imager3d_frame(prm, outliers, dropouts, state, queue, rng, t, px, py, pz, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """:meth:`Imager3D.frame` over explicit state: acquire if due, queue, deliver the newest frame due.

    ``state`` (4,): [next frame slot, last tick time, queue head, queue tail]; ``queue`` (rows, 6) ring of
    [t_deliver, t_acq, x, y, z, outlier] (:func:`queue_rows` rows); ``out`` (6,) [delivered, t_acq, x, y, z,
    outlier].  The caller checks that ``t`` and the position are finite and that time does not go back.
    """
    state[1] = t
    period = prm[0]
    if t + _EPS_S >= state[0] * period:
        state[0] = float(int(math.floor((t + _EPS_S) / period)) + 1)
        imager3d_acquire(prm, outliers, dropouts, rng, t, px, py, pz, out)
        if out[0] > 0.5:
            queue3d_push(queue, state, 3, t + prm[2], out)
    queue3d_deliver(queue, state, 2, 3, t, out)


@numba.njit(cache=True, nogil=True)
def queue3d_push(queue, state, tail, t_deliver, frame):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Put ``frame[1:6]`` (t_acq, x, y, z, outlier), due at ``t_deliver``, at the ring's tail (``state[tail]``)."""
    j = int(state[tail]) % queue.shape[0]
    queue[j, 0] = t_deliver
    for c in range(1, 6):
        queue[j, c] = frame[c]
    state[tail] += 1.0


@numba.njit(cache=True, nogil=True)
def queue3d_deliver(queue, state, head, tail, t, out):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Take every frame due at ``t`` off the ring's head; ``out`` = the newest ([delivered, t_acq, x, y, z, outlier])."""
    out[0] = 0.0
    while state[head] < state[tail]:
        j = int(state[head]) % queue.shape[0]
        if not queue[j, 0] <= t + _EPS_S:
            break
        out[0] = 1.0
        for c in range(1, 6):
            out[c] = queue[j, c]
        state[head] += 1.0


def queue_rows(params: ImagerParams) -> int:
    """Rows of the delivery ring: every frame that can wait for its delivery, and some."""
    return int(math.ceil(params.latency_s * params.frame_rate_Hz)) + 4


class Imager3D:
    """Stateful 3-D imager: call :meth:`frame` once per tick, in time order.

    Args:
        params: Imager parameters.
        rng: Seeded generator; the imager owns it from now on.
    """

    dims = 3

    def __init__(self, params: ImagerParams, rng: np.random.Generator) -> None:
        self.params = params
        self._variates = VariateBuffer(rng, DRAWS_PER_FRAME, fill_variates3d)
        self._prm, self._outliers, self._dropouts = imager_arrays(params)
        self._state = np.array([0.0, -math.inf, 0.0, 0.0])
        self._queue = np.zeros((queue_rows(params), 6))
        self._out = np.zeros(6)

    @property
    def rng(self) -> np.random.Generator:
        """The generator the imager draws from, exactly where its draws so far left it."""
        return self._variates.generator()

    def variates(self) -> npt.NDArray[np.float64]:
        """The variate buffer for one more acquisition, for compiled callers (the scanner's imager)."""
        return self._variates.ready()

    @property
    def frame_arrays(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """``(params, outliers, dropouts)`` now (injected bursts included), for compiled callers."""
        return self._prm, self._outliers, self._dropouts

    def inject_outliers(self, start_s: float, duration_s: float, magnitude_m: float, angle_rad: float | None = None) -> None:
        """Add an outlier burst at run time (``angle_rad`` None: a random direction per frame)."""
        row = np.array([[start_s, start_s + duration_s, magnitude_m, math.nan if angle_rad is None else angle_rad]])
        self._outliers = np.concatenate([self._outliers, row])

    def inject_dropout(self, start_s: float, duration_s: float) -> None:
        """Add a dropout window at run time."""
        self._dropouts = np.concatenate([self._dropouts, np.array([[start_s, start_s + duration_s]])])

    def acquire(self, t_acq_s: float, p: npt.NDArray[np.float64]) -> Measurement | None:
        """One frame of ``p`` (3,) acquired at ``t_acq_s`` (s), or None if it is dropped (the six draws always)."""
        o = self._out
        imager3d_acquire(self._prm, self._outliers, self._dropouts, self._variates.ready(), float(t_acq_s), float(p[0]),
                         float(p[1]), float(p[2]), o)
        if o[0] < 0.5:
            return None
        return Measurement(float(t_acq_s), o[2:5].copy(), bool(o[5] > 0.5))

    def frame(self, t_s: float, p_true: npt.ArrayLike) -> Measurement | None:
        """Acquire (if due) and deliver (if due) at tick ``t_s``: the newest frame delivered, or None.

        Raises:
            ModelInputError: on a non-finite time or position, a wrong shape or time going backwards.
        """
        p = np.asarray(p_true, dtype=np.float64)
        if p.shape != (3,) or not (math.isfinite(p[0]) and math.isfinite(p[1]) and math.isfinite(p[2])):
            raise ModelInputError(f"imager: true position must be a finite (3,) array, got {p_true!r}")
        if not math.isfinite(t_s) or t_s < self._state[1]:
            raise ModelInputError(f"imager: tick time must be finite and non-decreasing, got {t_s!r}")
        o = self._out
        imager3d_frame(self._prm, self._outliers, self._dropouts, self._state, self._queue, self._variates.ready(),
                       float(t_s), float(p[0]), float(p[1]), float(p[2]), o)
        if o[0] < 0.5:
            return None
        return Measurement(float(o[1]), o[2:5].copy(), bool(o[5] > 0.5))
