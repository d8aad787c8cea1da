"""Apparent blood viscosity in a vessel of diameter d, eq. (9) (Pries et al. 1996).

With d the vessel diameter in micrometres and h_d the discharge hematocrit::

    eta      = eta_pl * (d/(d-1.1))^2 * [1 + (eta_045 - 1) * (d/(d-1.1))^2
                                          * ((1-h_d)^c - 1) / ((1-0.45)^c - 1)]
    eta_045  = 6 exp(-0.085 d) + 3.2 - 2.44 exp(-0.06 d^0.645)
    c        = (0.8 + exp(-0.075 d)) * (-1 + 1/(1 + 1e-11 d^12)) + 1/(1 + 1e-11 d^12)   (Pries)
             = 1e11/(d^12 + 1e11) - (0.8 + exp(-0.075 d)) * d^12/(d^12 + 1e11)

The paper prints the first term of c as 1e11/d^12 instead of 1e11/(d^12+1e11).
Both agree for d >~ 20 um (d^12 >> 1e11) but the printed form diverges as
d -> 0 (c ~ 1.9e5 at d = 3 um, so (1-h_d)^c -> 0 and eta collapses to a
hematocrit-independent value).  ``model='pries_1996'`` (default) is the sound
form, ``'paper_printed'`` the printed one.  The formula needs d > 1.1 um.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import numpy.typing as npt
from numba.extending import register_jitable

from vesselbot_ros.config import ConfigError
from vesselbot_ros.physics._validate import positive
from vesselbot_ros.physics.params import BloodParams

__all__ = ["relative_viscosity_045", "hematocrit_exponent", "blood_viscosity", "viscosity_for"]


@register_jitable
def relative_viscosity_045(d_um):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """eta_0.45(d): relative apparent viscosity at h_d = 0.45 (-); d in um (scalar or array)."""
    return 6.0 * np.exp(-0.085 * d_um) + 3.2 - 2.44 * np.exp(-0.06 * d_um**0.645)


@register_jitable
def hematocrit_exponent(d_um, printed):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Exponent c(d) (-); ``printed`` = 1.0 selects the paper's printed 1e11/d^12 term."""
    d12 = d_um**12
    frac = d12 / (d12 + 1.0e11)
    first = printed * (1.0e11 / d12) + (1.0 - printed) * (1.0e11 / (d12 + 1.0e11))
    return first - (0.8 + np.exp(-0.075 * d_um)) * frac


@register_jitable
def _viscosity(d_um, hematocrit, plasma_viscosity, printed):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    ratio2 = (d_um / (d_um - 1.1)) ** 2
    c = hematocrit_exponent(d_um, printed)
    shape = ((1.0 - hematocrit) ** c - 1.0) / (0.55**c - 1.0)
    return plasma_viscosity * ratio2 * (1.0 + (relative_viscosity_045(d_um) - 1.0) * ratio2 * shape)


def blood_viscosity(
    diameter_m: npt.ArrayLike,
    hematocrit: float = 0.45,
    plasma_viscosity_Pa_s: float = 5.0e-3,
    model: Literal["pries_1996", "paper_printed", "constant"] = "pries_1996",
    constant_viscosity_Pa_s: float = 0.016,
) -> npt.NDArray[np.float64]:
    """Apparent blood viscosity eta (Pa s) in a vessel of diameter ``diameter_m``.

    Args:
        diameter_m: Vessel diameter D (m), scalar or any shape; must exceed 1.1 um.
        hematocrit: Discharge hematocrit h_d in [0, 1).
        plasma_viscosity_Pa_s: eta_pl (Pa s).
        model: ``'pries_1996'``, ``'paper_printed'`` or ``'constant'``.
        constant_viscosity_Pa_s: Returned everywhere by the ``'constant'`` model.

    Returns:
        eta (Pa s), same shape as ``diameter_m``.

    Raises:
        ConfigError: non-positive or too small diameter, hematocrit outside [0, 1),
            unknown model.
    """
    d_m = positive("diameter_m", diameter_m)
    if not (0.0 <= hematocrit < 1.0):
        raise ConfigError(f"hematocrit must be in [0, 1), got {hematocrit!r}")
    positive("plasma_viscosity_Pa_s", plasma_viscosity_Pa_s)
    if model == "constant":
        return np.full_like(d_m, positive("constant_viscosity_Pa_s", constant_viscosity_Pa_s))
    if model not in ("pries_1996", "paper_printed"):
        raise ConfigError(f"viscosity_model must be one of ['pries_1996', 'paper_printed', 'constant'], got {model!r}")
    d_um = d_m * 1.0e6
    if np.any(d_um <= 1.1):
        raise ConfigError(f"diameter_m must exceed 1.1e-6 m for eq. (9), got {diameter_m!r}")
    printed = 1.0 if model == "paper_printed" else 0.0
    with np.errstate(over="ignore", divide="ignore"):
        return np.asarray(_viscosity(d_um, hematocrit, plasma_viscosity_Pa_s, printed), dtype=np.float64)


def viscosity_for(blood: BloodParams, diameter_m: float) -> float:
    """eta (Pa s) of ``blood`` (its model and constants) in a vessel of ``diameter_m`` (m)."""
    return float(blood_viscosity(diameter_m, blood.hematocrit, blood.plasma_viscosity_Pa_s,
                                 blood.viscosity_model, blood.constant_viscosity_Pa_s))
