"""Closed-loop scenario: every parameter of one run, loaded strictly from YAML.

A :class:`Scenario` bundles the true physics, the controller's model of it,
the coil limits, the imager, the observer, the controller, the reference, the
initial conditions and the simulation settings.  ``load_scenario(path)`` goes
through :func:`vesselbot_ros.config.load_dataclass`, so unknown keys, wrong
types and out-of-range values raise :class:`~vesselbot_ros.config.ConfigError`
naming the dotted key and the value.  ROS nodes load the same mapping (or its
flattened parameters, see :func:`vesselbot_ros.config.flatten`) with
:func:`scenario_from_mapping`.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import sys
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, Literal

import numpy as np

from vesselbot_ros.config import (
    RESOLVE_TYPE,
    ConfigError,
    apply_overrides,
    check_choice,
    check_finite,
    check_nonnegative,
    check_positive,
    flatten,
    load_dataclass,
    load_yaml,
    parse_set_items,
    resolve_config_path,
    shipped_config_dir,
    to_mapping,
    unflatten,
)
from vesselbot_ros.control.backstepping import ControllerParams
from vesselbot_ros.control.bspline_reference import ReferenceParams
from vesselbot_ros.control.high_gain_observer import ObserverParams
from vesselbot_ros.control.route import planned_reference
from vesselbot_ros.imaging.imager_params import MrImagerParams, TrackerParams
from vesselbot_ros.physics.axes import AXES
from vesselbot_ros.physics.integrator import IntegratorParams
from vesselbot_ros.physics.params import FlowParams, PhysicsParams
from vesselbot_ros.resources import fmt_bytes, memory_budget_bytes
from vesselbot_ros.scanner.actuator_limits import CoilLimits
from vesselbot_ros.scanner.hardware import DbdtLimit, preset_changes
from vesselbot_ros.scanner.imager_model import ImagerParams
from vesselbot_ros.scanner.sequence import SequenceParams
from vesselbot_ros.sim.kinds import ROLES, SECTIONS, find, params_type, section_resolver, switch_sections
from vesselbot_ros.vessels.cfd import network_wall
from vesselbot_ros.vessels.network import load_network, network_dims, require_planar, route_to_outlet
from vesselbot_ros.vessels.tube_geometry import NetworkGeometry

__all__ = [
    "ModelParams",
    "InitialConditions",
    "IntegratorParams",
    "SimParams",
    "Scenario",
    "load_scenario",
    "load_scenario_mapping",
    "merge_scenario_mappings",
    "defaults_taken",
    "defaults_note",
    "BASE_KEY",
    "overridden",
    "with_overrides",
    "scenario_with",
    "scenario_from_mapping",
    "with_flow_preset_values",
    "short_copy",
    "scenario_overrides",
    "estimate_resources",
    "check_resources",
    "BYTES_PER_TICK",
    "BAG_BYTES_PER_TICK",
    "RECORDING_HEADROOM_BYTES",
    "shipped_scenarios",
    "SCENARIO_DIR",
    "DEFAULT_SCENARIO",
]

# What one control tick costs: the runner's and the launcher's per-tick time
# series (about 30 float64 columns plus flags) and the temporaries of the
# metrics, rounded up; with ``sim.record_forces`` the (8, 2) force terms.
BYTES_PER_TICK = 512
FORCE_BYTES_PER_TICK = 8 * 2 * 8
# What one tick adds to a recorded bag (about 120 MB for 60 s at 1 kHz).
BAG_BYTES_PER_TICK = 2048
#: Free space a recorded run needs besides its bag (bytes): the node logs, the bag's metadata and a report's
#: six figures (vesselbot_ros.bag.report.REPORT_BYTES is 8 MiB of it).
RECORDING_HEADROOM_BYTES = 16 * 2**20


@dataclasses.dataclass(frozen=True)
class ModelParams:
    """The controller's and observer's model of the plant.

    Attributes:
        overrides: Physics overrides (nested mapping, same keys as
            ``physics``) that make the model differ from the truth, e.g.
            ``{flow: {centreline_velocity_m_per_s: 0.02625}}`` for the paper's
            5 % blood-velocity error.  Empty = exact model.
        input_mapping: How ``U`` (m/s^2) maps to the gradient (T/m):
            ``with_tau_m``: ``U = tau_m M / rho * G`` (force of eq. (2) over the
            mass ``rho V``, physically consistent);
            ``paper_printed``: ``U = M / rho * G`` as printed below eq. (23)
            (omits ``tau_m``: the controller overestimates its authority by
            ``1 / tau_m = 1.25``).
    """

    overrides: dict[str, Any] = dataclasses.field(default_factory=dict)
    input_mapping: Literal["with_tau_m", "paper_printed"] = "with_tau_m"

    def __post_init__(self) -> None:
        check_choice("input_mapping", self.input_mapping, ("with_tau_m", "paper_printed"))
        if not isinstance(self.overrides, dict):
            raise ConfigError(f"overrides must be a mapping, got {self.overrides!r}")


@dataclasses.dataclass(frozen=True)
class InitialConditions:
    """Initial state (Table III: ``X0 = (0, 0.001)``, ``Z0 = (0, 0)``).

    Attributes:
        p0_m: (x, z) initial true position (m); (x, y, z) in a 3-D vessel tree (``Scenario.dims``).
        v0_m_per_s: (x, z) initial true velocity (m/s); (x, y, z) in a 3-D tree.
        z_hat0_m_per_s: (x, z) observer's prior velocity (m/s); (x, y, z) in a 3-D tree.
    """

    p0_m: tuple[float, ...] = (0.0, 1e-3)
    v0_m_per_s: tuple[float, ...] = (0.0, 0.0)
    z_hat0_m_per_s: tuple[float, ...] = (0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("p0_m", "v0_m_per_s", "z_hat0_m_per_s"):
            vals = getattr(self, name)
            if len(vals) not in (2, 3):
                raise ConfigError(f"{name} must have 2 values (x, z) or 3 (x, y, z, in a 3-D vessel tree), got {list(vals)}")
            for i, v in enumerate(vals):
                check_finite(f"{name}[{i}]", v)


@dataclasses.dataclass(frozen=True)
class SimParams:
    """Simulation settings.

    Attributes:
        duration_s: Simulated time (s). Paper (Fig. 9): 2.
        control_rate_Hz: Control (tick) rate (Hz); the plant sub-steps inside
            each period.
        metrics_after_s: Start of the steady-state metric window (s). Paper: 0.6.
        record_forces: Record the force breakdown at every tick (slower).
        integrator: Plant integrator settings.
    """

    duration_s: float = 2.0
    control_rate_Hz: float = 1000.0
    metrics_after_s: float = 0.6
    record_forces: bool = False
    integrator: IntegratorParams = dataclasses.field(default_factory=IntegratorParams)

    def __post_init__(self) -> None:
        check_positive("duration_s", self.duration_s)
        check_positive("control_rate_Hz", self.control_rate_Hz)
        check_nonnegative("metrics_after_s", self.metrics_after_s)
        ticks = self.duration_s * self.control_rate_Hz
        if ticks < 2:
            raise ConfigError(
                f"control_rate_Hz must give at least 2 control ticks in duration_s={self.duration_s!r} s, "
                f"got {self.control_rate_Hz!r} ({ticks:.3g} ticks)"
            )

    @property
    def dt_control_s(self) -> float:
        """Control period (s)."""
        return 1.0 / self.control_rate_Hz

    @property
    def n_ticks(self) -> int:
        """Number of control ticks ``k = 0 .. n-1`` (``t_k = k / rate``)."""
        return int(math.floor(self.duration_s * self.control_rate_Hz + 1e-9))


def _stage_section(role: str) -> dict[str, Any]:
    """A stage section's field metadata: its dataclass is the one of the kind its ``kind`` key names (:mod:`vesselbot_ros.sim.kinds`)."""
    return {RESOLVE_TYPE: section_resolver(role)}


