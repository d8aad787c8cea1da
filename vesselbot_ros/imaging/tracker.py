"""The default tracker: the bead's position from one MR frame, or the reason the frame is rejected.

Slice (:class:`SliceTracker`), a fit of the artefact model to the complex image:

1. checks: a non-finite sample rejects the frame (``nan_in_data``); more than 1 % of the real and imaginary
   parts at the frame's largest value (a clipped ADC) rejects it (``saturated``); a mean power within half the
   background's of the noise's (``2 sigma^2``), or a background model that explains under a tenth of the power
   (noise far above the frame's sigma), rejects it (``all_noise``);
2. the background without the bead, ``B`` (the same model, cached per FOV centre), and its complex scale
   ``c0 = <B, d> / <B, B>``;
3. coarse: the bead-only template ``T0 = I(centre) - B`` cross-correlated (FFT) with ``d - c0 B``; the peak
   gives the position to a pixel.  If the peak's chi-square gain, ``|<T0, d - c0 B>|^2 / (|T0|^2 sigma^2)``,
   is below ``min_chi2`` the frame holds no bead (``no_bead``);
4. fine, ``refinements`` times: the bead-only image at the current estimate, ``D = I(p) - B``, is shifted in
   k-space by ``delta`` (a phase ramp: exact for the bead's part of a band-limited image) and
   ``c (B + shift(D, delta))`` is fitted to the data in least squares over ``delta`` (in-plane) and the complex
   scale ``c`` (solved in closed form at each ``delta``: variable projection; scipy.optimize.least_squares).
   The vessel moves with the shifted template, the one approximation, and the next refinement re-synthesises
   at the new estimate, so it shrinks with the step.  The first fine fit reuses the last frame's template when
   the coarse estimate lies within ``reuse_template_px`` pixels of where it was synthesised (a bead moving
   less than that per frame costs one synthesis per frame).
   A fit that fails, or lands outside the field of view, rejects the frame (``fit_failed`` / ``no_bead``).

The slice gives the in-plane position (x, z); y is the slice plane's (the planar scenarios' y = 0).

Projections (:class:`ProjectionTracker`), per axis: the projection of a bead at the FOV centre, cross-correlated
with the data, gives the peak to a sample; then the projection synthesised at the estimate is shifted in
k-space and fitted (shift and complex scale, variable projection: the shift maximising
``|<shift(T), d>|``), twice.  The readout shift of the excited spins (about ``excitation_offset_Hz /
bandwidth`` samples) is in the template, so it is not a bias.  Nothing is excited without the bead: a frame
whose best fit gains less than ``min_chi2`` is ``no_bead``.

Never a NaN measurement: every path returns a finite position or a reason.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numba
import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares, minimize_scalar

from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.imaging.acquisition import (
    MrImagingParams,
    ProjectionFrame,
    SliceFrame,
    projection_data,
    slice_image,
)
from vesselbot_ros.physics.params import RobotParams

__all__ = ["Track", "REJECT_REASONS", "SliceTracker", "ProjectionTracker", "check_samples", "cdot"]

Array = npt.NDArray[np.float64]
CArray = npt.NDArray[np.complex128]

#: Why a frame is rejected.
REJECT_REASONS = ("nan_in_data", "saturated", "all_noise", "no_bead", "fit_failed")


class Track(NamedTuple):
    """One frame's outcome: ``position_m`` (3,) finite (x, y, z; frame W) and ``reason`` "" when accepted;
    ``position_m`` None and ``reason`` one of :data:`REJECT_REASONS` when rejected.  ``chi2_gain``: how much
    the bead model explains beyond the background (in units of the noise variance)."""

    position_m: Array | None
    reason: str
    chi2_gain: float = 0.0

    @property
    def accepted(self) -> bool:
        return self.position_m is not None


def _reject(reason: str, gain: float = 0.0) -> Track:
    return Track(None, reason, gain)


@numba.njit(cache=True, nogil=True)
def _cdot_kernel(a, b):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    acc = 0j
    for i in range(a.shape[0]):
        acc += a[i].conjugate() * b[i]
    return acc


def cdot(a: CArray, b: CArray) -> complex:
    """``sum(conj(a) b)`` in a fixed order, without BLAS (``np.vdot`` hands it to OpenBLAS, whose kernel and
    threads depend on the machine: the same frame would give other last bits; vesselbot_ros/blas_free.py)."""
    return complex(_cdot_kernel(np.ascontiguousarray(a).reshape(-1), np.ascontiguousarray(b).reshape(-1)))


def _vertex(a: float, b: float, c: float) -> float:
    """The vertex of the parabola through (-1, a), (0, b), (1, c), clipped to [-0.5, 0.5] (0 if flat)."""
    den = a - 2.0 * b + c
    if not den < 0.0:
        return 0.0
    return float(min(0.5, max(-0.5, 0.5 * (a - c) / den)))


def check_samples(data: CArray) -> str:
    """``""`` or the reason raw data are unusable: non-finite samples (``nan_in_data``), a clipped ADC
    (``saturated``: more than 1 % of the real and imaginary parts at the largest absolute value), all zero
    (``all_noise``)."""
    if not bool(np.isfinite(data).all()):
        return "nan_in_data"
    parts = np.abs(np.concatenate([data.real.ravel(), data.imag.ravel()]))
    top = float(parts.max())
    if top == 0.0:
        return "all_noise"
    if float(np.mean(parts >= top * (1.0 - 1e-9))) > 0.01:
        return "saturated"
    return ""


@dataclasses.dataclass
class _Tracker:
    """What both trackers hold: their model's arguments (:class:`SliceTracker`), the k-space frequencies of one
    encoded axis and the last frame's template."""

    params: MrImagingParams
    robot: RobotParams
    vessel_diameter_m: float = 0.0
    min_chi2: float = 100.0
    refinements: int = 2
    reuse_template_px: float = 1.0

    def __post_init__(self) -> None:
        self._k = np.fft.fftfreq(self.params.matrix, d=self.params.pixel_m)  # cycles/m, in numpy's FFT order
        self._last: tuple[tuple[float, ...], Array, CArray] | None = None

    def reset(self) -> None:
        """Forget the last frame's template (the next frame synthesises its own)."""
        self._last = None


