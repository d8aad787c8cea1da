"""Design maps of Fig. 7: F_m / F_tot over (lambda = 2r/D, Delta) per vessel and design.

Every force comes from the jitable formula functions of the physics core,
evaluated on numpy grids (no Python loop per grid point).

Conventions (see docs/physics.md and docs/reproduction.md):

* steady flow (the mean of eq. (12), a_f = 0) with Table I's velocity as the
  centreline velocity V_f, parabolic profile, nominal diameter D;
* the robot is held still (v = 0) so the drag is that of the blood overtaking it;
* F_tot = |F_d + F_el + F_vdw + F_s + W_a| (vector sum, Section III-A), the
  interaction forces summed over both walls; F_m is the largest motive force
  available (BP: 80 mT/m in any direction; EF, HT: along the axis);
* HT: the tail slow-down term of eq. (5) is added to F_tot (``ht_slowdown_in_load``)
  or subtracted from F_m;
* Delta spans the positions where the gap to either wall is >= ``min_gap_m``;
  the map's second axis is xi = Delta / (D/2 - r - min_gap_m) in [-1, 1].
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal, NamedTuple

import numpy as np
import numpy.typing as npt

from vesselbot_ros.config import ConfigError, check_positive, check_range, load_dataclass
from vesselbot_ros.physics.apparent_weight import apparent_weight_z, sphere_volume
from vesselbot_ros.physics.blood_flow import parabolic_profile, wall_deltas
from vesselbot_ros.physics.blood_viscosity import viscosity_for
from vesselbot_ros.physics.drag import drag_gain, wall_factor
from vesselbot_ros.physics.magnetic_force import (
    bead_pulling_force,
    ef_tail_length,
    elastic_flagellum_force,
    flagellum_normal_drag,
    helical_tail_slowdown_gain,
    helical_tail_thrust,
    helix_drag_coefficients,
    sperm_number_function,
)
from vesselbot_ros.physics.params import (
    BOLTZMANN_J_PER_K,
    VACUUM_PERMITTIVITY_F_PER_M,
    DesignParams,
    PhysicsParams,
)
from vesselbot_ros.physics.wall_interactions import (
    contact_heaviside_flag,
    electrostatic_factor,
    robot_charge,
    steric_coefficient,
    wall_pair_forces_z,
)
from vesselbot_ros.resources import require_fits

__all__ = [
    "DESIGNS",
    "VesselCase",
    "GridParams",
    "Table2Ranges",
    "DesignStudy",
    "DesignMap",
    "MapSummary",
    "motive_force",
    "load_forces",
    "design_map",
    "summarize",
    "all_design_maps",
]

Design = Literal["BP", "EF", "HT"]
DESIGNS: tuple[Design, ...] = ("BP", "EF", "HT")


@dataclasses.dataclass(frozen=True)
class VesselCase:
    """One vessel of Table I.

    Attributes:
        name: Label (e.g. ``artery``).
        diameter_m: D (m).
        velocity_m_per_s: Blood (centreline) velocity (m/s).
    """

    name: str = "small_artery"
    diameter_m: float = 1.0e-3
    velocity_m_per_s: float = 0.02

    def __post_init__(self) -> None:
        if not self.name:
            raise ConfigError("name must be a non-empty string, got ''")
        check_positive("diameter_m", self.diameter_m)
        check_positive("velocity_m_per_s", self.velocity_m_per_s)


def _table1() -> tuple[VesselCase, ...]:
    return (
        VesselCase("artery", 10e-3, 0.25),
        VesselCase("small_artery", 1e-3, 0.02),
        VesselCase("arteriole", 0.1e-3, 1e-3),
        VesselCase("capillary", 0.01e-3, 0.05e-3),
    )


MAX_GRID_POINTS = 1_000_000  # per map: about 100x the default 200 x 200, a few hundred MB of temporaries
#: What a map keeps per point (Delta, F_tot, the ratio: float64) and what one map's forces take while it is
#: computed (the force terms' temporaries, rounded up), bytes.
MAP_POINT_BYTES = 24
MAP_TEMP_BYTES = 512


@dataclasses.dataclass(frozen=True)
class GridParams:
    """Map grid.

    Attributes:
        n_lambda: Points along lambda (-).
        n_delta: Points along Delta (-).
        lambda_min: Smallest lambda (-), > 0.
        lambda_max: Largest lambda (-), < 1.
        min_gap_m: Closest robot-wall gap on the map (m) (default: L0 = 100 nm,
            where the polymer brush holds the robot off the wall).
    """

    n_lambda: int = 200
    n_delta: int = 200
    lambda_min: float = 0.01
    lambda_max: float = 0.9
    min_gap_m: float = 100e-9

    def __post_init__(self) -> None:
        if self.n_lambda < 2 or self.n_delta < 2:
            raise ConfigError(f"n_lambda and n_delta must be >= 2, got {self.n_lambda}, {self.n_delta}")
        if self.n_lambda * self.n_delta > MAX_GRID_POINTS:  # bounded memory and time before any work
            raise ConfigError(f"n_lambda x n_delta must be <= {MAX_GRID_POINTS} points per map, got "
                              f"{self.n_lambda} x {self.n_delta} = {self.n_lambda * self.n_delta:.3g}")
        check_range("lambda_min", self.lambda_min, 0.0, 1.0, lo_open=True, hi_open=True)
        check_range("lambda_max", self.lambda_max, self.lambda_min, 1.0, lo_open=True, hi_open=True)
        check_positive("min_gap_m", self.min_gap_m)


@dataclasses.dataclass(frozen=True)
class Table2Ranges:
    """Physiological ranges of Table II (low, high).

    Attributes:
        relative_permittivity: epsilon (-). The table's unit C^2 N^-1 m^-2 is a misprint.
        viscosity_Pa_s: eta (Pa s) (the table prints Pa.s^-1).
        blood_density_kg_per_m3: rho_f (kg/m^3).
        wall_young_modulus_Pa: E_w (Pa).
    """

    relative_permittivity: tuple[float, float] = (45.0, 77.0)
    viscosity_Pa_s: tuple[float, float] = (0.008, 0.02)
    blood_density_kg_per_m3: tuple[float, float] = (1050.6, 1062.1)
    wall_young_modulus_Pa: tuple[float, float] = (1.25e9, 1.37e9)

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            lo, hi = getattr(self, f.name)
            check_positive(f"{f.name}[0]", lo)
            if not hi >= lo:
                raise ConfigError(f"{f.name} must be (low, high) with high >= low, got {(lo, hi)!r}")


@dataclasses.dataclass(frozen=True)
class DesignStudy:
    """The Fig. 7 study: vessels x designs on a (lambda, Delta) grid."""

    vessels: tuple[VesselCase, ...] = dataclasses.field(default_factory=_table1)
    design: DesignParams = dataclasses.field(default_factory=DesignParams)
    grid: GridParams = dataclasses.field(default_factory=GridParams)
    table2: Table2Ranges = dataclasses.field(default_factory=Table2Ranges)

    def __post_init__(self) -> None:
        if not self.vessels:
            raise ConfigError("vessels must list at least one vessel")
        n_maps = len(self.vessels) * len(DESIGNS)  # every map is kept (the summary, the CSVs and the figure read them)
        points = self.grid.n_lambda * self.grid.n_delta
        require_fits("vessels", f"{len(self.vessels)} vessels", MAP_POINT_BYTES * n_maps * points + MAP_TEMP_BYTES * points,
                     what=f"the {n_maps} maps of {points} points", hint="fewer vessels or a coarser grid")

    @classmethod
    def from_mapping(cls, mapping: object) -> DesignStudy:
        """Strictly load from a YAML mapping (the ``design_study`` section)."""
        return load_dataclass(cls, mapping, "design_study")


class DesignMap(NamedTuple):
    """One map of Fig. 7.

    Attributes:
        vessel: Vessel name. design: 'BP' | 'EF' | 'HT'.
        lam: (n_lambda,) lambda values (-).
        xi: (n_delta,) normalised positions Delta / Delta_max (-), +1 = upper wall.
        delta_m: (n_lambda, n_delta) Delta (m).
        ratio: (n_lambda, n_delta) F_m / F_tot (-).
        f_motive_N: (n_lambda,) F_m (N). f_load_N: (n_lambda, n_delta) F_tot (N).
    """

    vessel: str
    design: str
    lam: npt.NDArray[np.float64]
    xi: npt.NDArray[np.float64]
    delta_m: npt.NDArray[np.float64]
    ratio: npt.NDArray[np.float64]
    f_motive_N: npt.NDArray[np.float64]
    f_load_N: npt.NDArray[np.float64]


class MapSummary(NamedTuple):
    """Printed summary of one map.

    Attributes:
        vessel, design: Labels.
        max_ratio: Maximum F_m / F_tot (-).
        lam_at_max: lambda at the maximum (-). delta_at_max_m: Delta at the maximum (m).
        xi_at_max: Delta / Delta_max at the maximum (-).
        lam_range_90: (lo, hi) lambda range where max over Delta >= 0.9 max_ratio.
    """

    vessel: str
    design: str
    max_ratio: float
    lam_at_max: float
    delta_at_max_m: float
    xi_at_max: float
    lam_range_90: tuple[float, float]


def motive_force(
    design: Design, r: npt.NDArray[np.float64], eta: float, params: PhysicsParams, dp: DesignParams
) -> npt.NDArray[np.float64]:
    """Largest motive force |F_m| (N) of ``design`` for radii ``r`` (m) in blood of viscosity eta."""
    rb = params.robot
    vol = sphere_volume(r)
    if design == "BP":
        return np.asarray(bead_pulling_force(rb.magnetic_ratio, vol, rb.magnetization_A_per_m, dp.bp_gradient_T_per_m))
    omega = 2.0 * math.pi * dp.rot_frequency_Hz
    phi = math.radians(dp.pitch_deg)
    kappa = dp.tail_radius_ratio * r
    if design == "EF":
        length = ef_tail_length(r, dp.n_turns, phi, 1.0 if dp.ef_tail_length == "helix_contour" else 0.0)
        zeta = flagellum_normal_drag(eta, length, kappa)
        z_sp = sperm_number_function(dp.sperm_number, dp.ef_base)
        return np.asarray(elastic_flagellum_force(rb.magnetic_ratio, vol, rb.magnetization_A_per_m, dp.rot_field_T, omega, length, zeta,
                                                  dp.sperm_number, z_sp))
    if design == "HT":
        zp, zl = helix_drag_coefficients(eta, r, kappa, phi)
        return np.asarray(helical_tail_thrust(r, dp.n_turns, phi, zp, zl, omega))
    raise ConfigError(f"design must be one of {list(DESIGNS)}, got {design!r}")


def load_forces(
    r: npt.NDArray[np.float64],
    z: npt.NDArray[np.float64],
    diameter_m: float,
    v_centre_m_per_s: float,
    eta: float,
    params: PhysicsParams,
) -> dict[str, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]]:
    """(x, z) components (N) of each non-motive force on a still robot, vectorised.

    Args:
        r: Radii (m), broadcastable with ``z``.
        z: Robot-centre positions Delta (m).
        diameter_m: D (m). v_centre_m_per_s: centreline blood velocity (m/s).
        eta: Blood viscosity (Pa s). params: physics parameters (blood, robot,
            interactions, drag, vessel.gravity).

    Returns:
        Mapping term name -> (F_x, F_z) arrays: drag, apparent_weight,
        van_der_waals, electrostatic, steric.
    """
    rb, it, b = params.robot, params.interactions, params.blood
    lam = 2.0 * r / diameter_m
    vf = v_centre_m_per_s * parabolic_profile(z, diameter_m)
    c = drag_gain(np.abs(vf), r, eta, b.density_kg_per_m3, wall_factor(lam, params.drag.alpha0, params.drag.lambda0))
    weight_z = apparent_weight_z(sphere_volume(r), rb.density_kg_per_m3, b.density_kg_per_m3, params.vessel.gravity_m_per_s2)
    q = robot_charge(r, rb.charge_C, rb.charge_scale)
    st = steric_coefficient(r, it.brush_length_m, BOLTZMANN_J_PER_K * b.temperature_K, it.grafting_density_per_m2)
    d_up, d_lo = wall_deltas(z, r, diameter_m)
    vdw, el, ster = wall_pair_forces_z(
        d_up, d_lo, r, it.hamaker_constant_J, it.vdw_floor_m, q,
        b.relative_permittivity * VACUUM_PERMITTIVITY_F_PER_M,
        electrostatic_factor(it.electrostatic_model), st, it.brush_length_m,
        contact_heaviside_flag(it.in_contact),
    )
    zero = np.zeros(np.broadcast(r, z).shape)
    return {
        "drag": (zero + c * vf, zero),
        "apparent_weight": (zero, zero + weight_z),
        "van_der_waals": (zero, zero + vdw),
        "electrostatic": (zero, zero + el),
        "steric": (zero, zero + ster),
    }


def design_map(vessel: VesselCase, design: Design, params: PhysicsParams, study: DesignStudy) -> DesignMap:
    """Compute one (lambda, Delta) map of F_m / F_tot for ``vessel`` and ``design``."""
    g = study.grid
    lam = np.linspace(g.lambda_min, g.lambda_max, g.n_lambda)
    xi = np.linspace(-1.0, 1.0, g.n_delta)
    d = vessel.diameter_m
    r = 0.5 * lam * d
    delta_max = np.maximum(0.5 * d - r - g.min_gap_m, 0.0)
    z = delta_max[:, None] * xi[None, :]
    eta = viscosity_for(params.blood, vessel.diameter_m)
    terms = load_forces(r[:, None], z, d, vessel.velocity_m_per_s, eta, params)
    fx = sum(t[0] for t in terms.values())
    fz = sum(t[1] for t in terms.values())
    fm = motive_force(design, r, eta, params, study.design)
    fm2 = np.broadcast_to(fm[:, None], z.shape)
    if design == "HT":
        dp = study.design
        phi = math.radians(dp.pitch_deg)
        zp, zl = helix_drag_coefficients(eta, r, dp.tail_radius_ratio * r, phi)
        slow = helical_tail_slowdown_gain(r, dp.n_turns, phi, zp, zl)[:, None] * vessel.velocity_m_per_s * parabolic_profile(z, d)
        if dp.ht_slowdown_in_load:
            fx = fx + slow
        else:
            fm2 = np.maximum(fm2 - slow, 0.0)
    f_tot = np.sqrt(fx * fx + fz * fz)
    ratio = fm2 / np.maximum(f_tot, 1e-300)
    return DesignMap(vessel.name, design, lam, xi, z, ratio, fm, f_tot)


def summarize(m: DesignMap) -> MapSummary:
    """Maximum, its location and the 90 % lambda range (contiguous, around the best lambda)."""
    i, j = np.unravel_index(int(np.argmax(m.ratio)), m.ratio.shape)
    best = float(m.ratio[i, j])
    per_lam = m.ratio.max(axis=1)
    ok = per_lam >= 0.9 * best
    lo = i
    while lo > 0 and ok[lo - 1]:
        lo -= 1
    hi = i
    while hi < ok.size - 1 and ok[hi + 1]:
        hi += 1
    return MapSummary(m.vessel, m.design, best, float(m.lam[i]), float(m.delta_m[i, j]), float(m.xi[j]),
                      (float(m.lam[lo]), float(m.lam[hi])))


def all_design_maps(params: PhysicsParams, study: DesignStudy) -> list[DesignMap]:
    """Every vessel x design map (12 for Table I), vessel-major order."""
    return [design_map(v, d, params, study) for v in study.vessels for d in DESIGNS]
