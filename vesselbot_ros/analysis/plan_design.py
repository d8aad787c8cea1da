"""Design for the scanner: which bead makes a path flyable on a given scanner, and with what floor.

The Fig. 7 design maps of the paper assume continuous propulsion.  On a
scanner the coil propels only in its propulsion windows, so the question
becomes: for this preset's coil and sequence and this vessel, which bead
(radius, material) gives a plan the coil can fly (:mod:`vesselbot_ros.analysis.plan`),
where in the lumen, and with what coast floor?  :func:`design_grid` plans
every (radius, material) of a grid on the scenario's path; an infeasible
cell keeps the planner's reason (the segment and the acceleration missing).

Materials (:data:`MATERIALS`): the paper's composite bead (Table III) and
four magnetic materials at saturation, with handbook densities and
saturation magnetisations (ours; a real bead's coating and shape change them).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence
from typing import Any

from vesselbot_ros.analysis.plan import PlanInfeasible, PlanOptions, make_plan
from vesselbot_ros.config import ConfigError
from vesselbot_ros.sim.scenario import Scenario

__all__ = ["Material", "MATERIALS", "DesignCell", "bead_scenario", "design_grid"]


@dataclasses.dataclass(frozen=True)
class Material:
    """A bead's magnetic material: share of magnetic volume, densities, magnetisation at saturation."""

    magnetic_ratio: float
    magnetic_density_kg_per_m3: float
    polymer_density_kg_per_m3: float
    magnetization_A_per_m: float
    source: str


MATERIALS: dict[str, Material] = {
    "paper": Material(0.8, 7874.0, 1500.0, 1.72e6, "Table III: 80 % iron-like core in a polymer"),
    "steel_1010": Material(1.0, 7850.0, 1500.0, 1.5e6, "ours: low-carbon steel, about 1.9 T at saturation"),
    "iron": Material(1.0, 7874.0, 1500.0, 1.71e6, "ours: pure iron, 2.15 T at saturation"),
    "permendur": Material(1.0, 8120.0, 1500.0, 1.91e6, "ours: FeCo 49/49/2, 2.4 T at saturation"),
    "magnetite_50": Material(0.5, 5170.0, 1500.0, 4.8e5, "ours: 50 % magnetite (0.6 T) in a polymer"),
}


@dataclasses.dataclass(frozen=True)
class DesignCell:
    """One bead's plan on the scenario's path (or why there is none)."""

    radius_m: float
    material: str
    status: str  # "ok" or the planner's one line
    where: str = ""  # "lower wall" or "free lumen"
    end_s: float = float("nan")
    margin_m_per_s2: float = float("nan")
    coast_floor_m: float = float("nan")
    missing_m_per_s2: float = float("nan")


def bead_scenario(base: Scenario, radius_m: float, material: str) -> Scenario:
    """``base`` with this bead; the start and the anchors kept 50 um inside the lumen it leaves (bigger beads).

    Raises:
        ConfigError: an unknown material, or a bead that does not fit the vessel.
    """
    if material not in MATERIALS:
        raise ConfigError(f"material must be one of {sorted(MATERIALS)}, got {material!r}")
    m = MATERIALS[material]
    ph = base.physics
    half = 0.5 * ph.vessel.diameter_m * (1.0 - ph.flow.diameter_pulsation) - radius_m - 50e-6
    if half <= 0.0:
        raise ConfigError(f"radius_m {radius_m!r} does not fit the vessel (diameter {ph.vessel.diameter_m!r} m)")
    robot = dataclasses.replace(ph.robot, radius_m=radius_m, magnetic_ratio=m.magnetic_ratio,
                                magnetic_density_kg_per_m3=m.magnetic_density_kg_per_m3,
                                polymer_density_kg_per_m3=m.polymer_density_kg_per_m3,
                                magnetization_A_per_m=m.magnetization_A_per_m)

    def clip(z: float) -> float:
        return max(-half, min(half, z))

    ref = dataclasses.replace(base.reference, anchors_z_m=tuple(clip(z) for z in base.reference.anchors_z_m))
    p0 = (base.initial.p0_m[0], clip(base.initial.p0_m[1]))
    return dataclasses.replace(base, physics=dataclasses.replace(ph, robot=robot), reference=ref,
                               initial=dataclasses.replace(base.initial, p0_m=p0))


def design_grid(base: Scenario, radii_m: Iterable[float], materials: Sequence[str],
                options: PlanOptions | None = None) -> list[DesignCell]:
    """Plan every (radius, material) on ``base``'s path, coil and sequence (module docstring)."""
    out = []
    for material in materials:
        for r in radii_m:
            scenario = bead_scenario(base, float(r), material)
            try:
                plan = make_plan(scenario, options)
            except PlanInfeasible as exc:
                out.append(DesignCell(float(r), material, str(exc), missing_m_per_s2=exc.missing_m_per_s2))
                continue
            wall = any(s.mode != "free" for s in plan.segments)
            out.append(DesignCell(float(r), material, "ok", "lower wall" if wall else "free lumen", plan.end_s,
                                  plan.margin_m_per_s2, plan.coast_floor_m))
    return out


def rows(cells: Sequence[DesignCell]) -> list[dict[str, Any]]:
    """The cells as table rows (SI units)."""
    return [dataclasses.asdict(c) for c in cells]
