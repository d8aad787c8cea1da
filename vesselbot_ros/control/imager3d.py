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
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
import numpy.typing as npt

from vesselbot_ros.control.imager_model import ImagerParams, Measurement
from vesselbot_ros.errors import ModelInputError

__all__ = ["Imager3D", "DRAWS_PER_FRAME"]

_EPS_S = 1e-9  # the planar imager's tick-grid tolerance
#: Variates drawn per acquired frame.
DRAWS_PER_FRAME = 6


class Imager3D:
    """Stateful 3-D imager: call :meth:`frame` once per tick, in time order.

    Args:
        params: Imager parameters.
        rng: Seeded generator; the imager owns it from now on.
    """

    dims = 3

    def __init__(self, params: ImagerParams, rng: np.random.Generator) -> None:
        self.params = params
        self.rng = rng
        self._period = 1.0 / params.frame_rate_Hz
        self._next = 0
        self._t_last = -math.inf
        self._queue: deque[tuple[float, float, npt.NDArray[np.float64], bool]] = deque()
        self._outliers = [(o.start_s, o.start_s + o.duration_s, o.magnitude_m,
                           o.angle_rad if o.direction == "fixed" else math.nan) for o in params.outliers]
        self._dropouts = [(d.start_s, d.start_s + d.duration_s) for d in params.dropouts]

    def inject_outliers(self, start_s: float, duration_s: float, magnitude_m: float, angle_rad: float | None = None) -> None:
        """Add an outlier burst at run time (``angle_rad`` None: a random direction per frame)."""
        self._outliers.append((start_s, start_s + duration_s, magnitude_m, math.nan if angle_rad is None else angle_rad))

    def inject_dropout(self, start_s: float, duration_s: float) -> None:
        """Add a dropout window at run time."""
        self._dropouts.append((start_s, start_s + duration_s))

    def acquire(self, t_acq_s: float, p: npt.NDArray[np.float64]) -> Measurement | None:
        """One frame of ``p`` (3,) acquired at ``t_acq_s`` (s), or None if it is dropped (the six draws always)."""
        v = self.rng.standard_normal(3)
        u_dir, u_drop, u_pol = self.rng.random(3)
        sig = self.params.noise_sigma_m
        m = np.array([p[0] + sig * v[0], p[1] + sig * v[1], p[2] + sig * v[2]])
        outlier = False
        for t0, t1, mag, ang in self._outliers:
            if t0 - _EPS_S <= t_acq_s < t1 - _EPS_S:
                if math.isnan(ang):
                    phi = 2.0 * math.pi * u_dir
                    c = 2.0 * u_pol - 1.0
                    s = math.sqrt(max(0.0, 1.0 - c * c))
                    d = (s * math.cos(phi), s * math.sin(phi), c)
                else:
                    d = (math.cos(ang), 0.0, math.sin(ang))
                m = m + mag * np.asarray(d)
                outlier = True
                break
        dropped = u_drop < self.params.dropout_probability or any(
            t0 - _EPS_S <= t_acq_s < t1 - _EPS_S for t0, t1 in self._dropouts)
        return None if dropped else Measurement(float(t_acq_s), m, outlier)

    def frame(self, t_s: float, p_true: npt.ArrayLike) -> Measurement | None:
        """Acquire (if due) and deliver (if due) at tick ``t_s``: the newest frame delivered, or None.

        Raises:
            ModelInputError: on a non-finite time or position, a wrong shape or time going backwards.
        """
        p = np.asarray(p_true, dtype=np.float64)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ModelInputError(f"imager: true position must be a finite (3,) array, got {p_true!r}")
        if not math.isfinite(t_s) or t_s < self._t_last:
            raise ModelInputError(f"imager: tick time must be finite and non-decreasing, got {t_s!r}")
        self._t_last = t_s
        if t_s + _EPS_S >= self._next * self._period:
            self._next = int(math.floor((t_s + _EPS_S) / self._period)) + 1
            m = self.acquire(t_s, p)
            if m is not None:
                self._queue.append((t_s + self.params.latency_s, m.t_acq_s, m.p, m.outlier))
        out = None
        while self._queue and self._queue[0][0] <= t_s + _EPS_S:
            _td, ta, pm, ol = self._queue.popleft()
            out = Measurement(ta, pm, ol)
        return out
