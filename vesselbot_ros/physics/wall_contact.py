"""Hertz contact with the vessel wall, eqs. (15)-(16), with explicit caller-held state.

delta > 0 is penetration of the robot into the wall (paper: delta = NM . n).
The contact force acts along -n (away from the wall, into the vessel)::

    loading   (15): |F_c| = k delta^(3/2)                          (delta > 0)
    unloading (16): |F_c| = F_max ((delta - delta_0)/(delta_max - delta_0))^p   (delta > delta_0)
    k = (4 sqrt(r) / 3) / ((1 - sigma_c^2)/E_c + (1 - sigma_w^2)/E_w)

State machine (``contact_transition``; phases FREE=0, LOADING=1, UNLOADING=2):

* FREE -> LOADING when delta > 0; delta_max, F_max track the deepest point;
* LOADING -> UNLOADING when delta decreases below delta_max; then
  delta_0 = permanent_deformation_ratio * delta_max (the paper gives no law
  for delta_0, Choi and Lim [30] use a fraction of delta_max);
* UNLOADING -> LOADING if delta exceeds delta_max again (reloading); within
  an integrator step, before the transition is applied, the force already
  follows the loading law beyond delta_max (``contact_force_magnitude``);
* UNLOADING -> FREE when delta <= delta_0 (separation; the wall recovers).

Both laws are 0 at delta = 0 (continuous), and the unloading law equals F_max
at delta_max, so the switch is continuous too.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from numba.extending import register_jitable

from vesselbot_ros.physics._validate import finite_array

__all__ = [
    "FREE",
    "LOADING",
    "UNLOADING",
    "hertz_stiffness",
    "contact_force_magnitude",
    "contact_transition",
    "ContactState",
    "update_contact_state",
]

FREE = 0
LOADING = 1
UNLOADING = 2


@register_jitable
def hertz_stiffness(r, e_c, sigma_c, e_w, sigma_w):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """k = (4 sqrt(r)/3) / ((1-sigma_c^2)/E_c + (1-sigma_w^2)/E_w) (N/m^1.5)."""
    return (4.0 * np.sqrt(r) / 3.0) / ((1.0 - sigma_c**2) / e_c + (1.0 - sigma_w**2) / e_w)


@register_jitable
def contact_force_magnitude(delta, phase, delta_max, force_max, delta_0, k, p_exp):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """|F_c| (N), repulsive along -n (arrays ok).

    Loading law (15) unless ``phase`` == UNLOADING and ``delta <= delta_max``,
    then the unloading law (16).  Beyond ``delta_max`` an unloading contact
    re-loads: the loading law applies (continuous at ``delta_max`` because
    ``force_max = k delta_max^1.5``), never an extrapolation of (16).
    """
    pen = np.maximum(delta, 0.0)
    loading = k * pen**1.5
    span = np.maximum(delta_max - delta_0, 1e-300)
    # Re-loading: an integrator stage may probe delta > delta_max while the
    # state still says UNLOADING (the transition is applied after the step).
    # The wall then re-loads along (15); extrapolating (16) beyond delta_max
    # would grow as ((delta - delta_0)/(delta_max - delta_0))^p, unbounded.
    ratio = np.minimum(np.maximum(delta - delta_0, 0.0) / span, 1.0)
    unloading = force_max * ratio**p_exp
    is_unl = (phase == 2) * (delta <= delta_max) * 1.0
    return (1.0 - is_unl) * loading + is_unl * unloading


@register_jitable
def contact_transition(phase, delta_max, force_max, delta_0, delta, k, ratio):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Next (phase, delta_max, force_max, delta_0) after observing ``delta`` (scalars)."""
    if phase == 0:
        if delta > 0.0:
            return 1.0, delta, k * delta**1.5, 0.0
        return 0.0, 0.0, 0.0, 0.0
    if phase == 1:
        if delta >= delta_max:
            return 1.0, delta, k * delta**1.5, 0.0
        if delta <= 0.0:
            return 0.0, 0.0, 0.0, 0.0
        return 2.0, delta_max, force_max, ratio * delta_max
    if delta > delta_max:
        return 1.0, delta, k * delta**1.5, 0.0
    if delta <= delta_0:
        return 0.0, 0.0, 0.0, 0.0
    return 2.0, delta_max, force_max, delta_0


class ContactState(NamedTuple):
    """Immutable Hertz loading/unloading state held by the caller.

    Attributes:
        phase: FREE (0), LOADING (1) or UNLOADING (2).
        delta_max_m: Deepest penetration of the current contact (m).
        force_max_N: Loading force at ``delta_max_m`` (N).
        delta_0_m: Permanent deformation delta_0 of the unloading law (m).
    """

    phase: int = FREE
    delta_max_m: float = 0.0
    force_max_N: float = 0.0
    delta_0_m: float = 0.0

    def to_array(self) -> npt.NDArray[np.float64]:
        """(4,) float64 ``contact_arr`` layout of the kernel: [phase, delta_max, F_max, delta_0]."""
        return np.array([float(self.phase), self.delta_max_m, self.force_max_N, self.delta_0_m])

    @classmethod
    def from_array(cls, arr: npt.ArrayLike) -> ContactState:
        """Inverse of :meth:`to_array`."""
        a = finite_array("contact_arr", arr).reshape(4)
        return cls(int(round(a[0])), float(a[1]), float(a[2]), float(a[3]))


def update_contact_state(
    state: ContactState, delta_m: float, stiffness_N_per_m1p5: float, permanent_deformation_ratio: float
) -> ContactState:
    """Pure state update after observing the penetration ``delta_m`` (m).

    Args:
        state: Current state.
        delta_m: Signed distance to the wall (m), > 0 in contact.
        stiffness_N_per_m1p5: Hertz k (N/m^1.5), see :func:`hertz_stiffness`.
        permanent_deformation_ratio: delta_0 / delta_max in [0, 1).

    Returns:
        The next state (a new object).
    """
    d = float(finite_array("delta_m", delta_m))
    out = contact_transition(float(state.phase), state.delta_max_m, state.force_max_N, state.delta_0_m, d,
                             stiffness_N_per_m1p5, permanent_deformation_ratio)
    return ContactState(int(out[0]), float(out[1]), float(out[2]), float(out[3]))