@dataclasses.dataclass(frozen=True)
class Scenario:
    """Everything one closed-loop run needs (see ``config/*.yaml``).

    Attributes:
        name: Scenario name (used for output paths).
        seed: Seed of the imager's ``numpy.random.Generator``.
        physics: True physics (the plant).
        model: The controller's and observer's model (overrides, input mapping).
        coil: Gradient-coil limits.
        imager: Imager model.
        tracker: The tracker of an imager that delivers MR frames (``mr_images``): unused otherwise.
        observer: High-gain observer.
        controller: Backstepping controller.
        reference: Reference trajectory.

    The sections of the seven stages (physics for the plant, imager, tracker,
    observer, reference, controller, coil) each name their stage's ``kind``; the
    annotated classes are the built-in kinds' parameters, and a section of
    another kind (a user's ``module:Class``) holds that kind's parameters
    (:mod:`vesselbot_ros.sim.kinds`).
        initial: Initial conditions.
        sim: Simulation settings.
        sequence: The scanner's imaging/propulsion sequence (``continuous``:
            the paper's loop; ``multiplexed``: tracking and propulsion windows).
        dbdt: The coil's dB/dt (peripheral nerve stimulation) limit, as a
            slew limit (``mode: off``, the default: the coil's slew only).
    """

    name: str = "scenario"
    seed: int = 0
    physics: PhysicsParams = dataclasses.field(default_factory=PhysicsParams, metadata=_stage_section("plant"))
    model: ModelParams = dataclasses.field(default_factory=ModelParams)
    coil: CoilLimits = dataclasses.field(default_factory=CoilLimits, metadata=_stage_section("coil"))
    imager: ImagerParams = dataclasses.field(default_factory=ImagerParams, metadata=_stage_section("imager"))
    tracker: TrackerParams = dataclasses.field(default_factory=TrackerParams, metadata=_stage_section("tracker"))
    observer: ObserverParams = dataclasses.field(default_factory=ObserverParams, metadata=_stage_section("observer"))
    controller: ControllerParams = dataclasses.field(default_factory=ControllerParams, metadata=_stage_section("controller"))
    reference: ReferenceParams = dataclasses.field(default_factory=ReferenceParams, metadata=_stage_section("reference"))
    initial: InitialConditions = dataclasses.field(default_factory=InitialConditions)
    sim: SimParams = dataclasses.field(default_factory=SimParams)
    sequence: SequenceParams = dataclasses.field(default_factory=SequenceParams)
    dbdt: DbdtLimit = dataclasses.field(default_factory=DbdtLimit)

    def __post_init__(self) -> None:
        if not self.name or not all(c.isalnum() or c in "_-." for c in self.name):
            raise ConfigError(f"name must be non-empty and use only letters, digits, '_', '-', '.', got {self.name!r}")
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed!r}")
        # the checks below read the built-in kinds' parameters; a user's kind checks its own in its params class
        mri = isinstance(self.imager, ImagerParams)
        if isinstance(self.imager, (ImagerParams, MrImagerParams)) and (
                self.imager.frame_rate_Hz > self.sim.control_rate_Hz * (1.0 + 1e-9)):
            raise ConfigError(
                f"imager.frame_rate_Hz must be <= sim.control_rate_Hz ({self.sim.control_rate_Hz!r}), "
                f"got {self.imager.frame_rate_Hz!r}"
            )
        if self.sequence.mode == "multiplexed":
            if mri and self.imager.latency_s != 0.0:
                raise ConfigError(f"imager.latency_s must be 0 with sequence.mode 'multiplexed' (the sequence's "
                                  f"latency_s applies), got {self.imager.latency_s!r}")
            if self.sequence.tracking_window_s < self.sim.dt_control_s - 1e-12:
                raise ConfigError(f"sequence.tracking_window_s must be >= one control tick ({self.sim.dt_control_s!r} s), "
                                  f"got {self.sequence.tracking_window_s!r}")
            _check_on_tick_grid(self.sequence, self.sim.dt_control_s)
            _check_fits_run(self.sequence, self.sim.duration_s)
        elif mri and self.imager.latency_s >= self.sim.duration_s:
            raise ConfigError(f"imager.latency_s must be < sim.duration_s ({self.sim.duration_s!r} s): no frame would "
                              f"reach the observer within the run, got {self.imager.latency_s!r}")
        for role in ROLES:  # each kind's own rules across the sections (StageKind.check: observer (25)'s frame rate)
            section = getattr(self, SECTIONS[role])
            check = find(role, section.kind).check
            if check is not None:
                check(section, self)
        bspline = isinstance(self.reference, ReferenceParams)
        # the axis count and the model's physics are read once, here (every builder and check asks these)
        object.__setattr__(self, "_dims", network_dims(self.physics.vessel.network))
        d = self.dims
        for name in ("p0_m", "v0_m_per_s", "z_hat0_m_per_s"):
            vals = getattr(self.initial, name)
            if len(vals) != d:
                raise ConfigError(f"initial.{name} must have {d} values ({', '.join(AXES[d])}: the vessel is "
                                  f"{'a 3-D tree' if d == 3 else 'planar'}), got {list(vals)}")
        if bspline and self.reference.anchors_y_m and "y" not in AXES[d]:  # a planar scenario pins y
            raise ConfigError(f"reference.anchors_y_m: a path in three dimensions needs a 3-D vessel tree "
                              f"(physics.vessel.network giving y_m); this vessel is planar (XZ), "
                              f"got anchors_y_m={list(self.reference.anchors_y_m)}")
        if self.physics.vessel.network:
            self._check_network(bspline)
        elif bspline and self.reference.route_outlet:
            raise ConfigError(f"reference.route_outlet needs physics.vessel.network, got route_outlet={self.reference.route_outlet!r}")
        if self.physics.flow.preset and not self.physics.vessel.network:
            raise ConfigError(f"physics.flow.preset needs physics.vessel.network (a preset is a vessel network's), "
                              f"got preset={self.physics.flow.preset!r}")
        half_d = 0.5 * self.physics.vessel.diameter_m
        for i, z in (() if self.physics.vessel.network or not bspline else enumerate(self.reference.anchors_z_m)):
            if abs(z) >= half_d:
                raise ConfigError(f"reference.anchors_z_m[{i}] must lie inside the vessel (|z| < {half_d!r}), got {z!r}")
        if not self.physics.vessel.network and abs(self.initial.p0_m[1]) >= half_d:
            raise ConfigError(f"initial.p0_m[1] must lie inside the vessel (|z| < {half_d!r}), got {self.initial.p0_m[1]!r}")
        try:  # model.overrides merged once: model_physics() hands out this object
            model = self.physics.with_overrides(self.model.overrides) if self.model.overrides else self.physics
        except ConfigError as exc:
            raise ConfigError(f"model.overrides: {exc}") from None
        object.__setattr__(self, "_model_physics", model)

    @property
    def dims(self) -> int:
        """3 when ``physics.vessel.network`` is a 3-D tree (its file gives ``y_m``): the loop runs on (x, y, z);
        else 2, the paper's plane (x, z).  Read once, at validation (a network that does not load counts as
        planar there; its own check names the cause)."""
        return int(self.__dict__["_dims"])

    def _check_network(self, bspline: bool) -> None:
        """Start point and anchors (given or planned; ``bspline``: the built-in reference) must lie inside the lumen."""
        try:
            net = load_network(self.physics.vessel.network)
            if not net.is_3d:  # the vessel kind's edge: a planar network, or a tree checked below
                require_planar(net, "the 2-D plant")
        except ConfigError as exc:
            raise ConfigError(f"physics.vessel.network: {exc}") from None
        flow = self.physics.flow
        if flow.preset:  # scenario_from_mapping wrote its values; a scenario built otherwise must hold them too
            for k, v in net.flow_preset(flow.preset).flow_values().items():
                if getattr(flow, k) != v:
                    raise ConfigError(f"physics.flow.{k}={getattr(flow, k)!r} is not flow preset {flow.preset!r}'s "
                                      f"{v!r} (the preset sets it: build the scenario with scenario_from_mapping)")
        if net.is_3d:
            self._check_tree(net, bspline)
            return
        if bspline and self.reference.route_outlet:
            if self.reference.route_outlet not in net.outlets:
                raise ConfigError(f"reference.route_outlet must be an outlet of network {net.name!r} "
                                  f"({net.outlets}), got {self.reference.route_outlet!r}")
            route_to_outlet(net, self.reference.route_outlet)
        # the meshed wall the plant sees (exact in the junctions, where the centreline tubes are a lower bound)
        geom = network_wall(net, self.physics.blood)
        s0 = float(geom.query(np.asarray(self.initial.p0_m))["sdist"][0])
        if s0 <= 0.0:
            raise ConfigError(f"initial.p0_m must lie inside the vessel network {net.name!r}, got {list(self.initial.p0_m)} "
                              f"({-s0:.6g} m outside the wall)")
        if not bspline:
            return
        ref = planned_reference(self)
        sd = geom.query(np.column_stack([ref.anchors_x_m, ref.anchors_z_m]))["sdist"]
        for i, v in enumerate(sd):
            if v <= 0.0:
                raise ConfigError(f"reference anchor {i} ({ref.anchors_x_m[i]!r}, {ref.anchors_z_m[i]!r}) must lie inside the "
                                  f"vessel network {net.name!r} ({-v:.6g} m outside the wall)")

    def _check_tree(self, net: Any, bspline: bool) -> None:
        """:meth:`_check_network` in a 3-D tree, against its centreline tubes (the meshed wall's lumen is theirs
        up to the mesh's facets and the junctions' fillets; building its exact query costs tens of seconds)."""
        if bspline and self.reference.route_outlet:
            if self.reference.route_outlet not in net.outlets:
                raise ConfigError(f"reference.route_outlet must be an outlet of network {net.name!r} "
                                  f"({net.outlets}), got {self.reference.route_outlet!r}")
            route_to_outlet(net, self.reference.route_outlet)
        geom = NetworkGeometry(net, dims=3)
        s0 = float(geom.query(np.asarray(self.initial.p0_m))["sdist"][0])
        if s0 <= 0.0:
            raise ConfigError(f"initial.p0_m must lie inside the vessel network {net.name!r}, got {list(self.initial.p0_m)} "
                              f"({-s0:.6g} m outside the wall)")
        if not bspline:
            return
        pts = planned_reference(self).anchor_points()
        if pts.shape[1] != 3:
            raise ConfigError("reference.anchors_y_m must be given in a 3-D vessel tree (or reference.route_outlet set)")
        sd = geom.query(pts)["sdist"]
        for i, v in enumerate(sd):
            if v <= 0.0:
                raise ConfigError(f"reference anchor {i} {pts[i].tolist()} must lie inside the vessel network {net.name!r} "
                                  f"({-v:.6g} m outside the wall)")

    def model_physics(self) -> PhysicsParams:
        """The controller's physics: ``physics`` with ``model.overrides`` applied (merged once, at validation)."""
        model: PhysicsParams = self.__dict__["_model_physics"]
        return model

    def to_mapping(self) -> dict[str, Any]:
        """Plain YAML-able mapping; ``scenario_from_mapping`` inverts it."""
        out: dict[str, Any] = to_mapping(self)
        return out