@dataclasses.dataclass
class SliceTracker(_Tracker):
    """Track the bead in :class:`~vesselbot_ros.imaging.acquisition.SliceFrame` s of ``params``.

    Args:
        params: The acquisition (its model is the tracker's).
        robot: The bead (radius, magnetisation).
        vessel_diameter_m: The vessel in the background model (0: none).
        min_chi2: Chi-square gain below which a frame holds no bead.
        refinements: Fine fits, each from a template synthesised at the previous estimate (>= 1).
        reuse_template_px: The first fine fit starts from the template the last frame synthesised when the
            coarse estimate lies within this many pixels of where it was synthesised (0: never), so a bead that
            moves less than that per frame costs one synthesis per frame, not ``refinements``.
    """

    def __post_init__(self) -> None:
        super().__post_init__()
        self._cache: dict[tuple[float, ...], tuple[CArray, CArray, CArray]] = {}

    def _background(self, centre: Array) -> tuple[CArray, CArray, CArray]:
        key = tuple(float(v) for v in centre)
        if key not in self._cache:
            bg = slice_image(self.params, self.robot, None, centre, self.vessel_diameter_m)
            t0 = slice_image(self.params, self.robot, centre, centre, self.vessel_diameter_m) - bg
            self._cache = {key: (bg, t0, np.fft.fft2(t0))}
        return self._cache[key]

    def _inplane(self, frame: SliceFrame) -> tuple[int, int]:
        ro = frame.readout_axis
        return ro, 2 - ro

    def _shifted(self, fd: CArray, d_ro: float, d_pe: float) -> CArray:
        ramp_ro = np.exp(-2j * np.pi * self._k * d_ro)
        ramp_pe = np.exp(-2j * np.pi * self._k * d_pe)
        return np.fft.ifft2(fd * ramp_pe[:, None] * ramp_ro[None, :])

    def track(self, frame: SliceFrame) -> Track:
        """The bead's position in ``frame``, or the reason it is rejected."""
        d = frame.image
        n = self.params.matrix
        if d.shape != (n, n):
            raise ModelInputError(f"slice tracker: the image must be ({n}, {n}), got {d.shape}")
        bad = check_samples(d)
        if bad:
            return _reject(bad)
        centre = np.array(frame.centre_m, dtype=np.float64)
        bg, t0, ft0 = self._background(centre)
        s2 = frame.sigma ** 2
        bb = cdot(bg, bg).real
        dd_power = cdot(d, d).real
        c0 = cdot(bg, d) / bb
        # all noise: less power than half the background's above the noise's, or the background model explains
        # under a tenth of the power (noise far above the frame's sigma)
        if dd_power / d.size < 2.0 * s2 + 0.5 * bb / d.size or abs(c0) ** 2 * bb < 0.1 * dd_power:
            return _reject("all_noise")
        r = d - c0 * bg
        corr = np.fft.ifft2(np.fft.fft2(r) * np.conj(ft0))
        i, j = np.unravel_index(int(np.argmax(np.abs(corr))), corr.shape)
        tt = cdot(t0, t0).real
        gain = float(np.abs(corr[i, j]) ** 2 / (tt * s2)) if tt > 0 else 0.0
        if not gain >= self.min_chi2:
            return _reject("no_bead", gain)
        h = self.params.pixel_m
        ro, pe = self._inplane(frame)
        p = centre.copy()
        ac = np.abs(corr)
        # rows: phase axis; circular lag in -n/2..n/2-1, refined by a parabola through the peak and its neighbours
        p[pe] += ((((i + n // 2) % n) - n // 2) + _vertex(ac[(i - 1) % n, j], ac[i, j], ac[(i + 1) % n, j])) * h
        p[ro] += ((((j + n // 2) % n) - n // 2) + _vertex(ac[i, (j - 1) % n], ac[i, j], ac[i, (j + 1) % n])) * h
        half = 0.5 * n * h
        key = tuple(float(v) for v in centre)
        for it in range(max(1, self.refinements)):
            last = self._last
            if (it == 0 and last is not None and last[0] == key
                    and float(np.abs(p - last[1]).max()) <= self.reuse_template_px * h):
                start = np.array([(p[ro] - last[1][ro]) / h, (p[pe] - last[1][pe]) / h])
                p = last[1].copy()
                fd = last[2]
            else:
                start = np.zeros(2)
                fd = np.fft.fft2(slice_image(self.params, self.robot, p, centre, self.vessel_diameter_m) - bg)
                self._last = (key, p.copy(), fd)

            def resid(x: Array, fd: CArray = fd) -> Array:
                m = bg + self._shifted(fd, x[0] * h, x[1] * h)
                c = cdot(m, d) / cdot(m, m).real
                e = (d - c * m).ravel()
                return np.concatenate([e.real, e.imag]) / frame.sigma

            try:
                sol = least_squares(resid, start, method="lm", x_scale=np.ones(2), diff_step=1e-4)
            except (ValueError, np.linalg.LinAlgError):
                return _reject("fit_failed", gain)
            if not (sol.success and bool(np.isfinite(sol.x).all())):
                return _reject("fit_failed", gain)
            p[ro] += float(sol.x[0]) * h
            p[pe] += float(sol.x[1]) * h
            if abs(p[ro] - centre[ro]) > half or abs(p[pe] - centre[pe]) > half:
                return _reject("no_bead", gain)
        chi_bg = float(np.sum(np.abs(r) ** 2)) / s2
        gain = chi_bg - 2.0 * float(sol.cost)
        if not (math.isfinite(gain) and gain >= self.min_chi2):
            return _reject("no_bead", gain)
        return Track(p, "", gain)


@dataclasses.dataclass
class ProjectionTracker(_Tracker):
    """Track the bead in :class:`~vesselbot_ros.imaging.acquisition.ProjectionFrame` s of ``params``
    (arguments as :class:`SliceTracker`)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        self._cache: dict[tuple[float, ...], CArray] = {}

    def _template(self, centre: Array) -> CArray:
        key = tuple(float(v) for v in centre)
        if key not in self._cache:
            self._cache = {key: np.fft.fft(projection_data(self.params, self.robot, centre, centre,
                                                           self.vessel_diameter_m), axis=1)}
        return self._cache[key]

    def _fit_axis(self, ft: CArray, fdata: CArray, x0: float) -> tuple[float, float]:
        """The shift (m) maximising ``|<shift(T), d>|`` near ``x0`` (m), and the chi-square gain numerator
        ``|<shift(T), d>|^2 / |T|^2`` (Parseval, in the Fourier domain)."""
        n = self.params.matrix
        h = self.params.pixel_m
        cross = np.conj(ft) * fdata
        tt = float(np.sum(np.abs(ft) ** 2)) / n

        def neg(x: float) -> float:
            return -float(np.abs(np.sum(cross * np.exp(2j * np.pi * self._k * x))) ** 2) / (n * n)

        res = minimize_scalar(neg, bounds=(x0 - h, x0 + h), method="bounded", options={"xatol": 1e-4 * h})
        return float(res.x), -float(res.fun) / tt if tt > 0 else 0.0

    def track(self, frame: ProjectionFrame) -> Track:
        """The bead's position (x, y, z) in ``frame``, or the reason it is rejected."""
        d = frame.data
        n = self.params.matrix
        if d.shape != (3, n):
            raise ModelInputError(f"projection tracker: the data must be (3, {n}), got {d.shape}")
        bad = check_samples(d)
        if bad:
            return _reject("no_bead" if bad == "all_noise" else bad)
        centre = np.array(frame.centre_m, dtype=np.float64)
        h = self.params.pixel_m
        s2 = frame.sigma ** 2
        fdata = np.fft.fft(d, axis=1)
        ft0 = self._template(centre)
        p = centre.copy()
        gain = 0.0
        for a in range(3):
            corr = np.fft.ifft(np.conj(ft0[a]) * fdata[a])
            lag = int(np.argmax(np.abs(corr)))
            p[a] += (((lag + n // 2) % n) - n // 2) * h
            tt = float(np.sum(np.abs(ft0[a]) ** 2)) / n
            gain += float(np.abs(corr[lag]) ** 2) / (tt * s2) if tt > 0 else 0.0
        if not gain >= self.min_chi2:
            return _reject("no_bead", gain)
        key = tuple(float(v) for v in centre)
        for it in range(max(1, self.refinements)):
            last = self._last
            if (it == 0 and last is not None and last[0] == key
                    and float(np.abs(p - last[1]).max()) <= self.reuse_template_px * h):
                start = p - last[1]
                p = last[1].copy()
                ft = last[2]
            else:
                start = np.zeros(3)
                ft = np.fft.fft(projection_data(self.params, self.robot, p, centre, self.vessel_diameter_m),
                                axis=1)
                self._last = (key, p.copy(), ft)
            gain = 0.0
            step = np.zeros(3)
            for a in range(3):
                step[a], g = self._fit_axis(ft[a], fdata[a], float(start[a]))
                gain += g / s2
            p = p + step
            if not bool(np.isfinite(p).all()):
                return _reject("fit_failed", gain)
            if bool((np.abs(p - centre) > 0.5 * n * h).any()):
                return _reject("no_bead", gain)
        if not (math.isfinite(gain) and gain >= self.min_chi2):
            return _reject("no_bead", gain)
        return Track(p, "", gain)
