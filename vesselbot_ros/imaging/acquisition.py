"""MR data of the bead: a 2-D gradient-echo slice and MS-SET-style 1-D projections, synthesised from physics.

Both acquisitions share one signal model (docs/imaging.md):

* the object: tissue (proton density ``tissue_proton_density``, ``t2star_s``) filling the field of view, a
  straight vessel of blood along x through y = z = 0 (``blood_proton_density``, ``blood_t2star_s``; the
  diameter is the scenario's, an argument), the bead (no protons: a signal void) and its dipole field
  (:mod:`~vesselbot_ros.imaging.dipole`; B0 along x);
* the bead's field is sampled on a grid ``oversample`` times finer than a pixel, and each sub-voxel carries
  the first-order dephasing of the field's gradient across it, ``prod_j sinc(g_j h_j / 2)`` with
  ``g = 2 pi gamma_bar TE grad(dB)`` (a linear phase over the sub-voxel), so the intravoxel dephasing that
  voids the signal near the bead is resolved below the sub-voxel too;
* the off-resonance ``df = gamma_bar dB`` acts through the echo time (phase ``-2 pi df TE``) and along the
  readout: a spin with ``df`` is placed ``df / bandwidth_Hz_per_pixel`` pixels along +readout (the image-domain
  equivalent of its phase accruing over the readout, for a readout gradient along +readout), split linearly
  between the two nearest sub-voxel nodes; spins pushed out of the field of view are lost (the readout's
  anti-alias filter);
* the fine grid is Fourier-transformed (numpy.fft), the central ``matrix`` k-space samples are kept (the
  acquisition's band limit: the image is the object convolved with the sampled Dirichlet kernel, Gibbs ringing
  included), the readout's T2* decay (tissue's) multiplies each k-space line about the echo, and the inverse
  transform gives the image;
* complex Gaussian noise: each of the real and imaginary parts N(0, sigma^2) with
  ``sigma = sqrt(bandwidth / snr_bandwidth) / snr`` in units where a voxel of proton density 1 fully excited
  at TE = 0 reads 1 (so ``snr`` is that voxel's SNR at ``snr_bandwidth_Hz_per_pixel``; voxel-volume scaling
  is the caller's: the presets state theirs).

**Slice** (:func:`acquire_slice`): the x-z plane at ``y = centre[1]`` (the planar scenarios' plane), readout
along ``readout_axis`` (x or z), phase encoding along the other; ``image[i, j]``: row i the phase-encode axis,
column j the readout axis, pixel centres at ``centre + (n - matrix/2) pixel_m`` (n = 0..matrix-1) on each.
The slice profile in excitation frequency: ``P((s - y0) / thickness + df / rf_bandwidth_Hz)`` (a spin off
resonance is excited in a shifted slab), a flat top with cos^2 edges over +-10 % of the thickness (ours),
sampled at ``slice_samples`` points over +-thickness.  A moving bead (a list of positions over the frame's
window): phase-encode lines are acquired in order (-matrix/2 first), line n from position
``floor(n P / matrix)``.

**Projections** (:func:`acquire_projections`): MS-SET after Felfoul, Mathieu, Beaudoin and Martel (IEEE TMI
2008): a spectrally selective pulse excites only spins whose off-resonance lies in
``excitation_offset_Hz +- excitation_bandwidth_Hz / 2`` (flat top, cos^2 edges over 10 % of the band: ours):
the bead's lobes, never the on-resonance background.  Three readouts, along x, y and z, each give a 1-D
projection of the excited spins (``matrix`` samples of ``pixel_m`` about ``centre``), shifted along its readout
by the off-resonance like the slice.  The excited spins are sampled on a cube about the bead (half-width where
the dipole falls below the band).  A moving bead: projection a (x, y, z in order) from position ``floor(a P / 3)``.

Everything is deterministic: the noise is drawn from the ``numpy.random.Generator`` passed in (real parts, then
imaginary parts), nothing else draws.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.config import ConfigError, check_choice, check_finite, check_positive, check_range
from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.imaging.dipole import GAMMA_BAR_HZ_PER_T, bead_moment_Am2, dipole_dbz_grad, dipole_prefactor
from vesselbot_ros.physics.params import RobotParams

__all__ = ["MrImagingParams", "PRESETS", "PRESET_SOURCES", "PROFILE_EDGE", "check_field_of_view", "noise_sigma",
           "SliceFrame", "ProjectionFrame", "acquire_slice", "acquire_projections", "slice_image",
           "projection_data", "slice_pixel_centres", "as_position3"]

Array = npt.NDArray[np.float64]
CArray = npt.NDArray[np.complex128]

#: Half-width of the cos^2 edges of the slice and excitation profiles, as a fraction of their width (ours).
PROFILE_EDGE = 0.1
_EDGE = PROFILE_EDGE


@dataclasses.dataclass(frozen=True)
class MrImagingParams:
    """MR acquisition parameters (SI units in the names).

    Attributes:
        acquisition: ``slice`` (2-D gradient echo) or ``projections`` (MS-SET, three 1-D projections).
        b0_T: Main field B0 (T), > 0.  It labels the preset and changes no number of the model: the bead is
            saturated at either field, its off-resonance is ``gamma_bar dB`` whatever B0, and the SNR's growth
            with B0 is in the presets' ``snr``.
        echo_time_s: Echo time TE (s), > 0 and at least half the readout (``0.5 / bandwidth_Hz_per_pixel``).
        repetition_time_s: Repetition time TR (s), >= TE + half the readout; a slice takes ``matrix`` TRs,
            a projection set three.
        matrix: Samples per axis (an even integer, 8 to 1024): the slice is matrix x matrix, each projection
            matrix long.
        pixel_m: Pixel (sample) size along each encoded axis (m), > 0.
        bandwidth_Hz_per_pixel: Receiver bandwidth per pixel (Hz), > 0: the readout lasts
            ``1 / bandwidth_Hz_per_pixel`` and an off-resonance df shifts by ``df / bandwidth`` pixels.
        readout_axis: The slice's frequency-encoding axis, ``x`` or ``z`` (phase encoding along the other).
        slice_thickness_m: Slice thickness (m), > 0.
        rf_bandwidth_Hz: The slice-selective pulse's bandwidth (Hz), > 0: a spin ``df`` off resonance is
            excited ``df / rf_bandwidth_Hz`` slice thicknesses away.
        excitation_offset_Hz: MS-SET: the centre of the excited band (Hz), finite, ``|offset|`` above half
            the band (the background at 0 Hz is never excited).
        excitation_bandwidth_Hz: MS-SET: the excited band's width (Hz), > 0.
        b0_offset_Hz: A uniform off-resonance of every spin (Hz), finite: the scanner's centre frequency off the
            tissue's resonance (a shim or frequency-adjustment error).  It shifts the whole image along the
            readout and the slab through the slice like the bead's field does; 0 (the default) is a perfect
            adjustment.  MS-SET's band must stay clear of it.
        snr: SNR of a voxel of proton density 1 fully excited at TE = 0, at ``snr_bandwidth_Hz_per_pixel``.
        snr_bandwidth_Hz_per_pixel: The bandwidth the ``snr`` holds at (Hz); sigma scales as sqrt(bandwidth).
        t2star_s: Tissue T2* (s), > 0.
        blood_t2star_s: Blood T2* (s), > 0.
        tissue_proton_density: Tissue proton density relative to water, in [0, 1].
        blood_proton_density: Blood proton density relative to water, in [0, 1].
        oversample: Sub-voxel samples per pixel and axis (an integer, 1 to 8; ``matrix oversample`` at most
            2048, the fine grid's side).
        slice_samples: Samples across the slice (over +-thickness; an integer, 1 to 32).
    """

    acquisition: Literal["slice", "projections"] = "slice"
    b0_T: float = 3.0
    echo_time_s: float = 5.0e-3
    repetition_time_s: float = 8.0e-3
    matrix: int = 128
    pixel_m: float = 1.0e-3
    bandwidth_Hz_per_pixel: float = 400.0
    readout_axis: Literal["x", "z"] = "x"
    slice_thickness_m: float = 5.0e-3
    rf_bandwidth_Hz: float = 1000.0
    excitation_offset_Hz: float = 1500.0
    excitation_bandwidth_Hz: float = 1000.0
    b0_offset_Hz: float = 0.0
    snr: float = 20.0
    snr_bandwidth_Hz_per_pixel: float = 400.0
    t2star_s: float = 0.025
    blood_t2star_s: float = 0.05
    tissue_proton_density: float = 0.8
    blood_proton_density: float = 0.9
    oversample: int = 3
    slice_samples: int = 6

    def __post_init__(self) -> None:
        check_choice("acquisition", self.acquisition, ("slice", "projections"))
        check_positive("b0_T", self.b0_T)
        check_positive("echo_time_s", self.echo_time_s)
        check_positive("repetition_time_s", self.repetition_time_s)
        _check_int("matrix", self.matrix, 8, 1024)
        if self.matrix % 2:
            raise ConfigError(f"matrix must be even, got {self.matrix!r}")
        check_positive("pixel_m", self.pixel_m)
        check_positive("bandwidth_Hz_per_pixel", self.bandwidth_Hz_per_pixel)
        check_choice("readout_axis", self.readout_axis, ("x", "z"))
        check_positive("slice_thickness_m", self.slice_thickness_m)
        check_positive("rf_bandwidth_Hz", self.rf_bandwidth_Hz)
        check_finite("excitation_offset_Hz", self.excitation_offset_Hz)
        check_positive("excitation_bandwidth_Hz", self.excitation_bandwidth_Hz)
        check_finite("b0_offset_Hz", self.b0_offset_Hz)
        if abs(self.excitation_offset_Hz - self.b0_offset_Hz) <= (0.5 + _EDGE) * self.excitation_bandwidth_Hz:
            raise ConfigError(f"excitation_offset_Hz must lie more than 0.6 excitation_bandwidth_Hz "
                              f"({self.excitation_bandwidth_Hz!r}) from b0_offset_Hz ({self.b0_offset_Hz!r}), so "
                              f"the background is not excited, got {self.excitation_offset_Hz!r}")
        check_positive("snr", self.snr)
        check_positive("snr_bandwidth_Hz_per_pixel", self.snr_bandwidth_Hz_per_pixel)
        check_positive("t2star_s", self.t2star_s)
        check_positive("blood_t2star_s", self.blood_t2star_s)
        check_range("tissue_proton_density", self.tissue_proton_density, 0.0, 1.0)
        check_range("blood_proton_density", self.blood_proton_density, 0.0, 1.0)
        _check_int("oversample", self.oversample, 1, 8)
        _check_int("slice_samples", self.slice_samples, 1, 32)
        if self.matrix * self.oversample > 2048:
            raise ConfigError(f"oversample must keep matrix x oversample <= 2048 (matrix = {self.matrix!r}), "
                              f"got {self.oversample!r}")
        half_readout = 0.5 / self.bandwidth_Hz_per_pixel
        if self.echo_time_s < half_readout:
            raise ConfigError(f"echo_time_s must be >= half the readout (0.5 / bandwidth_Hz_per_pixel = "
                              f"{half_readout:.6g} s), got {self.echo_time_s!r}")
        if self.repetition_time_s < self.echo_time_s + half_readout:
            raise ConfigError(f"repetition_time_s must be >= echo_time_s + half the readout "
                              f"({self.echo_time_s + half_readout:.6g} s), got {self.repetition_time_s!r}")

    @property
    def fov_m(self) -> float:
        """Field of view along each encoded axis, ``matrix pixel_m`` (m)."""
        return self.matrix * self.pixel_m

    @property
    def readout_s(self) -> float:
        """Duration of one readout, ``1 / bandwidth_Hz_per_pixel`` (s)."""
        return 1.0 / self.bandwidth_Hz_per_pixel

    @property
    def frame_time_s(self) -> float:
        """Time to acquire one frame (s): ``matrix`` TRs for a slice, three for the projections."""
        return (self.matrix if self.acquisition == "slice" else 3) * self.repetition_time_s


def _check_int(name: str, value: int, lo: int, hi: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{name} must be an integer, got {value!r}")
    if not lo <= value <= hi:
        raise ConfigError(f"{name} must be in [{lo}, {hi}], got {value!r}")


def check_field_of_view(params: MrImagingParams, vessel_diameter_m: float) -> None:
    """ConfigError unless the field of view (``matrix pixel_m``) holds the vessel's diameter."""
    if params.fov_m < vessel_diameter_m:
        raise ConfigError(f"fov_m (matrix x pixel_m) must be >= the vessel's diameter ({vessel_diameter_m!r} m), "
                          f"got {params.fov_m!r}")


def noise_sigma(params: MrImagingParams) -> float:
    """Standard deviation of each of the real and imaginary noise parts (signal units: a fully excited voxel of
    proton density 1 at TE = 0 reads 1)."""
    return math.sqrt(params.bandwidth_Hz_per_pixel / params.snr_bandwidth_Hz_per_pixel) / params.snr


# ---- presets -----------------------------------------------------------------------------------------------------
# Sources (docs/imaging.md "Presets"): the tracking sequences of the MRI-navigation papers are reported only in
# part; every number not quoted from a source is ours and marked so.
#
# gre_1p5t / gre_3t: a clinical spoiled 2-D gradient echo as used to image the bead's susceptibility artefact
#   (Folio and Ferreira, IEEE T-RO 33(3), 2017, tracked a 750 um steel bead's artefact in GRE images;
#   their TE, bandwidth and resolution were not found in the stored abstract).  Ours, inside clinical ranges:
#   TE 4.8 / 3.0 ms (a shorter TE at 3 T: the saturated bead's field does not grow with B0, so the same
#   TE gives the same artefact; the shorter one buys speed), 1 mm pixels, 5 mm slice,
#   400 Hz/pixel.  T2*: muscle about 30 ms at 1.5 T and 20-25 ms at 3 T,
#   arterial blood longer (ours, typical literature values, not from one source).  Proton density tissue 0.8,
#   blood 0.9 of water (ours).  SNR 20 at 1.5 T and 30 at 3 T per 1 x 1 x 5 mm voxel (ours: SNR grows
#   roughly linearly with B0; we take 1.5x).
# msset_1p5t: Felfoul O., Mathieu J.-B., Beaudoin G., Martel S., "In vivo MR-tracking based on magnetic
#   signature selective excitation", IEEE Trans. Med. Imaging 27(1):28-35, 2008 (MS-SET on a clinical
#   scanner).  The positive off-resonance band, three orthogonal
#   projections and no slice selection are theirs; the numbers (band 1-2 kHz, 256 samples of 0.5 mm,
#   800 Hz/pixel, TE 2 ms, SNR 20) and B0 = 1.5 T are ours.
PRESETS: dict[str, MrImagingParams] = {
    "gre_1p5t": MrImagingParams(acquisition="slice", b0_T=1.5, echo_time_s=4.8e-3, repetition_time_s=8.0e-3,
                                matrix=128, pixel_m=1.0e-3, bandwidth_Hz_per_pixel=400.0, slice_thickness_m=5e-3,
                                rf_bandwidth_Hz=1000.0, snr=20.0, snr_bandwidth_Hz_per_pixel=400.0,
                                t2star_s=0.03, blood_t2star_s=0.1),
    "gre_3t": MrImagingParams(acquisition="slice", b0_T=3.0, echo_time_s=3.0e-3, repetition_time_s=6.0e-3,
                              matrix=128, pixel_m=1.0e-3, bandwidth_Hz_per_pixel=400.0, slice_thickness_m=5e-3,
                              rf_bandwidth_Hz=1000.0, snr=30.0, snr_bandwidth_Hz_per_pixel=400.0,
                              t2star_s=0.022, blood_t2star_s=0.05),
    "msset_1p5t": MrImagingParams(acquisition="projections", b0_T=1.5, echo_time_s=2.0e-3, repetition_time_s=4.0e-3,
                                  matrix=256, pixel_m=0.5e-3, bandwidth_Hz_per_pixel=800.0,
                                  excitation_offset_Hz=1500.0, excitation_bandwidth_Hz=1000.0, snr=20.0,
                                  snr_bandwidth_Hz_per_pixel=800.0, t2star_s=0.03, blood_t2star_s=0.1),
}
#: One line per preset: what is sourced and what is ours.
PRESET_SOURCES: dict[str, str] = {
    "gre_1p5t": "GRE artefact tracking as in Folio & Ferreira, IEEE T-RO 2017; every number ours (clinical ranges)",
    "gre_3t": "as gre_1p5t at 3 T; every number ours (clinical ranges)",
    "msset_1p5t": "MS-SET: Felfoul, Mathieu, Beaudoin, Martel, IEEE TMI 27(1) 2008 (positive off-resonance band, "
                  "three projections); every number ours",
}


# ---- frames ------------------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class SliceFrame:
    """One slice: ``image`` (matrix, matrix) complex (rows: phase-encode axis, columns: readout axis), the FOV
    ``centre_m`` (3,) (x, y, z; the slice plane is y = centre[1]), the readout axis (0: x, 2: z) and sigma."""

    image: CArray
    centre_m: Array
    readout_axis: int
    pixel_m: float
    sigma: float

    @property
    def magnitude(self) -> Array:
        return np.abs(self.image)

    @property
    def phase(self) -> Array:
        return np.angle(self.image)


@dataclasses.dataclass(frozen=True)
class ProjectionFrame:
    """Three projections: ``data`` (3, matrix) complex, row a along axis a (x, y, z), samples at
    ``centre_m[a] + (n - matrix/2) pixel_m``, and sigma."""

    data: CArray
    centre_m: Array
    pixel_m: float
    sigma: float


def as_position3(p: npt.ArrayLike, what: str = "position") -> Array:
    """A (3,) finite position (x, y, z) from a (2,) (x, z; y = 0) or (3,) one; ModelInputError otherwise."""
    a = np.array(p, dtype=np.float64).reshape(-1)
    if a.shape == (2,):
        a = np.array([a[0], 0.0, a[1]])
    if a.shape != (3,) or not bool(np.isfinite(a).all()):
        raise ModelInputError(f"{what} must be a finite (2,) (x, z) or (3,) (x, y, z) array, got {p!r}")
    return a


def _positions(bead: npt.ArrayLike | None) -> list[Array | None]:
    """The bead's positions over the window: None (no bead), one position, or a (P, 2|3) sequence."""
    if bead is None:
        return [None]
    a = np.asarray(bead, dtype=np.float64)
    if a.ndim == 2:
        if a.shape[0] == 0:
            raise ModelInputError("bead positions: an empty list (give None for no bead)")
        return [as_position3(row, "bead position") for row in a]
    return [as_position3(a, "bead position")]


def slice_pixel_centres(params: MrImagingParams, centre_m: npt.ArrayLike) -> tuple[Array, Array]:
    """``(readout, phase)`` coordinates (m, frame W) of the slice's pixel centres along its two axes."""
    c = as_position3(centre_m, "centre_m")
    ro = 0 if params.readout_axis == "x" else 2
    pe = 2 - ro
    n = (np.arange(params.matrix) - params.matrix // 2) * params.pixel_m
    return c[ro] + n, c[pe] + n


# ---- compiled kernels --------------------------------------------------------------------------------------------
@numba.njit(cache=True, nogil=True)
def _profile(u):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Flat top on |u| <= 0.5 - e, cos^2 edges to 0 at |u| = 0.5 + e (integral 1)."""
    au = abs(u)
    if au <= 0.5 - _EDGE:
        return 1.0
    if au >= 0.5 + _EDGE:
        return 0.0
    c = math.cos(0.5 * math.pi * (au - 0.5 + _EDGE) / (2.0 * _EDGE))
    return c * c


@numba.njit(cache=True, nogil=True)
def _sinc(x):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    x2 = x * x
    if x2 < 1e-4:  # Taylor: the error x^4 / 120 < 1e-10
        return 1.0 - x2 / 6.0
    return math.sin(x) / x


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _slice_fine(fine, o, n, pixel, ro, centre, has_bead, bead, k, a, sprm):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Accumulate the slice's sub-voxel signal on ``fine`` (M, M) complex (rows: phase axis, columns: readout).

    sprm: [TE, bw_pp, thickness, rf_bw, slice samples, pd tissue, t2* tissue, pd blood, t2* blood, vessel r,
    uniform off-resonance (Hz)].
    """
    te, bw, thk, rfbw = sprm[0], sprm[1], sprm[2], sprm[3]
    ns = int(sprm[4])
    pdt, t2t, pdb, t2b, rv, f_off = sprm[5], sprm[6], sprm[7], sprm[8], sprm[9], sprm[10]
    m = fine.shape[0]
    d = pixel / o
    ds = 2.0 * thk / ns
    ph = 2.0 * math.pi * GAMMA_BAR_HZ_PER_T * te  # rad per T
    et = pdt * math.exp(-te / t2t) * (ds / thk)  # a sample's weight before the profile and dephasing
    eb = pdb * math.exp(-te / t2b) * (ds / thk)
    inv_rfbw = 1.0 / rfbw
    o_bw = o / bw  # fine bins of readout shift per Hz
    reach = 2.0 * k * GAMMA_BAR_HZ_PER_T * inv_rfbw  # |df| / rf_bw <= reach / r^3
    h_ro = 0.5 * ph * d
    ph_hz = 2.0 * math.pi * te  # rad per Hz
    pe = 2 - ro
    for j in range(ns):
        s = (j + 0.5) * ds - thk
        u_s = s / thk + f_off * inv_rfbw  # the sample's place in the profile without the bead
        beyond = abs(u_s) - 0.5 - _EDGE  # > 0: the profile reaches this sample only through the bead's field
        if not has_bead and beyond >= 0.0:
            continue
        h_s = 0.5 * ph * ds
        y = centre[1] + s
        for ip in range(m):
            up = centre[pe] + (ip - m // 2) * d
            for ir in range(m):
                ur = centre[ro] + (ir - m // 2) * d
                x = ur if ro == 0 else up
                z = up if ro == 0 else ur
                w = eb if y * y + z * z < rv * rv else et
                df = 0.0  # the bead's off-resonance (Hz); the uniform one is in u_s, phi and f
                fac = 1.0
                if has_bead:
                    dx, dy, dz = x - bead[0], y - bead[1], z - bead[2]
                    r2 = dx * dx + dy * dy + dz * dz
                    if r2 < a * a:
                        continue  # the sphere: no protons
                    # |df| <= 2 k gamma_bar / r^3: a sample the slice profile cannot reach is skipped unevaluated
                    if beyond > 0.0 and beyond * r2 * math.sqrt(r2) >= reach:
                        continue
                    db, gx, gy, gz = dipole_dbz_grad(dx, dy, dz, k, a)
                    df = GAMMA_BAR_HZ_PER_T * db
                    g_ro = gx if ro == 0 else gz
                    g_pe = gz if ro == 0 else gx
                    fac = _sinc(h_ro * g_ro) * _sinc(h_ro * g_pe) * _sinc(h_s * gy)
                wp = _profile(u_s + df * inv_rfbw)
                if wp == 0.0:
                    continue
                amp = w * wp * fac
                phi = -ph_hz * (df + f_off)
                v = amp * complex(math.cos(phi), math.sin(phi))
                f = ir + (df + f_off) * o_bw
                i0 = int(math.floor(f))
                fr = f - i0
                if 0 <= i0 < m:
                    fine[ip, i0] += (1.0 - fr) * v
                if 0 <= i0 + 1 < m:
                    fine[ip, i0 + 1] += fr * v


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _projection_fine(fine, o, pixel, centre, bead, k, a, half, pprm):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Accumulate the excited spins on ``fine`` (3, M) complex: row a the projection along axis a.

    pprm: [TE, bw_pp, offset, band, pd tissue, t2* tissue, pd blood, t2* blood, vessel r, uniform off-resonance].
    The excited spins are sampled on the cube of half-width ``half`` (m) about the bead.
    """
    te, bw, off, band = pprm[0], pprm[1], pprm[2], pprm[3]
    pdt, t2t, pdb, t2b, rv, f_off = pprm[4], pprm[5], pprm[6], pprm[7], pprm[8], pprm[9]
    m = fine.shape[1]
    d = pixel / o
    nq = int(math.ceil(half / d))
    et = pdt * math.exp(-te / t2t)
    eb = pdb * math.exp(-te / t2b)
    ph = 2.0 * math.pi * GAMMA_BAR_HZ_PER_T * te
    # |df| <= 2 k gamma_bar / r^3: beyond r_lim no spin reaches the band's near edge, skipped unevaluated
    f_lo = abs(off - f_off) - (0.5 + _EDGE) * band
    r_lim2 = (2.0 * k * GAMMA_BAR_HZ_PER_T / f_lo) ** (2.0 / 3.0) if f_lo > 0.0 else math.inf
    # sample nodes on the fine grid of each axis (so a bead on a node samples the same points)
    base = np.empty(3)
    for c in range(3):
        base[c] = centre[c] + (math.floor((bead[c] - centre[c]) / d) - nq) * d
    q = np.empty(3)
    for i in range(2 * nq + 2):
        q[0] = base[0] + i * d
        for j in range(2 * nq + 2):
            q[1] = base[1] + j * d
            for w3 in range(2 * nq + 2):
                q[2] = base[2] + w3 * d
                dx, dy, dz = q[0] - bead[0], q[1] - bead[1], q[2] - bead[2]
                r2 = dx * dx + dy * dy + dz * dz
                if r2 < a * a or r2 > r_lim2:
                    continue
                db, gx, gy, gz = dipole_dbz_grad(dx, dy, dz, k, a)
                df = GAMMA_BAR_HZ_PER_T * db + f_off
                wp = _profile((df - off) / band)
                if wp == 0.0:
                    continue
                w = eb if q[1] * q[1] + q[2] * q[2] < rv * rv else et
                amp = w * wp * _sinc(0.5 * ph * gx * d) * _sinc(0.5 * ph * gy * d) * _sinc(0.5 * ph * gz * d)
                amp *= (d / pixel) ** 3
                phi = -2.0 * math.pi * te * df
                v = amp * complex(math.cos(phi), math.sin(phi))
                for c in range(3):
                    f = (q[c] - centre[c]) / d + m // 2 + df / bw * o
                    i0 = int(math.floor(f + 1e-9))
                    fr = f - i0
                    if 0 <= i0 < m:
                        fine[c, i0] += (1.0 - fr) * v
                    if 0 <= i0 + 1 < m:
                        fine[c, i0 + 1] += fr * v


# ---- acquisitions ------------------------------------------------------------------------------------------------
def _crop_1d(n: int, m: int) -> slice:
    return slice(m // 2 - n // 2, m // 2 - n // 2 + n)


def _central_kspace(fine: CArray, n: int) -> CArray:
    """The central n x n k-space samples (k = -n/2 .. n/2-1 on each axis, centred order) of the fine grid
    (m x m, node ``m/2`` at the origin): ``fftshift(fft2(ifftshift(fine)))`` cropped, computed as the readout
    FFT of every row, then the phase-axis FFT of the n kept columns only, the origin's shift as ``(-1)^k``."""
    m = fine.shape[0]
    kk = np.arange(n) - n // 2
    idx = kk % m
    sign = np.where(kk % 2 == 0, 1.0, -1.0)
    rows = np.fft.fft(fine, axis=1)[:, idx] * sign[None, :]
    return np.fft.fft(rows, axis=0)[idx, :] * sign[:, None]


def _readout_decay(params: MrImagingParams) -> Array:
    """exp(-tau / T2*) over the readout about the echo (tissue's T2*), per centred k-space sample."""
    n = params.matrix
    tau = (np.arange(n) - n // 2) / (n * params.bandwidth_Hz_per_pixel)
    return np.exp(-tau / params.t2star_s)


def _bead_constants(robot: RobotParams) -> tuple[float, float]:
    return dipole_prefactor(bead_moment_Am2(robot)), robot.radius_m


def slice_image(params: MrImagingParams, robot: RobotParams, bead: npt.ArrayLike | None, centre_m: npt.ArrayLike,
                vessel_diameter_m: float = 0.0) -> CArray:
    """The noiseless slice (matrix, matrix) complex of a bead at ``bead`` ((2|3,), a (P, 2|3) sequence over the
    window, or None), FOV centred on ``centre_m``, vessel of ``vessel_diameter_m`` along x (0: none)."""
    n, o = params.matrix, params.oversample
    m = n * o
    c = as_position3(centre_m, "centre_m")
    ro = 0 if params.readout_axis == "x" else 2
    k, a = _bead_constants(robot)
    sprm = np.array([params.echo_time_s, params.bandwidth_Hz_per_pixel, params.slice_thickness_m,
                     params.rf_bandwidth_Hz, float(params.slice_samples), params.tissue_proton_density,
                     params.t2star_s, params.blood_proton_density, params.blood_t2star_s, 0.5 * vessel_diameter_m,
                     params.b0_offset_Hz])
    positions = _positions(bead)
    kspace = np.empty((n, n), dtype=np.complex128)
    lines = np.arange(n)
    which = (lines * len(positions)) // n
    for i, p in enumerate(positions):
        fine = np.zeros((m, m), dtype=np.complex128)
        _slice_fine(fine, o, n, params.pixel_m, ro, c, p is not None, p if p is not None else np.zeros(3), k, a, sprm)
        ks = _central_kspace(fine, n)
        rows = which == i
        kspace[rows] = ks[rows]
    kspace *= _readout_decay(params)[None, :]
    return np.fft.fftshift(np.fft.ifft2(np.fft.ifftshift(kspace))) * (n * n) / (m * m)


def _excited_half_width(params: MrImagingParams, robot: RobotParams) -> float:
    """Half-width (m) of the cube holding every spin the MS-SET band can excite (dB at most 2 k / r^3)."""
    k = _bead_constants(robot)[0]
    f_lo = max(abs(params.excitation_offset_Hz - params.b0_offset_Hz) - (0.5 + _EDGE) * params.excitation_bandwidth_Hz,
               1.0)
    r_max = (2.0 * k * GAMMA_BAR_HZ_PER_T / f_lo) ** (1.0 / 3.0)
    return r_max + 2.0 * params.pixel_m / params.oversample


def projection_data(params: MrImagingParams, robot: RobotParams, bead: npt.ArrayLike | None,
                    centre_m: npt.ArrayLike, vessel_diameter_m: float = 0.0) -> CArray:
    """The noiseless projections (3, matrix) complex of a bead at ``bead`` (as :func:`slice_image`)."""
    n, o = params.matrix, params.oversample
    m = n * o
    c = as_position3(centre_m, "centre_m")
    k, a = _bead_constants(robot)
    pprm = np.array([params.echo_time_s, params.bandwidth_Hz_per_pixel, params.excitation_offset_Hz,
                     params.excitation_bandwidth_Hz, params.tissue_proton_density, params.t2star_s,
                     params.blood_proton_density, params.blood_t2star_s, 0.5 * vessel_diameter_m,
                     params.b0_offset_Hz])
    positions = _positions(bead)
    half = _excited_half_width(params, robot)
    out = np.zeros((3, n), dtype=np.complex128)
    crop = _crop_1d(n, m)
    decay = _readout_decay(params)
    fines: dict[int, CArray] = {}
    for axis in range(3):
        i = (axis * len(positions)) // 3
        p = positions[i]
        if p is None:
            continue  # nothing is excited without the bead
        if i not in fines:
            fines[i] = np.zeros((3, m), dtype=np.complex128)
            _projection_fine(fines[i], o, params.pixel_m, c, p, k, a, half, pprm)
        ks = np.fft.fftshift(np.fft.fft(np.fft.ifftshift(fines[i][axis])))[crop] * decay
        # a fine bin holds the spins of 1/o of a pixel: the band-limited resampling keeps that density, times o
        # (= m / n) makes each sample the signal of its pixel's slab (units: a pixel^3 tissue cube of density 1)
        out[axis] = np.fft.fftshift(np.fft.ifft(np.fft.ifftshift(ks)))
    return out


def _noise(rng: np.random.Generator, shape: tuple[int, ...], sigma: float) -> CArray:
    z = rng.standard_normal((2, *shape))
    return sigma * (z[0] + 1j * z[1])


def acquire_slice(params: MrImagingParams, robot: RobotParams, bead: npt.ArrayLike | None, rng: np.random.Generator,
                  centre_m: npt.ArrayLike = (0.0, 0.0, 0.0), vessel_diameter_m: float = 0.0) -> SliceFrame:
    """One noisy slice (:func:`slice_image` plus complex Gaussian noise drawn from ``rng``)."""
    img = slice_image(params, robot, bead, centre_m, vessel_diameter_m)
    sigma = noise_sigma(params)
    img = img + _noise(rng, img.shape, sigma)
    return SliceFrame(img, as_position3(centre_m, "centre_m"), 0 if params.readout_axis == "x" else 2,
                      params.pixel_m, sigma)


def acquire_projections(params: MrImagingParams, robot: RobotParams, bead: npt.ArrayLike | None,
                        rng: np.random.Generator, centre_m: npt.ArrayLike = (0.0, 0.0, 0.0),
                        vessel_diameter_m: float = 0.0) -> ProjectionFrame:
    """Three noisy projections (:func:`projection_data` plus complex Gaussian noise drawn from ``rng``)."""
    data = projection_data(params, robot, bead, centre_m, vessel_diameter_m)
    sigma = noise_sigma(params)
    return ProjectionFrame(data + _noise(rng, data.shape, sigma), as_position3(centre_m, "centre_m"),
                           params.pixel_m, sigma)