def _check_on_tick_grid(seq: SequenceParams, dt: float) -> None:
    """Window edges and frame stamps of a multiplexed sequence fall on control ticks.

    A frame is stamped at its tracking window's middle, and the graph's nodes
    recover every stamp as a tick (``graph_spec.tick_of_ns``): an off-tick
    stamp would be refused by the observer node while the ROS-free runner
    used it.  So the start, the windows and the dead time are whole ticks, and
    the tracking window an even number of them.
    """
    for name, value, mult in (("start_s", seq.start_s, 1), ("tracking_window_s", seq.tracking_window_s, 2),
                              ("dead_time_s", seq.dead_time_s, 1), ("propulsion_window_s", seq.propulsion_window_s, 1)):
        n = value / (mult * dt)
        if abs(n - round(n)) > 1e-6:
            what = "an even number of control ticks (its middle stamps the frame)" if mult == 2 else "whole control ticks"
            raise ConfigError(f"sequence.{name} must be {what} of {dt!r} s with sequence.mode 'multiplexed', got {value!r}")


def _check_fits_run(seq: SequenceParams, duration_s: float) -> None:
    """A multiplexed sequence's first frame reaches the observer, and its first propulsion window opens, in the run.

    A latency or a window longer than the run would leave the loop without a
    measurement or without propulsion: every command refuses such a scenario
    (``simulate``, ``run``, ``plan``, ``campaign`` and the scanner study load
    it here).  The message names the key, its value and the run's duration.

    The other times that may exceed the run are harmless, and accepted: a run
    shorter than them is the same loop as the first seconds of a longer run
    (``--duration`` makes such a prefix of every shipped scenario):
    ``coil.command_timeout_s`` and ``controller.stale_timeout_s`` (the
    watchdog and the safe action then never fire, as in that prefix; the coil
    still ramps a rejected command to zero from its tick), an imager outlier
    burst or dropout window that starts after the run (never reached), an
    imager frame period longer than the run in continuous mode (the frame at
    t = 0, then the observer predicts), and ``sim.metrics_after_s`` (the
    metrics cover the whole run and say so, ``metrics_window_note``).  In
    continuous mode the sequence's windows and latency are unused.
    """
    run = f"sim.duration_s ({duration_s!r} s)"
    for name, value in (("latency_s", seq.latency_s), ("tracking_window_s", seq.tracking_window_s),
                        ("start_s", seq.start_s)):
        if value >= duration_s:
            raise ConfigError(f"sequence.{name} must be < {run} with sequence.mode 'multiplexed': the loop would get "
                              f"no frame within the run, got {value!r}")
    first_frame = seq.start_s + seq.tracking_window_s + seq.latency_s
    if first_frame >= duration_s:
        raise ConfigError(f"sequence.latency_s={seq.latency_s!r}: the first frame reaches the observer at "
                          f"sequence.start_s + tracking_window_s + latency_s = {first_frame:.6g} s, not before the run "
                          f"ends ({run}); shorten the latency or the window, or run longer")
    first_push = seq.start_s + seq.tracking_window_s + seq.dead_time_s
    if first_push >= duration_s:
        raise ConfigError(f"sequence.dead_time_s={seq.dead_time_s!r}: the first propulsion window opens at "
                          f"sequence.start_s + tracking_window_s + dead_time_s = {first_push:.6g} s, not before the "
                          f"run ends ({run})")


