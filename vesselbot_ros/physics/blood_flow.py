"""Pulsatile blood flow (12), diameter pulsation (13) and the straight-vessel geometry.

Geometry (paper Section II-B, Table III), 2-D frame W: x along the vessel axis
(flow towards +x), z across it (vertical, gravity along -z).  The centreline is
z = 0, the upper wall z = +D(t)/2, the lower wall z = -D(t)/2.  Delta = z is
the signed distance of the robot centre to the centreline.

Signed wall distance (paper convention, delta = NM . n): for a robot of radius
r centred at z,

    delta_upper = z + r - D(t)/2        n_upper = (0, +1)
    delta_lower = -z + r - D(t)/2       n_lower = (0, -1)

n is the wall normal pointing out of the vessel; delta > 0 means the robot
penetrates the wall (contact), delta < 0 is a gap of -delta.

Flow (12): v_f = V_f (1 + a_f sin(omega_f t + phi_f)) p(x, z, t) along +x, with
the parabolic profile p_p = 1 - (2 z / D(t))^2 (V_f is the centreline velocity),
or, inside a major-bifurcation section, the blend of p_p with the rational
profile of :mod:`vesselbot_ros.physics.bifurcation`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from numba.extending import register_jitable

from vesselbot_ros.errors import ModelInputError
from vesselbot_ros.physics._validate import finite_array
from vesselbot_ros.physics.bifurcation import ProfileTable, load_profile_table, rational_profile_at
from vesselbot_ros.physics.params import PhysicsParams

__all__ = [
    "pulse_factor",
    "vessel_diameter",
    "parabolic_profile",
    "wall_deltas",
    "smoothstep",
    "bifurcation_weight",
    "blended_profile",
    "WallGeometry",
    "Vessel",
]


@register_jitable
def pulse_factor(t, a_f, omega_f, phi_f):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """1 + a_f sin(omega_f t + phi_f), eq. (12) (-); t in s."""
    return 1.0 + a_f * np.sin(omega_f * t + phi_f)


@register_jitable
def vessel_diameter(t, d_nominal, amplitude, omega_f, phi_f):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """D(t) = D (1 + amplitude sin(omega_f t + phi_f)), eq. (13) (m)."""
    return d_nominal * (1.0 + amplitude * np.sin(omega_f * t + phi_f))


@register_jitable
def parabolic_profile(z, d_t):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """p_p = max(0, 1 - (2 z / D(t))^2) (-); zero outside the vessel."""
    y = 2.0 * z / d_t
    return np.maximum(0.0, 1.0 - y * y)


@register_jitable
def wall_deltas(z, r, d_t):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """(delta_upper, delta_lower) (m): signed robot-wall distances, > 0 in contact."""
    return z + r - 0.5 * d_t, -z + r - 0.5 * d_t


@register_jitable
def smoothstep(s):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """C^1 ramp 3 s^2 - 2 s^3 of s clamped to [0, 1] (-)."""
    c = np.minimum(1.0, np.maximum(0.0, s))
    return c * c * (3.0 - 2.0 * c)


@register_jitable
def bifurcation_weight(x, x_start, x_end, ramp_fraction):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Blend weight w(x) in [0, 1] of the rational profile; 0 outside [x_start, x_end]."""
    s = (x - x_start) / (x_end - x_start)
    return smoothstep(s / ramp_fraction) * smoothstep((1.0 - s) / ramp_fraction)


