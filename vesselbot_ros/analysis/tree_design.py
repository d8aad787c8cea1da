"""Design for a vessel tree: which branches a scanner can reach, with which bead and under which flow, and why not.

The Fig. 7 design maps ask, for one vessel, which bead the coil can hold.  In a
tree the question is per outlet: for a scanner preset's coil and sequence and a
tree scenario (its start point), plan the route to each outlet
(:mod:`vesselbot_ros.analysis.plan`: a reference re-timed so that the coil
holds the bead, riding the flow where no slower pace can) for every bead
(radius x material, :data:`~vesselbot_ros.analysis.plan_design.MATERIALS`) and
every flow condition:

* ``table3``: the scenario's own flow (the paper's Table III);
* ``<preset>``: a physiological flow preset of the tree's file (``physics.flow.preset``, docs/vessels.md);
* ``<preset>@<fraction>``: that preset with the inflow reduced to ``fraction`` (``physics.flow.inflow_fraction``:
  a balloon catheter upstream).

A cell is flyable (the plan's time and its least margin) or not, with the
planner's reason: the segment no reference can fly within the coil's budget
and the acceleration missing (:class:`~vesselbot_ros.analysis.plan.PlanInfeasible`);
a bead that does not fit, or a flow the tree's file does not have, is a cell
with its one line too.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from typing import Any

from vesselbot_ros.analysis.plan import PlanInfeasible, PlanOptions, make_plan
from vesselbot_ros.analysis.plan_design import MATERIALS
from vesselbot_ros.config import ConfigError
from vesselbot_ros.errors import VesselbotError
from vesselbot_ros.sim.scenario import Scenario, scenario_with

__all__ = ["TABLE3", "TreeCell", "flow_changes", "tree_design", "tree_rows"]

#: The flow condition that keeps the scenario's own flow.
TABLE3 = "table3"


@dataclasses.dataclass(frozen=True)
class TreeCell:
    """One (outlet, bead, flow) of the design: its plan, or why there is none."""

    outlet: str
    radius_m: float
    material: str
    flow: str
    status: str  # "ok" or the one line that says why not
    end_s: float = math.nan
    margin_m_per_s2: float = math.nan
    missing_m_per_s2: float = math.nan


def flow_changes(flow: str) -> dict[str, Any]:
    """The dotted scenario changes of a flow condition (module docstring).

    Raises:
        ConfigError: a malformed ``<preset>@<fraction>`` (one line naming it).
    """
    if flow == TABLE3:
        return {}
    name, sep, frac = flow.partition("@")
    out: dict[str, Any] = {"physics.flow.preset": name}
    if sep:
        try:
            f = float(frac)
        except ValueError:
            raise ConfigError(f"flow condition {flow!r}: the inflow fraction after '@' must be a number") from None
        if not (math.isfinite(f) and 0.0 <= f <= 1.0):
            raise ConfigError(f"flow condition {flow!r}: the inflow fraction must be in [0, 1], got {frac!r}")
        out["physics.flow.inflow_fraction"] = f
    return out


def _bead(material: str, radius_m: float) -> dict[str, Any]:
    m = MATERIALS[material]
    return {"physics.robot.radius_m": float(radius_m), "physics.robot.magnetic_ratio": m.magnetic_ratio,
            "physics.robot.magnetic_density_kg_per_m3": m.magnetic_density_kg_per_m3,
            "physics.robot.polymer_density_kg_per_m3": m.polymer_density_kg_per_m3,
            "physics.robot.magnetization_A_per_m": m.magnetization_A_per_m}


def tree_design(base: Scenario, outlets: Sequence[str], radii_m: Iterable[float], materials: Sequence[str],
                flows: Sequence[str], options: PlanOptions | None = None) -> list[TreeCell]:
    """Plan the route to every outlet for every bead and flow condition (module docstring).

    Raises:
        ConfigError: ``base`` is not a network scenario, an outlet or a material is unknown (one line).
    """
    if not base.physics.vessel.network:
        raise ConfigError("the tree design needs a network scenario (physics.vessel.network), got a straight vessel")
    for m in materials:
        if m not in MATERIALS:
            raise ConfigError(f"material must be one of {sorted(MATERIALS)}, got {m!r}")
    radii = [float(r) for r in radii_m]
    out = []
    for outlet in outlets:
        for flow in flows:
            for material in materials:
                for r in radii:
                    # the route to this outlet, re-planned from scratch (a planned scenario's timing, anchors and
                    # wall-follow weights are its own route's)
                    changes = {"reference.route_outlet": outlet, "reference.route_anchors": "planned",
                               "reference.timing": "constant", "reference.planned_t_s": [],
                               "reference.planned_u_m": [], "reference.wall_follow": [],
                               **flow_changes(flow), **_bead(material, r)}
                    try:
                        scenario = scenario_with(base, changes)
                        plan = make_plan(scenario, options)
                    except PlanInfeasible as exc:
                        out.append(TreeCell(outlet, r, material, flow, str(exc), missing_m_per_s2=exc.missing_m_per_s2))
                        continue
                    except VesselbotError as exc:  # a bead that does not fit, a preset the file lacks: its line
                        out.append(TreeCell(outlet, r, material, flow, str(exc)))
                        continue
                    out.append(TreeCell(outlet, r, material, flow, "ok", plan.end_s, plan.margin_m_per_s2))
    return out


def tree_rows(cells: Sequence[TreeCell]) -> list[dict[str, Any]]:
    """The cells as table rows (SI units)."""
    return [dataclasses.asdict(c) for c in cells]