def short_copy(scenario: Scenario, duration_s: float) -> Scenario:
    """``scenario`` run for ``duration_s`` only: a warm-up's throwaway copy (its first calls load compiled code).

    A multiplexed sequence's windows shrink to one or two control ticks, with
    no latency and no dead time (a tracking window as long as an MR frame's
    acquisition), so that its first frame and its first
    propulsion window fall within the copy's few ticks (the loader refuses a
    sequence that does not fit in its run, :func:`_check_fits_run`); every
    stage still runs the same code.  A continuous scenario keeps its sequence.
    """
    sim = dataclasses.replace(scenario.sim, duration_s=duration_s)
    seq = scenario.sequence
    if seq.mode == "multiplexed":
        dt = sim.dt_control_s
        window = 2.0 * dt
        # an imager of MR frames needs its acquisition's time in the window (its kind refuses less): the copy
        # runs one such window and a propulsion tick
        frame_s = float(getattr(getattr(scenario.imager, "imaging", None), "frame_time_s", 0.0))
        if frame_s > window:
            window = math.ceil(frame_s / dt - 1e-9) * dt
            sim = dataclasses.replace(sim, duration_s=max(duration_s, window + 2.0 * dt))
        seq = dataclasses.replace(seq, start_s=0.0, tracking_window_s=window, dead_time_s=0.0,
                                  propulsion_window_s=dt, latency_s=0.0)
    return dataclasses.replace(scenario, sim=sim, sequence=seq)