@register_jitable
def blended_profile(x, z, d_t, x_start, x_end, theta_start, theta_end, ramp, knots, values, slopes):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Profile p(x, z) (-) of a vessel with one major bifurcation (scalars only).

    theta(x) goes linearly from theta_start to theta_end (deg) over the section;
    p = (1 - w) p_p + w p_r(2 z / D(t); theta(x)).
    """
    pp = parabolic_profile(z, d_t)
    w = bifurcation_weight(x, x_start, x_end, ramp)
    if w <= 0.0:
        return pp
    s = min(1.0, max(0.0, (x - x_start) / (x_end - x_start)))
    theta = theta_start + (theta_end - theta_start) * s
    y = min(1.0, max(-1.0, 2.0 * z / d_t))
    pr = rational_profile_at(y, theta, knots, values, slopes)
    inside = 1.0 if abs(2.0 * z / d_t) <= 1.0 else 0.0
    return (1.0 - w) * pp + w * pr * inside


class WallGeometry(NamedTuple):
    """Local geometry of the robot relative to the nearest wall.

    Attributes:
        delta_m: Signed distance to the nearest wall (m); > 0 is penetration.
        wall: +1 for the upper wall (z = +D/2), -1 for the lower wall.
        normal_W: (2,) outward wall normal n of that wall in W (-).
        diameter_m: Vessel diameter D(t) (m).
        v_fluid_W: (2,) blood velocity at the robot centre in W (m/s).
    """

    delta_m: float
    wall: int
    normal_W: npt.NDArray[np.float64]
    diameter_m: float
    v_fluid_W: npt.NDArray[np.float64]


class Vessel:
    """Straight vessel of Table III (optionally with one major bifurcation).

    A thin numpy facade over the jitable formulas above; the same formulas run
    in the numba kernel (:mod:`vesselbot_ros.physics.kernel`).

    Args:
        params: Physics parameters (vessel, flow and robot sections are used).
    """

    def __init__(self, params: PhysicsParams) -> None:
        self.params = params
        bif = params.vessel.major_bifurcation
        self.table: ProfileTable | None = load_profile_table(bif.profile_table) if bif.enabled else None

    def diameter(self, t_s: float) -> float:
        """D(t) (m), eq. (13)."""
        f = self.params.flow
        t = float(t_s) if isinstance(t_s, (float, int)) else float(finite_array("t_s", t_s))
        if not math.isfinite(t):
            raise ModelInputError(f"t_s must be finite, got {t_s!r}")
        return float(vessel_diameter(t, self.params.vessel.diameter_m, f.diameter_pulsation,
                                     f.angular_frequency_rad_per_s, f.phase_rad))

    def profile(self, t_s: float, p_W: npt.ArrayLike) -> float:
        """Velocity profile value p(x, z) (-) at the point ``p_W`` = (x, z) (m)."""
        x, z = finite_array("p_W", p_W).reshape(2)
        d_t = self.diameter(t_s)
        bif = self.params.vessel.major_bifurcation
        if self.table is None:
            return float(parabolic_profile(z, d_t))
        return float(blended_profile(float(x), float(z), d_t, bif.x_start_m, bif.x_end_m,
                                     bif.theta_start_deg, bif.theta_end_deg, bif.ramp_fraction,
                                     self.table.knots_deg, self.table.values.ravel(), self.table.slopes.ravel()))

    def fluid_velocity(self, t_s: float, p_W: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """(2,) blood velocity v_f at ``p_W`` (m/s), eq. (12), along +x."""
        f = self.params.flow
        pulse = pulse_factor(float(t_s), f.pulsatility, f.angular_frequency_rad_per_s, f.phase_rad)
        return np.array([f.inflow_velocity_m_per_s * pulse * self.profile(t_s, p_W), 0.0])

    def geometry(self, t_s: float, p_W: npt.ArrayLike) -> WallGeometry:
        """Signed distance, wall and normal of the nearest wall at robot position ``p_W`` (m)."""
        p = finite_array("p_W", p_W).reshape(2)
        d_t = self.diameter(t_s)
        d_up, d_lo = wall_deltas(float(p[1]), self.params.robot.radius_m, d_t)
        wall = 1 if d_up >= d_lo else -1
        return WallGeometry(
            delta_m=float(max(d_up, d_lo)),
            wall=wall,
            normal_W=np.array([0.0, float(wall)]),
            diameter_m=d_t,
            v_fluid_W=self.fluid_velocity(t_s, p),
        )
