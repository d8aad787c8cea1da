"""The ``imager`` section of the ``mr_images`` kind (:mod:`vesselbot_ros.imaging.imager_stage`): light to import (the
stage registry loads it in every node process; the trackers' scipy.optimize only where the imager is built)."""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

from vesselbot_ros.config import ConfigError, check_nonnegative, check_positive
from vesselbot_ros.imaging.acquisition import PRESETS, MrImagingParams

__all__ = ["MrImagerParams", "TrackerParams"]


@dataclasses.dataclass(frozen=True)
class MrImagerParams:
    """The ``imager`` section of the ``mr_images`` kind (units in the names).

    Attributes:
        kind: ``mr_images``.
        preset: An acquisition of :data:`~vesselbot_ros.imaging.acquisition.PRESETS` (``gre_1p5t``, ``gre_3t``,
            ``msset_1p5t``), or ``""``: ``acquisition`` as given.
        acquisition: The acquisition's parameters when ``preset`` is ``""``.
        frame_rate_Hz: Acquisitions per second with continuous propulsion (> 0).
        latency_s: Reconstruction and tracking latency with continuous propulsion (s, >= 0; a multiplexed
            sequence's own latency applies there).
        fov_centre_m: The field of view's centre (x, y, z) (m).
        vessel_diameter_m: The vessel in the synthesised background and the tracker's model (m; 0: tissue only).
        noise_sigma_m: Not an input of this imager (its noise is the scanner's): the position noise the
            observers' defaults and the estimation bound assume, 0 (the tables then read the tracker's own).
    """

    kind: Literal["mr_images"] = "mr_images"
    preset: str = "msset_1p5t"
    acquisition: MrImagingParams = dataclasses.field(default_factory=MrImagingParams)
    frame_rate_Hz: float = 50.0
    latency_s: float = 0.0
    fov_centre_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    vessel_diameter_m: float = 0.0
    noise_sigma_m: float = 0.0

    #: The ``mri`` kind's burst and dropout lists, empty here (read by the nodes' fault injection).
    outliers = ()
    dropouts = ()

    def __post_init__(self) -> None:
        if self.preset and self.preset not in PRESETS:
            raise ConfigError(f"imager.preset must be one of {sorted(PRESETS)} or '', got {self.preset!r}")
        check_positive("imager.frame_rate_Hz", self.frame_rate_Hz)
        check_nonnegative("imager.latency_s", self.latency_s)
        check_nonnegative("imager.vessel_diameter_m", self.vessel_diameter_m)
        if len(self.fov_centre_m) != 3 or not all(math.isfinite(v) for v in self.fov_centre_m):
            raise ConfigError(f"imager.fov_centre_m must be three finite numbers (m), got {self.fov_centre_m!r}")

    @property
    def imaging(self) -> MrImagingParams:
        """The acquisition: the preset's, or ``acquisition``."""
        return PRESETS[self.preset] if self.preset else self.acquisition


@dataclasses.dataclass(frozen=True)
class TrackerParams:
    """The ``tracker`` section: the stage that turns each MR frame of the ``mr_images`` imager into a position.

    Attributes:
        kind: ``dipole_fit`` (the default tracker, :class:`~vesselbot_ros.imaging.imager_stage.DipoleFitTracker`),
            or a user's ``module:Class``.  Unused with an imager that delivers positions (``mri``).
        min_chi2: The detection threshold: the chi-square gain of the bead model over the background (> 0); a
            frame whose best fit gains less holds no bead.
    """

    kind: str = "dipole_fit"
    min_chi2: float = 100.0

    def __post_init__(self) -> None:
        check_positive("tracker.min_chi2", self.min_chi2)