def scenario_from_mapping(mapping: Any) -> Scenario:
    """Build a :class:`Scenario` from a plain mapping (strict, see module docstring).

    A mapping with a ``base:`` key (ROS parameters of a user's node, say) extends that scenario as a file does
    (:func:`load_scenario_mapping`); a relative path is taken from the working directory.
    """
    if isinstance(mapping, Mapping) and BASE_KEY in mapping:
        mapping = _extend(dict(mapping), Path.cwd() / "<mapping>", ())
    return load_dataclass(Scenario, with_flow_preset_values(mapping), "")


def with_flow_preset_values(mapping: Any) -> Any:
    """``mapping`` with ``physics.flow.preset``'s values written into ``physics.flow`` (docs/vessels.md).

    The preset (a ``flow_presets`` entry of the file ``physics.vessel.network`` names) sets the flow section's
    ``centreline_velocity_m_per_s``, ``pulsatility`` and ``angular_frequency_rad_per_s`` (whatever the section
    held: the preset is the flow); a ``model.overrides`` velocity is scaled by the same ratio, so the model keeps
    its relative error (the III-C 5 %).  Idempotent: a scenario's own mapping loads to the same scenario.  A
    mapping without a preset is returned as it is.

    Raises:
        ConfigError: a preset without a network, a network that does not load, or no such preset (one line).
    """
    physics = mapping.get("physics") if isinstance(mapping, Mapping) else None
    flow = physics.get("flow") if isinstance(physics, Mapping) else None
    preset = flow.get("preset") if isinstance(flow, Mapping) else None
    if not preset or not isinstance(preset, str) or not isinstance(physics, Mapping) or not isinstance(flow, Mapping):
        return mapping  # no preset (or not a name: FlowParams names the key and value)
    vessel = physics.get("vessel")
    network = vessel.get("network") if isinstance(vessel, Mapping) else None
    if not network or not isinstance(network, str):
        raise ConfigError(f"physics.flow.preset needs physics.vessel.network (a preset is a vessel network's), "
                          f"got preset={preset!r} and network={network!r}")
    try:
        net = load_network(network)
    except ConfigError as exc:
        raise ConfigError(f"physics.vessel.network: {exc}") from None
    values = net.flow_preset(preset).flow_values()
    out = apply_overrides(mapping, {f"physics.flow.{k}": v for k, v in values.items()})
    old_vf = flow.get("centreline_velocity_m_per_s", FlowParams().centreline_velocity_m_per_s)
    model = out.get("model")
    overrides = model.get("overrides") if isinstance(model, Mapping) else None
    key = "flow.centreline_velocity_m_per_s"
    if isinstance(overrides, Mapping) and overrides:
        flat = flatten(unflatten(dict(overrides)))
        v = flat.get(key)
        if (isinstance(v, (int, float)) and not isinstance(v, bool) and isinstance(old_vf, (int, float))
                and old_vf != values["centreline_velocity_m_per_s"] and math.isfinite(old_vf) and old_vf != 0.0):
            flat[key] = v * (values["centreline_velocity_m_per_s"] / old_vf)
            out["model"]["overrides"] = unflatten(flat)
    return out


#: The key of a scenario file naming the scenario it extends: a shipped scenario's name (``sound_small_artery``)
#: or a path relative to the file.
BASE_KEY = "base"


def merge_scenario_mappings(base: Mapping[str, Any], child: Mapping[str, Any]) -> dict[str, Any]:
    """``child`` over ``base``, key by key: what a scenario file with ``base:`` loads as.

    A mapping merges into the base's mapping at the same key (recursively); any other value (a number, a
    string, a list) and an empty mapping ``{}`` replace the base's value.  A stage section whose ``kind`` the
    child switches to a kind with other parameters drops the base's keys of the old kind
    (:func:`~vesselbot_ros.sim.kinds.switch_sections`, as ``--set`` does).  Unknown keys are left for the loader
    to refuse, naming the key.
    """
    return switch_sections(base, _deep_merge(base, child), child)


