"""Validated, frozen parameters of the physics core (SI units, Table III defaults).

The composition is::

    PhysicsParams(blood, flow, vessel, robot, wall, interactions, drag)

Every field carries its unit in its name or comment.  Where the paper's printed
equation and the physically sound form differ, a ``Literal`` field selects the
form; the default is always the sound one (see ``docs/physics.md``).

Overrides: ``params.with_overrides({"flow.centreline_velocity_m_per_s": 0.02625})``
returns a new, re-validated instance (dotted keys, same strict loader as YAML);
``dataclasses.replace`` also works on every section.

Design-study parameters for the three motive designs (Section III-A) live in
:class:`DesignParams`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, Literal

from vesselbot_ros.config import (
    OMIT_IF,
    ConfigError,
    apply_overrides,
    check_choice,
    check_finite,
    check_nonnegative,
    check_positive,
    check_range,
    flatten,
    load_dataclass,
    to_mapping,
    unflatten,
)
from vesselbot_ros.physics.apparent_weight import sphere_volume

__all__ = [
    "BloodParams",
    "FlowParams",
    "MajorBifurcationParams",
    "VesselParams",
    "RobotParams",
    "WallParams",
    "InteractionParams",
    "DragParams",
    "PhysicsParams",
    "DesignParams",
    "planar_twin",
    "VACUUM_PERMITTIVITY_F_PER_M",
    "BOLTZMANN_J_PER_K",
]

VACUUM_PERMITTIVITY_F_PER_M = 8.8541878128e-12
BOLTZMANN_J_PER_K = 1.380649e-23


@dataclasses.dataclass(frozen=True)
class BloodParams:
    """Blood properties (Table III; eq. (9) viscosity).

    Attributes:
        plasma_viscosity_Pa_s: Plasma viscosity eta_pl (Pa s). Table III: 5e-3.
        density_kg_per_m3: Blood density rho_f (kg/m^3). Table III: 1060.
        hematocrit: Discharge hematocrit h_d, in [0, 1). Pries' reference 0.45.
        viscosity_model: ``'pries_1996'`` (sound exponent c of Pries et al.),
            ``'paper_printed'`` (eq. (9) as printed, diverges for small d) or
            ``'constant'`` (use ``constant_viscosity_Pa_s``).
        constant_viscosity_Pa_s: Viscosity used by the ``'constant'`` model (Pa s).
        relative_permittivity: Relative permittivity of blood epsilon (-).  Table III
            prints the unit C^2 N^-1 m^-2, but 70 is dimensionless (water ~ 74 at 37 C).
        temperature_K: Absolute temperature T (K), used by the steric force.
    """

    plasma_viscosity_Pa_s: float = 5.0e-3
    density_kg_per_m3: float = 1060.0
    hematocrit: float = 0.45
    viscosity_model: Literal["pries_1996", "paper_printed", "constant"] = "pries_1996"
    constant_viscosity_Pa_s: float = 0.016
    relative_permittivity: float = 70.0
    temperature_K: float = 310.0

    def __post_init__(self) -> None:
        check_positive("plasma_viscosity_Pa_s", self.plasma_viscosity_Pa_s)
        check_positive("density_kg_per_m3", self.density_kg_per_m3)
        check_range("hematocrit", self.hematocrit, 0.0, 1.0, hi_open=True)
        check_choice("viscosity_model", self.viscosity_model, ("pries_1996", "paper_printed", "constant"))
        check_positive("constant_viscosity_Pa_s", self.constant_viscosity_Pa_s)
        check_range("relative_permittivity", self.relative_permittivity, 1.0, 1000.0)
        check_positive("temperature_K", self.temperature_K)


def _is_empty(value: str) -> bool:
    return value == ""


def _is_one(value: float) -> bool:
    return bool(value == 1.0)


@dataclasses.dataclass(frozen=True)
class FlowParams:
    """Pulsatile blood flow, eqs. (12)-(13) (Table III).

    Attributes:
        centreline_velocity_m_per_s: V_f, the centreline (profile maximum) velocity
            of the mean flow (m/s). Table III: 0.025.
        pulsatility: a_f (-); a_f > 1 gives diastolic backflow. Table III: 1.15.
        angular_frequency_rad_per_s: omega_f (rad/s). Table III: 2 pi.
        phase_rad: phi_f (rad). Table III: pi/2.
        diameter_pulsation: Relative amplitude of D(t), eq. (13) (-). Paper: 0.1.
        preset: ``""`` (the values above, Table III by default) or the name of a physiological flow preset of
            the vessel network (its file's ``flow_presets``, docs/vessels.md "Physiological flow presets"): the
            scenario loader then writes the preset's centreline velocity, pulsatility and angular frequency
            into this section (:func:`vesselbot_ros.sim.scenario.scenario_from_mapping`), and the network's
            CFD field is solved with the preset's outlet shares.  Left out of
            :func:`~vesselbot_ros.config.to_mapping` when empty.
        inflow_fraction: Fraction of the inflow left by a flow reduction upstream (-), in [0, 1]: 1 (the
            default) none; a proximal balloon occlusion arrests the antegrade flow (0).  The plant and the
            model scale V_f by it (:attr:`inflow_velocity_m_per_s`).  Left out of ``to_mapping`` at 1.
    """

    centreline_velocity_m_per_s: float = 0.025
    pulsatility: float = 1.15
    angular_frequency_rad_per_s: float = 2.0 * math.pi
    phase_rad: float = math.pi / 2.0
    diameter_pulsation: float = 0.1
    preset: str = dataclasses.field(default="", metadata={OMIT_IF: _is_empty})
    inflow_fraction: float = dataclasses.field(default=1.0, metadata={OMIT_IF: _is_one})

    def __post_init__(self) -> None:
        check_finite("centreline_velocity_m_per_s", self.centreline_velocity_m_per_s)
        check_nonnegative("pulsatility", self.pulsatility)
        check_nonnegative("angular_frequency_rad_per_s", self.angular_frequency_rad_per_s)
        check_finite("phase_rad", self.phase_rad)
        check_range("diameter_pulsation", self.diameter_pulsation, 0.0, 0.5)
        if not isinstance(self.preset, str) or (self.preset and not all(c.isalnum() or c == "_" for c in self.preset)):
            raise ConfigError(f"preset must be '' or a name of letters, digits and '_', got {self.preset!r}")
        check_range("inflow_fraction", self.inflow_fraction, 0.0, 1.0)

    @property
    def inflow_velocity_m_per_s(self) -> float:
        """V_f the plant flies in (m/s): ``centreline_velocity_m_per_s`` times ``inflow_fraction`` (exact at 1)."""
        return self.centreline_velocity_m_per_s * self.inflow_fraction


@dataclasses.dataclass(frozen=True)
class MajorBifurcationParams:
    """Placement of one major bifurcation along a straight vessel (Section II-A2).

    Inside ``[x_start_m, x_end_m]`` the parabolic profile is blended into the
    rational profile p_r whose parameters follow the angle theta, mapped linearly
    from x: theta(x_start) = theta_start_deg, theta(x_end) = theta_end_deg.

    Attributes:
        enabled: Whether the section exists (default: straight small artery, none).
        x_start_m: Start of the section along the axis (m).
        x_end_m: End of the section (m), > x_start_m.
        theta_start_deg: Angle at x_start (deg).
        theta_end_deg: Angle at x_end (deg).
        ramp_fraction: Fraction of the section length over which the profile is
            blended (smoothstep) from/to the parabola at each end (-), in (0, 0.5].
        profile_table: ``'default'`` (shipped table, see ``bifurcation.py``) or a
            path to a parameter CSV written by ``bifurcation.save_profile_table``.
    """

    enabled: bool = False
    x_start_m: float = 0.01
    x_end_m: float = 0.02
    theta_start_deg: float = 0.0
    theta_end_deg: float = 60.0
    ramp_fraction: float = 0.1
    profile_table: str = "default"

    def __post_init__(self) -> None:
        check_finite("x_start_m", self.x_start_m)
        check_finite("x_end_m", self.x_end_m)
        if self.x_end_m <= self.x_start_m:
            raise ConfigError(
                f"x_end_m must be > x_start_m ({self.x_start_m!r}), got {self.x_end_m!r}"
            )
        check_finite("theta_start_deg", self.theta_start_deg)
        check_finite("theta_end_deg", self.theta_end_deg)
        check_range("ramp_fraction", self.ramp_fraction, 0.0, 0.5, lo_open=True)


@dataclasses.dataclass(frozen=True)
class VesselParams:
    """Straight 2-D vessel: centreline z = 0, walls at z = +/- D(t)/2, flow along +x.

    Attributes:
        diameter_m: Nominal diameter D (m). Table III: 3e-3.
        gravity_m_per_s2: Gravity magnitude g (m/s^2), acting along -z.
        major_bifurcation: Optional major-bifurcation section.
        network: ``""`` (the straight vessel above, analytic flow) or a vessel
            network file (``config/vessels/<name>.yaml``, or a shipped name):
            geometry and flow from its CFD field (``vesselbot_ros.vessels``);
            ``diameter_m`` is then only the nominal diameter of the design rules.
    """

    diameter_m: float = 3.0e-3
    gravity_m_per_s2: float = 9.81
    major_bifurcation: MajorBifurcationParams = dataclasses.field(default_factory=MajorBifurcationParams)
    network: str = ""

    def __post_init__(self) -> None:
        check_positive("diameter_m", self.diameter_m)
        check_nonnegative("gravity_m_per_s2", self.gravity_m_per_s2)
        # the network file itself is checked where it is read (vesselbot_ros.vessels.network.load_network,
        # called by the scenario's checks and vessels.cfd.packed_params): VesselParams never reads it
        if self.network and self.major_bifurcation.enabled:
            raise ConfigError("major_bifurcation.enabled must be false with a network (its bifurcations are in "
                              f"the geometry), got network={self.network!r}")


@dataclasses.dataclass(frozen=True)
class RobotParams:
    """Spherical robot: magnetic aggregate in a polymer binder (Table III).

    Attributes:
        radius_m: r (m). Table III: 250e-6.
        magnetic_ratio: tau_m = V_m / V (-), in (0, 1]. Table III: 0.8.
        magnetic_density_kg_per_m3: rho_m (kg/m^3). Table III: 7874 (iron).
        polymer_density_kg_per_m3: rho_poly (kg/m^3). Table III: 1500.
        magnetization_A_per_m: Saturation magnetisation M (A/m). Table III: 1.72e6.
        young_modulus_Pa: E_c (Pa). Table III: 1e9.
        poisson_ratio: sigma_c (-). Table III: 0.27.
        charge_C: Robot charge q (C); ``None`` = Hays' maximum allowable charge [33],
            q = 1e-6 * 4 pi r^2 * 30 * (100 r)^-0.3 with r in m.
        charge_scale: Multiplier on q (-) (sensitivity studies).
    """

    radius_m: float = 250.0e-6
    magnetic_ratio: float = 0.8
    magnetic_density_kg_per_m3: float = 7874.0
    polymer_density_kg_per_m3: float = 1500.0
    magnetization_A_per_m: float = 1.72e6
    young_modulus_Pa: float = 1.0e9
    poisson_ratio: float = 0.27
    charge_C: float | None = None
    charge_scale: float = 1.0

    def __post_init__(self) -> None:
        check_positive("radius_m", self.radius_m)
        check_range("magnetic_ratio", self.magnetic_ratio, 0.0, 1.0, lo_open=True)
        check_positive("magnetic_density_kg_per_m3", self.magnetic_density_kg_per_m3)
        check_positive("polymer_density_kg_per_m3", self.polymer_density_kg_per_m3)
        check_nonnegative("magnetization_A_per_m", self.magnetization_A_per_m)
        check_positive("young_modulus_Pa", self.young_modulus_Pa)
        check_range("poisson_ratio", self.poisson_ratio, -1.0, 0.5, lo_open=True, hi_open=True)
        if self.charge_C is not None:
            check_nonnegative("charge_C", self.charge_C)
        check_nonnegative("charge_scale", self.charge_scale)

    @property
    def density_kg_per_m3(self) -> float:
        """rho = tau_m rho_m + (1 - tau_m) rho_poly (kg/m^3), below eq. (14)."""
        t = self.magnetic_ratio
        return t * self.magnetic_density_kg_per_m3 + (1.0 - t) * self.polymer_density_kg_per_m3

    @property
    def volume_m3(self) -> float:
        """V = 4/3 pi r^3 (m^3)."""
        return float(sphere_volume(self.radius_m))

    @property
    def mass_kg(self) -> float:
        """m = rho V (kg)."""
        return self.density_kg_per_m3 * self.volume_m3


@dataclasses.dataclass(frozen=True)
class WallParams:
    """Vessel wall mechanics for the Hertz contact, eqs. (15)-(16).

    Attributes:
        young_modulus_Pa: E_w (Pa). Table III: 1e9.
        poisson_ratio: sigma_w (-). Table III: 0.2.
        unloading_exponent: Exponent of the unloading law (16) (-); the paper
            says it lies in [1.5, 2.5] (it calls it q, and p in the equation).
        permanent_deformation_ratio: delta_0 / delta_max after a loading phase
            (-), in [0, 1).  The paper gives no value; 0 makes unloading elastic.
    """

    young_modulus_Pa: float = 1.0e9
    poisson_ratio: float = 0.2
    unloading_exponent: float = 2.0
    permanent_deformation_ratio: float = 0.1

    def __post_init__(self) -> None:
        check_positive("young_modulus_Pa", self.young_modulus_Pa)
        check_range("poisson_ratio", self.poisson_ratio, -1.0, 0.5, lo_open=True, hi_open=True)
        check_range("unloading_exponent", self.unloading_exponent, 1.5, 2.5)
        check_range("permanent_deformation_ratio", self.permanent_deformation_ratio, 0.0, 1.0, hi_open=True)


@dataclasses.dataclass(frozen=True)
class InteractionParams:
    """Robot-wall interactions: van der Waals (17)-(18), electrostatic (19), steric (22).

    Attributes:
        hamaker_constant_J: A_h (J). Table III: 4e-19.
        vdw_min_separation: How the gap at which the vdW force (18) is floored
            (held constant) is chosen.  ``'brush_limited'`` (sound default):
            ``brush_compressed_fraction * brush_length_m`` (0.2 L0 = 20 nm for
            Table III): the grafted polymer brush cannot be compressed below
            about 0.2 L0 (the lower validity bound of eq. (20)), so the robot's
            core never comes closer to the endothelium than that.
            ``'explicit'``: ``vdw_min_separation_m`` (the paper does not
            specify a value; 0.4 nm is the bare atomic contact distance, at
            which the adhesion, ~1e-4 N, traps the robot on the wall).
        vdw_min_separation_m: vdW floor used with ``vdw_min_separation: explicit`` (m).
        brush_compressed_fraction: Thickness of the fully compressed brush over
            L0 (-), in (0, 1]; 0.2 is the lower validity bound of eq. (20).
        electrostatic_model: ``'image_charge'`` (q^2 / (4 pi eps eps0 (2 s)^2), the
            true image force) or ``'paper_printed'`` (eq. (19), 4x larger).
        brush_length_m: Polymer brush equilibrium length L_0 (m). Table III: 100e-9.
        grafting_density_per_m2: Grafting density tau (chains/m^2). Not in the
            paper; see docs/physics.md for the choice.
        in_contact: ``'hold'``: while in contact (delta > 0) the interaction
            forces keep their value at zero gap (continuous at delta = 0);
            ``'paper_heaviside'``: multiply by H(-delta) as printed (jump at 0).
    """

    hamaker_constant_J: float = 4.0e-19
    vdw_min_separation: Literal["brush_limited", "explicit"] = "brush_limited"
    vdw_min_separation_m: float = 0.4e-9
    brush_compressed_fraction: float = 0.2
    electrostatic_model: Literal["image_charge", "paper_printed"] = "image_charge"
    brush_length_m: float = 100.0e-9
    grafting_density_per_m2: float = 1.0e15
    in_contact: Literal["hold", "paper_heaviside"] = "hold"

    def __post_init__(self) -> None:
        check_nonnegative("hamaker_constant_J", self.hamaker_constant_J)
        check_choice("vdw_min_separation", self.vdw_min_separation, ("brush_limited", "explicit"))
        check_positive("vdw_min_separation_m", self.vdw_min_separation_m)
        check_range("brush_compressed_fraction", self.brush_compressed_fraction, 0.0, 1.0, lo_open=True)
        check_choice("electrostatic_model", self.electrostatic_model, ("image_charge", "paper_printed"))
        check_positive("brush_length_m", self.brush_length_m)
        check_nonnegative("grafting_density_per_m2", self.grafting_density_per_m2)
        check_choice("in_contact", self.in_contact, ("hold", "paper_heaviside"))

    @property
    def vdw_floor_m(self) -> float:
        """Gap (m) below which the vdW force is held constant (see ``vdw_min_separation``)."""
        if self.vdw_min_separation == "brush_limited":
            return self.brush_compressed_fraction * self.brush_length_m
        return self.vdw_min_separation_m


@dataclasses.dataclass(frozen=True)
class DragParams:
    """Wall-effect factor (10) of Kehlenbeck and Di Felice.

    Attributes:
        alpha0: alpha_0 (-). Paper: 1.5.
        lambda0: lambda_0 (-). Paper: 0.29.
    """

    alpha0: float = 1.5
    lambda0: float = 0.29

    def __post_init__(self) -> None:
        check_positive("alpha0", self.alpha0)
        check_positive("lambda0", self.lambda0)


@dataclasses.dataclass(frozen=True)
class PhysicsParams:
    """All parameters of the force model (eq. (1)), Table III small artery by default.

    ``kind`` is the plant's stage kind (:mod:`vesselbot_ros.sim.kinds`): ``vessel``.
    """

    blood: BloodParams = dataclasses.field(default_factory=BloodParams)
    flow: FlowParams = dataclasses.field(default_factory=FlowParams)
    vessel: VesselParams = dataclasses.field(default_factory=VesselParams)
    robot: RobotParams = dataclasses.field(default_factory=RobotParams)
    wall: WallParams = dataclasses.field(default_factory=WallParams)
    interactions: InteractionParams = dataclasses.field(default_factory=InteractionParams)
    drag: DragParams = dataclasses.field(default_factory=DragParams)
    kind: Literal["vessel"] = "vessel"

    def __post_init__(self) -> None:
        check_choice("kind", self.kind, ("vessel",))
        d_min = self.vessel.diameter_m * (1.0 - self.flow.diameter_pulsation)
        lam = 2.0 * self.robot.radius_m / d_min
        if lam >= 1.0:
            raise ConfigError(
                f"robot.radius_m must give lambda = 2 r / D_min < 1 "
                f"(D_min = vessel.diameter_m * (1 - flow.diameter_pulsation) = {d_min!r}), "
                f"got radius_m={self.robot.radius_m!r} (lambda = {lam:.4g})"
            )

    @property
    def diameter_ratio(self) -> float:
        """lambda = 2 r / D at the nominal diameter (-)."""
        return 2.0 * self.robot.radius_m / self.vessel.diameter_m

    def with_overrides(self, overrides: Mapping[str, Any]) -> PhysicsParams:
        """Return a re-validated copy with dotted-key overrides applied.

        Args:
            overrides: e.g. ``{"flow.centreline_velocity_m_per_s": 0.02625}``.

        Raises:
            ConfigError: unknown key or invalid value (named).
        """
        mapping = _every_field(self)  # with the keys to_mapping leaves out at their defaults (flow.inflow_fraction)
        flat = flatten(unflatten(dict(overrides)))  # nested or dotted, as model.overrides may be written
        for key in flat:
            node: Any = mapping
            for depth, part in enumerate(key.split(".")):
                if not isinstance(node, dict) or part not in node:
                    where = ".".join(key.split(".")[:depth])
                    allowed = sorted(node) if isinstance(node, dict) else []
                    raise ConfigError(f"unknown override key {key}; allowed {'keys of ' + where if where else 'sections'}"
                                      f": {allowed}")
                node = node[part]
        return load_dataclass(type(self), apply_overrides(mapping, flat), "physics")  # a plant kind's params subclass


def planar_twin(params: PhysicsParams) -> PhysicsParams:
    """``params`` without its network: the straight vessel of the same bead, blood and flow, whose packed head is
    what the kernel's scalars and the input matrix read (a network's or a 3-D tree's, packed without its field)."""
    return dataclasses.replace(params, vessel=dataclasses.replace(params.vessel, network=""))


def _every_field(obj: Any) -> Any:
    """:func:`~vesselbot_ros.config.to_mapping` of a params tree, keeping the fields it omits at their defaults."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _every_field(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    return to_mapping(obj)


@dataclasses.dataclass(frozen=True)
class DesignParams:
    """Actuation and tail design of the three motive schemes (Section III-A).

    Attributes:
        bp_gradient_T_per_m: Maximum gradient norm for bead pulling (T/m). 0.08.
        bp_field_T: Uniform MRI field B_0 for BP (T); saturates M. 3.
        rot_field_T: Rotating/oscillating field amplitude for EF/HT (T). 2e-3.
        rot_frequency_Hz: Field frequency omega / 2 pi for EF/HT (Hz). 30.
        n_turns: Helical turns n (-). 10.
        pitch_deg: Helix pitch angle phi (deg). 35.
        sperm_number: S_p of the elastic flagellum (-). 3.4.
        tail_radius_ratio: Filament radius over bead radius kappa / r (-), << 1.
        ef_tail_length: ``'helix_contour'``: L = 2 pi n r / sin(phi) (same filament
            length as the helix); ``'helix_axial'``: L = 2 pi n r / tan(phi).
        ef_base: Base condition of the torque-driven filament for Z(S_p):
            ``'hinged'`` (base pinned by the bead) or ``'free'``.
        ht_slowdown_in_load: Count the HT tail slow-down term of eq. (5) in
            F_tot (True) rather than subtracting it from F_m (False).
    """

    bp_gradient_T_per_m: float = 0.08
    bp_field_T: float = 3.0
    rot_field_T: float = 2.0e-3
    rot_frequency_Hz: float = 30.0
    n_turns: float = 10.0
    pitch_deg: float = 35.0
    sperm_number: float = 3.4
    tail_radius_ratio: float = 0.02
    ef_tail_length: Literal["helix_contour", "helix_axial"] = "helix_contour"
    ef_base: Literal["hinged", "free"] = "hinged"
    ht_slowdown_in_load: bool = True

    def __post_init__(self) -> None:
        check_positive("bp_gradient_T_per_m", self.bp_gradient_T_per_m)
        check_positive("bp_field_T", self.bp_field_T)
        check_positive("rot_field_T", self.rot_field_T)
        check_positive("rot_frequency_Hz", self.rot_frequency_Hz)
        check_positive("n_turns", self.n_turns)
        check_range("pitch_deg", self.pitch_deg, 0.0, 90.0, lo_open=True, hi_open=True)
        check_range("sperm_number", self.sperm_number, 3.4, 1.0e3)
        check_range("tail_radius_ratio", self.tail_radius_ratio, 0.0, 0.2, lo_open=True)
        check_choice("ef_tail_length", self.ef_tail_length, ("helix_contour", "helix_axial"))
        check_choice("ef_base", self.ef_base, ("hinged", "free"))
