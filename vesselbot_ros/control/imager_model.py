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

Outliers ("aberrant values", Section III-C, at t = 0.5 s) add
``magnitude_m * (cos theta, sin theta)`` with a random ``theta`` to frames
acquired in ``[start, start + duration)``.  Dropouts drop frames acquired in a
window, or at random with ``dropout_probability``.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from vesselbot_ros.config import ConfigError, check_nonnegative, check_positive, check_range
from vesselbot_ros.errors import ModelInputError

__all__ = ["OutlierBurst", "Dropout", "ImagerParams", "Measurement", "ImagerModel"]

_EPS_S = 1e-9  # tick-grid tolerance: a tick within 1 ns of a deadline counts as on time


@dataclasses.dataclass(frozen=True)
class OutlierBurst:
    """Aberrant measurements on frames acquired in ``[start_s, start_s + duration_s)``.

    Attributes:
        start_s: Start time (s).
        duration_s: Duration (s), > 0.
        magnitude_m: Offset added to the measured position (m), > 0.
    """

    start_s: float = 0.5
    duration_s: float = 0.02
    magnitude_m: float = 1e-3

    def __post_init__(self) -> None:
        check_nonnegative("start_s", self.start_s)
        check_positive("duration_s", self.duration_s)
        check_positive("magnitude_m", self.magnitude_m)


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
    """

    noise_sigma_m: float = 100e-6
    frame_rate_Hz: float = 50.0
    latency_s: float = 0.0
    outliers: tuple[OutlierBurst, ...] = ()
    dropouts: tuple[Dropout, ...] = ()
    dropout_probability: float = 0.0

    def __post_init__(self) -> None:
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
        self._rng = rng
        self._period = 1.0 / params.frame_rate_Hz
        self._n_next = 0
        self._queue: deque[Measurement] = deque()
        self._outliers: list[tuple[float, float, float]] = [
            (o.start_s, o.start_s + o.duration_s, o.magnitude_m) for o in params.outliers
        ]
        self._dropouts: list[tuple[float, float]] = [(d.start_s, d.start_s + d.duration_s) for d in params.dropouts]
        self._t_last = -math.inf

    def inject_outliers(self, start_s: float, duration_s: float, magnitude_m: float) -> None:
        """Add an outlier burst at run time (same effect as a scheduled one)."""
        burst = OutlierBurst(start_s=start_s, duration_s=duration_s, magnitude_m=magnitude_m)
        self._outliers.append((burst.start_s, burst.start_s + burst.duration_s, burst.magnitude_m))

    def inject_dropout(self, start_s: float, duration_s: float) -> None:
        """Add a dropout window at run time (same effect as a scheduled one)."""
        d = Dropout(start_s=start_s, duration_s=duration_s)
        self._dropouts.append((d.start_s, d.start_s + d.duration_s))

    def acquire(self, t_acq_s: float, p: npt.NDArray[np.float64]) -> Measurement | None:
        """One frame of position ``p`` (m) acquired at ``t_acq_s`` (s), or None if it is dropped.

        Draws the frame's four random numbers (two normals for the noise, one
        uniform for the outlier direction, one for random dropout, in this
        order, whether or not they are used), so the stream depends only on the
        seed and on how many frames were acquired.
        """
        prm = self.params
        noise = self._rng.standard_normal(2)
        u_dir = self._rng.random()
        u_drop = self._rng.random()
        meas = p + prm.noise_sigma_m * noise
        outlier = False
        for a, b, mag in self._outliers:
            if a - _EPS_S <= t_acq_s < b - _EPS_S:
                th = 2.0 * math.pi * u_dir
                meas = meas + mag * np.array([math.cos(th), math.sin(th)])
                outlier = True
                break
        dropped = u_drop < prm.dropout_probability or any(a - _EPS_S <= t_acq_s < b - _EPS_S for a, b in self._dropouts)
        return None if dropped else Measurement(float(t_acq_s), meas, outlier)

    def frame(self, t_s: float, p_true: npt.ArrayLike) -> Measurement | None:
        """Acquire (if due) and deliver (if due) at tick ``t_s``.

        Args:
            t_s: Tick time (s), non-decreasing across calls.
            p_true: (2,) true position at ``t_s``, m, frame W.

        Returns:
            The newest frame delivered at ``t_s``, or None.

        Raises:
            ModelInputError: on a non-finite time or position, a wrong shape or
                time going backwards.
        """
        p = check_frame_inputs(t_s, p_true, self._t_last)
        self._t_last = t_s
        prm = self.params
        if t_s + _EPS_S >= self._n_next * self._period:
            # skip frames whose slot passed between ticks (ticks slower than frames)
            self._n_next = int(math.floor((t_s + _EPS_S) / self._period)) + 1
            meas = self.acquire(float(t_s), p)
            if meas is not None:
                self._queue.append(meas)
        out: Measurement | None = None
        while self._queue and self._queue[0].t_acq_s + prm.latency_s <= t_s + _EPS_S:
            out = self._queue.popleft()
        return out