def _deep_merge(base: Mapping[str, Any], child: Mapping[str, Any]) -> dict[str, Any]:
    out = apply_overrides(base, {})  # a deep copy
    for key, value in child.items():
        old = out.get(key)
        if isinstance(value, Mapping) and value and isinstance(old, Mapping):
            out[key] = _deep_merge(old, value)
        else:
            out[key] = apply_overrides({"v": value}, {})["v"]
    return out


def _base_path(path: Path, base: str) -> Path:
    """The file ``base:`` of ``path`` names: a path relative to ``path``'s folder (or absolute), else a shipped name."""
    near = (path.parent / Path(base).expanduser())
    if near.is_file():
        return near
    return resolve_config_path(base)


def _extend(data: dict[str, Any], path: Path, chain: tuple[Path, ...]) -> dict[str, Any]:
    """``data`` (read from ``path``) merged over the scenario its ``base:`` names, that one's base first."""
    base = data.pop(BASE_KEY)
    if not isinstance(base, str) or not base.strip():
        raise ConfigError(f"{BASE_KEY} in {path} must be a shipped scenario's name or a path relative to the file, "
                          f"got {base!r}")
    bp = _base_path(path, base)
    if not bp.is_file():
        names = ", ".join(sorted(shipped_scenarios()))
        raise ConfigError(f"{BASE_KEY}: {base!r} in {path} does not exist (neither {path.parent / base} nor a shipped "
                          f"scenario; shipped: {names})")
    parent = _read_scenario_file(bp, (*chain, path.resolve()))
    merged = merge_scenario_mappings(parent, data)
    if "name" not in data and _is_name(path.stem) and path.name != "<mapping>":
        merged["name"] = path.stem  # the run is labelled after the file, not after its base
    return merged


def _is_name(text: str) -> bool:
    return bool(text) and all(c.isalnum() or c in "_-." for c in text)


def _read_scenario_file(path: Path, chain: tuple[Path, ...]) -> dict[str, Any]:
    p = resolve_config_path(path)
    key = p.resolve()
    if key in chain:
        loop = [*chain[chain.index(key):], key]
        raise ConfigError(f"{BASE_KEY}: scenario files extend each other in a circle: "
                          + " -> ".join(str(q) for q in loop))
    data = load_yaml(p)
    return _extend(data, p, chain) if BASE_KEY in data else data


def load_scenario_mapping(path: str | Path, *, note: bool = True) -> dict[str, Any]:
    """The mapping of a scenario file, its ``base:`` chain resolved: the one reader of scenario files.

    A file with ``base: NAME`` (a shipped scenario's name or a path relative to the file) is merged over that
    scenario key by key (:func:`merge_scenario_mappings`); the base may have a base of its own.  A file that
    sets no ``name`` is named after itself (its stem).  A file without ``base:`` takes the code's defaults for
    every key it leaves out; when those differ from :data:`DEFAULT_SCENARIO`'s, one line on stderr says so
    (:func:`defaults_note`; not for the shipped files, which are written whole on purpose).

    Raises:
        ConfigError: as :func:`~vesselbot_ros.config.load_yaml`, for the file and each base; a base that does
            not exist (named, with the shipped names); a ``base:`` that is not a string; files whose bases form
            a circle (every file named).
    """
    p = resolve_config_path(path)
    data = load_yaml(p)  # read once: the chain below reads each base once too
    if BASE_KEY in data:
        return _extend(data, p, ())
    line = defaults_note(p, data) if note else None
    if line:
        print(line, file=sys.stderr, flush=True)
    return data


def defaults_taken(data: Mapping[str, Any], default: Mapping[str, Any]) -> list[tuple[str, Any, Any]]:
    """The keys a scenario mapping without ``base:`` leaves to the code where ``default`` sets another value.

    Returns:
        ``(dotted key, the code's default, default's value)`` per such key, in ``default``'s order; the code's
        default is :data:`UNSET` where the code has none (an entry of a mapping such as ``model.overrides``).
        A stage section whose ``kind`` ``data`` switches to a kind with other parameters is left out (the
        default's keys do not apply to it).
    """
    hints = typing.get_type_hints(Scenario)
    code_top = Scenario.__dataclass_fields__
    role_of = {sec: role for role, sec in SECTIONS.items()}
    out: list[tuple[str, Any, Any]] = []
    for sec, dval in default.items():
        if sec in ("name", BASE_KEY) or sec not in code_top:
            continue
        fval = data.get(sec)
        if not isinstance(dval, Mapping):
            field = code_top[sec]
            if sec not in data and field.default is not dataclasses.MISSING and field.default != dval:
                out.append((sec, field.default, dval))
            continue
        if fval is not None and not isinstance(fval, Mapping):
            continue  # the loader refuses it, naming the key
        try:
            if sec in role_of:
                cls = params_type(role_of[sec], fval or {})
                if cls is not params_type(role_of[sec], dval):
                    continue
            else:
                cls = hints[sec]
            code = flatten(to_mapping(cls()))
        except (ConfigError, TypeError):
            continue  # a kind the code cannot default (a user's class with required fields): nothing to compare
        for key, value in flatten(dval).items():
            if not _is_set(fval, key.split(".")) and code.get(key, UNSET) != value:
                out.append((f"{sec}.{key}", code.get(key, UNSET), value))
    return out


class _Unset:
    def __repr__(self) -> str:
        return "unset"


#: The code's default of a key it has none for (:func:`defaults_taken`).
UNSET: Any = _Unset()


def _is_set(section: Any, parts: list[str]) -> bool:
    node = section
    for part in parts:
        if not isinstance(node, Mapping) or not node:
            return node is not None  # a value or an empty mapping written above the key: the file decided
        if part not in node:
            return False
        node = node[part]
    return True


def _short(value: Any) -> str:
    if isinstance(value, float):
        text = f"{value:g}"
    elif isinstance(value, (list, tuple)) and any(isinstance(v, Mapping) for v in value):
        text = f"[{len(value)} entr{'y' if len(value) == 1 else 'ies'}]"
    elif isinstance(value, (list, tuple)):
        text = "[" + ", ".join(_short(v) for v in value) + "]"
    else:
        text = str(value)
    return text if len(text) <= 24 else text[:21] + "..."


def defaults_note(path: str | Path, data: Mapping[str, Any]) -> str | None:
    """The one line that tells a scenario file without ``base:`` which defaults it got, or None.

    None for a shipped file and for a file that sets every key where the code's defaults and
    :data:`DEFAULT_SCENARIO`'s differ (:func:`defaults_taken`): there is nothing to tell.
    """
    p = Path(path)
    shipped = shipped_config_dir().resolve()
    if p.resolve().parent == shipped or shipped in p.resolve().parents:
        return None
    default = load_yaml(resolve_config_path(DEFAULT_SCENARIO))
    taken = defaults_taken(data, default)
    if not taken:
        return None
    shown = ", ".join(f"{k} {_short(code)} not {_short(val)}" for k, code, val in taken[:4])
    more = f", and {len(taken) - 4} more" if len(taken) > 4 else ""
    return (f"note: {p} has no `{BASE_KEY}:`; keys it does not set take the code's defaults ({shown}{more}), not "
            f"those of {DEFAULT_SCENARIO}: add `{BASE_KEY}: {DEFAULT_SCENARIO}` to extend the default scenario")


def scenario_overrides(
    sets: Iterable[str] = (), duration: float | None = None, seed: int | None = None
) -> dict[str, Any]:
    """The dotted-key overrides of ``--set KEY=VALUE``, ``--duration S`` and ``--seed N``.

    ``--duration`` is ``sim.duration_s`` and ``--seed`` is ``seed``; they win
    over a ``--set`` of the same key.  Apply the result with
    :func:`vesselbot_ros.config.apply_overrides`.
    """
    out = parse_set_items(sets)
    if duration is not None:
        out["sim.duration_s"] = duration
    if seed is not None:
        out["seed"] = seed
    return out


def load_scenario(
    path: str | Path, *, sets: Iterable[str] = (), duration: float | None = None, seed: int | None = None,
    changes: Mapping[str, Any] | None = None, hardware: str | None = None,
) -> Scenario:
    """Load a scenario YAML file, with the command line's overrides applied (one path for every command).

    Args:
        path: The scenario YAML file (its ``base:`` chain resolved, :func:`load_scenario_mapping`).
        sets: ``KEY=VALUE`` strings (``--set``), VALUE read as YAML by the one
            parser; a mapping value replaces the mapping at KEY.
        duration: ``--duration`` (``sim.duration_s``), s.
        seed: ``--seed``.
        changes: Dotted-key values a command sets; ``sets``, ``duration``
            and ``seed`` win over them.
        hardware: ``--hardware PRESET``: a scanner preset's coil and sequence
            (:func:`~vesselbot_ros.scanner.hardware.preset_changes`), applied
            first: ``changes``, ``sets``, ``duration`` and ``seed`` win over it.

    Raises:
        ConfigError: missing or unreadable file, not a scenario (empty, binary,
            too large, too deep, self-expanding), duplicate key, unknown key,
            wrong type or out-of-range value (the message names the dotted key
            and value).
    """
    preset = preset_changes(hardware) if hardware is not None else {}
    return with_overrides(load_scenario_mapping(path),
                          {**preset, **(changes or {}), **scenario_overrides(sets, duration, seed)})


def overridden(mapping: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``mapping`` with each dotted key of ``overrides`` set to its value: the one override path of a scenario.

    ``--set``, ``--duration``, ``--seed``, ``--hardware``, a campaign's ``overrides``, variants, grid points and
    draws all go through here: a value *replaces* what is at its key (``model.overrides={}`` clears the
    mapping, :func:`~vesselbot_ros.config.apply_overrides`), and a section whose ``kind`` an override switches
    to a kind with other parameters drops the old kind's keys (:func:`~vesselbot_ros.sim.kinds.switch_sections`).
    Not validated: the loader does that once, naming the key.
    """
    return switch_sections(mapping, apply_overrides(mapping, overrides), unflatten(overrides))


def with_overrides(mapping: Mapping[str, Any], overrides: Mapping[str, Any]) -> Scenario:
    """The scenario of ``mapping`` with dotted-key ``overrides`` (:func:`overridden`), validated."""
    return scenario_from_mapping(overridden(mapping, overrides))


def scenario_with(scenario: Scenario, overrides: Mapping[str, Any]) -> Scenario:
    """``scenario`` with dotted-key ``overrides`` (:func:`with_overrides`)."""
    return with_overrides(scenario.to_mapping(), overrides)


@dataclasses.dataclass(frozen=True)
class ResourceEstimate:
    """What a run of a scenario will need.

    Attributes:
        n_ticks: Control ticks.
        memory_bytes: Time series held in memory (runner or launcher).
        bag_bytes: Size of the recorded bag.
    """

    n_ticks: int
    memory_bytes: int
    bag_bytes: int


def estimate_resources(scenario: Scenario) -> ResourceEstimate:
    """Estimate the memory and recording size of one run of ``scenario``."""
    ticks = scenario.sim.duration_s * scenario.sim.control_rate_Hz
    per_tick = BYTES_PER_TICK + (FORCE_BYTES_PER_TICK if scenario.sim.record_forces else 0)
    n = int(min(ticks, 2**62))
    bag = ticks * BAG_BYTES_PER_TICK + _frame_bag_bytes(scenario)
    return ResourceEstimate(n, int(min(ticks * per_tick, 2**62)), int(min(bag, 2**62)))


#: What one tick of an imager of MR frames adds to a bag besides its frames: the empty ``imager/frame`` (bytes).
EMPTY_FRAME_BAG_BYTES = 160


def _frame_bag_bytes(scenario: Scenario) -> float:
    """The MR frames a run records (``imager/frame``: 16 bytes a complex sample; ``imager/image``: 4), bytes."""
    imaging = getattr(scenario.imager, "imaging", None)
    if imaging is None:
        return 0.0
    samples = imaging.matrix * (imaging.matrix if imaging.acquisition == "slice" else 3)
    seq = scenario.sequence
    rate = 1.0 / seq.period_s if seq.mode == "multiplexed" else float(scenario.imager.frame_rate_Hz)
    ticks = scenario.sim.duration_s * scenario.sim.control_rate_Hz
    return ticks * EMPTY_FRAME_BAG_BYTES + scenario.sim.duration_s * rate * (20 * samples + 2 * EMPTY_FRAME_BAG_BYTES)


# the one budget and formatter of every resource check (vesselbot_ros.resources.require_fits reads them too)
_memory_budget_bytes = memory_budget_bytes
_fmt_bytes = fmt_bytes


def check_resources(
    scenario: Scenario, bag_dir: str | Path | None = None, memory_budget_bytes: int | None = None
) -> ResourceEstimate:
    """Refuse, before any work is done, a run that does not fit in memory (or on disk).

    ``vesselbot simulate`` calls it before it runs anything; the launcher
    (``vesselbot run``) calls it before it makes the run directory.

    Args:
        scenario: The validated scenario.
        bag_dir: Where the bag will be recorded (its nearest existing parent
            is checked for free space), or None for no recording.
        memory_budget_bytes: Memory one run may hold (default: half of this
            machine's physical memory).

    Returns:
        The estimate.

    Raises:
        ConfigError: one line naming ``sim.duration_s`` and
            ``sim.control_rate_Hz``, what the run needs and what is available;
            for a 3-D tree whose wall and flow are not yet built, naming the
            ``cfd`` key whose build would not fit
            (:func:`vesselbot_ros.vessels.tree_field.check_build`).
    """
    est = estimate_resources(scenario)
    budget = _memory_budget_bytes() if memory_budget_bytes is None else memory_budget_bytes
    sim = scenario.sim
    what = f"sim.duration_s={sim.duration_s!r} s at sim.control_rate_Hz={sim.control_rate_Hz!r} Hz is {est.n_ticks:.3g} control ticks"
    if est.memory_bytes > budget:
        raise ConfigError(
            f"{what}; its time series need about {_fmt_bytes(est.memory_bytes)}, more than the "
            f"{_fmt_bytes(budget)} a run may use (half of this machine's memory): shorten sim.duration_s or lower "
            f"sim.control_rate_Hz"
        )
    if scenario.dims == 3:  # the vessel kind's edge: a tree's wall and flow, built once per tree, bounded before any node starts
        from vesselbot_ros.vessels.tree_field import check_build  # deferred: the 3-D wall's numba kernels

        check_build(load_network(scenario.physics.vessel.network), scenario.physics.blood, quiet=True)
    if bag_dir is not None:
        parent = Path(bag_dir).expanduser().absolute()
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
        free = shutil.disk_usage(parent).free
        need = est.bag_bytes + RECORDING_HEADROOM_BYTES  # the one rule of `vesselbot run` (the recorder checks no other)
        if need > free:
            raise ConfigError(
                f"{what}; recording it to {bag_dir} needs {_fmt_bytes(need)} free ({_fmt_bytes(est.bag_bytes)} of bag "
                f"at {BAG_BYTES_PER_TICK} B per tick, and {_fmt_bytes(RECORDING_HEADROOM_BYTES)} for the node logs, the "
                f"bag's metadata and a report), but only {_fmt_bytes(free)} is free on {parent}: free some space, "
                f"shorten sim.duration_s, lower sim.control_rate_Hz or use --no-record"
            )
    return est


#: The scenario ``vesselbot run`` / ``simulate`` (and ``make run`` / ``make simulate``) run without ``--config``:
#: Section III-C with the physically sound readings (docs/reproduction.md).
DEFAULT_SCENARIO = "sound_small_artery"

#: Folder of the scenarios shipped with vesselbot_ros (a checkout's config/, or the installed share/ copy).
SCENARIO_DIR = shipped_config_dir()
#: The clinical 3 T plan with the estimate made from MR images of the bead (docs/imaging.md's example): its file and
#: overrides.  The image-based environment's default (``vesselbot/MriImages-v0``); the warm-up compiles the image
#: stages on it.
MR_IMAGES_PLAN: tuple[Path, dict[str, Any]] = (SCENARIO_DIR / "plans" / "clinical_3t.yaml",
                                               {"imager.kind": "mr_images", "imager.fov_centre_m": [4.0e-3, 0.0, 0.0]})


def shipped_scenarios() -> dict[str, Path]:
    """``{name: path}`` of the shipped scenario files (``config/*.yaml`` with a top-level ``name``).

    Parameter sets that are not scenarios (``physics_default.yaml``,
    ``design_study.yaml``) carry no ``name`` and are left out.
    """
    out: dict[str, Path] = {}
    for path in sorted(SCENARIO_DIR.glob("*.yaml")):
        data = load_yaml(path)  # parsed once per process and content (its cache): a few ms for the list again
        if isinstance(data.get("name"), str):
            out[data["name"]] = path
    return out
