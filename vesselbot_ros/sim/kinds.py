"""The registry of stage kinds: every stage of the loop is built here, by role and kind, and nowhere else.

The loop has seven roles (:data:`ROLES`): the plant, the imager, the tracker
(only with an imager that delivers MR frames: it turns each into a position),
the observer, the controller, the gradient coil and the reference.  A scenario names the
kind of each in its section's ``kind`` key (:data:`SECTIONS`: the plant's
section is ``physics``)::

    controller:
      kind: backstepping          # a built-in kind (vesselbot kinds lists them)
    observer:
      kind: my_lab.observers:Ukf  # a user's class, module:Class

A kind (:class:`StageKind`) brings three things: its parameters dataclass
(the scenario section, validated by the one config loader: unknown keys are
errors), a builder that makes its Python stage from a :class:`BuildContext`,
and whether the compiled loop (:mod:`vesselbot_ros.sim.compiled_loop`) has it.
The per-tick loop, the compiled loop, the nodes, campaigns, the study and the
command line all build stages through :func:`build` and look kinds up with
:func:`kind_of` / :func:`find`.

Kinds come from three places, looked up in this order:

1. the built-in kinds, registered below with :func:`register`;
2. installed packages, through the entry point group :data:`ENTRY_POINT_GROUP`
   (entry name = kind name, value = ``module:attr``);
3. ``module:attr`` named in the scenario itself (the module must be importable,
   e.g. on ``PYTHONPATH``: in node processes and on Dask workers too).

``attr`` is either a :class:`StageKind` or a stage class following the plug-in
convention (see ``examples/plugin_controller.py``)::

    class MyController:
        ROLE = "controller"                 # one of ROLES
        Params = MyParams                   # frozen dataclass whose first field is ``kind: str``
        def __init__(self, params, context): ...   # context: BuildContext
        def command(self, t_s, estimate, ref): ...  # the role's protocol (below)

The protocols (what the loop and the nodes call, :class:`PlantStage` ...
:class:`ReferenceStage`) are the built-in stages' per-tick methods.  A user's
controller receives the estimate the graph carries between nodes
(:func:`controller_estimate`: position, velocity, age of the last measurement,
flow scale), so the same controller gives the same numbers in
``vesselbot simulate``, ``vesselbot campaign`` and inside the controller node
of ``vesselbot run``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import importlib.metadata
import importlib.util
import inspect
import math
import sys
import threading
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from vesselbot_ros.config import ConfigError
from vesselbot_ros.control.action_replay import ActionReplayController, ActionReplayParams, load_actions
from vesselbot_ros.control.backstepping import BacksteppingController, ControlCommand, ControllerParams
from vesselbot_ros.control.bspline_reference import (
    ReferenceParams,
    ReferenceTrajectory,
    RefSample,
    WallMotion,
    wall_shift_of,
)
from vesselbot_ros.control.compiled_stage import CompiledController, CompiledObserver
from vesselbot_ros.control.ekf_observer import ExtendedKalmanObserver
from vesselbot_ros.control.estimate import Estimate
from vesselbot_ros.control.high_gain_observer import HighGainObserver, ObserverParams, check_frame_period
from vesselbot_ros.control.model import DynamicsModel
from vesselbot_ros.control.policy import PolicyController, PolicyParams, load_policy
from vesselbot_ros.control.predictive import PredictiveController, PredictiveParams
from vesselbot_ros.control.route import planned_reference
from vesselbot_ros.errors import ModelInputError, VesselbotError
from vesselbot_ros.imaging.imager_params import MrImagerParams, TrackerParams
from vesselbot_ros.numba_cache import freshen_dependent
from vesselbot_ros.physics.integrator import blood_velocity, floor_offsets
from vesselbot_ros.physics.kernel import I_D_PULSE, I_OMEGA_F, I_PHI_F
from vesselbot_ros.physics.params import PhysicsParams
from vesselbot_ros.scanner.actuator_limits import CoilLimiter, CoilLimits, CoilOutput
from vesselbot_ros.scanner.hardware import effective_coil_limits
from vesselbot_ros.scanner.imager_model import ImagerModel, ImagerParams, Measurement
from vesselbot_ros.scanner.sequence import duty_cycle
from vesselbot_ros.scanner.stages import SequencedCoil, SequencedImager
from vesselbot_ros.sim.plant import PlantOutput, PlantSimulator
from vesselbot_ros.vessels.tree_field import packed_vessel, vessel_geom

__all__ = [
    "ROLES", "SECTIONS", "DEFAULT_KINDS", "ENTRY_POINT_GROUP", "StageKind", "BuildContext", "register", "find",
    "kind_of", "kinds", "build", "compiled_stage", "STEPPED_ROLES", "params_type", "section_resolver", "switch_sections",
    "fingerprint", "controller_estimate", "call_controller", "checked_command", "rejection_warning", "REJECT_REASONS",
    "REJECT_NONE", "REJECT_NONFINITE", "REJECT_ESTIMATE", "REJECT_RAISED", "REJECT_MALFORMED", "COMMAND_STATUSES",
    "make_observer", "delivers_frames", "PlantStage", "ImagerStage", "TrackerStage",
    "ObserverStage", "ControllerStage", "CoilStage", "ReferenceStage",
]

#: The loop's roles, in the order the loop calls them (the fields of ``closed_loop.Stages`` but the model).
ROLES: tuple[str, ...] = ("plant", "imager", "tracker", "observer", "reference", "controller", "coil")
#: The roles whose kinds bring a compiled step the compiled loop calls through a pointer (its signature:
#: :mod:`vesselbot_ros.control.compiled_stage`); the plant, imager, reference and coil are the loop's own.
STEPPED_ROLES: tuple[str, ...] = ("observer", "controller")
#: The scenario section that holds each role's parameters (and its ``kind``).
SECTIONS: dict[str, str] = {"plant": "physics", "imager": "imager", "tracker": "tracker", "observer": "observer",
                            "reference": "reference", "controller": "controller", "coil": "coil"}
#: The kind of each role when its section does not name one.
DEFAULT_KINDS: dict[str, str] = {"plant": "vessel", "imager": "mri", "tracker": "dipole_fit", "observer": "high_gain",
                                 "reference": "bspline", "controller": "backstepping", "coil": "gradient_coil"}
#: Entry point group through which installed packages register kinds (entry name = kind name).
ENTRY_POINT_GROUP = "vesselbot_ros.stages"


# ---- protocols: what the loop and the nodes call on a stage of each role ---------------------------------------
@runtime_checkable
class PlantStage(Protocol):
    """The plant: ground truth at the tick, then one control period integrated under the applied gradient."""

    def output(self, with_forces: bool = False) -> PlantOutput: ...

    def step(self, g_applied: npt.NDArray[np.float64]) -> None: ...


@runtime_checkable
class ImagerStage(Protocol):
    """The imager: the measurement delivered at ``t_s`` (or None) of the true position."""

    def frame(self, t_s: float, p_true: npt.NDArray[np.float64]) -> Measurement | None: ...


@runtime_checkable
class TrackerStage(Protocol):
    """The tracker: the measurement of an MR frame the imager delivered at ``t_s``
    (:class:`~vesselbot_ros.imaging.imager_stage.MrFrame`), or None for a frame it rejects (never a NaN)."""

    def track(self, t_s: float, frame: Any) -> Measurement | None: ...


@runtime_checkable
class ObserverStage(Protocol):
    """The observer: the estimate after the tick's measurement (or None) and the previous applied gradient."""

    def update(self, t_s: float, measurement: Measurement | None, g_prev: npt.NDArray[np.float64]) -> Estimate: ...


@runtime_checkable
class ReferenceStage(Protocol):
    """The reference: position, velocity and acceleration at a time, or at many."""

    def sample(self, t_s: float) -> RefSample: ...

    def sample_many(self, ts: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], ...]: ...


@runtime_checkable
class ControllerStage(Protocol):
    """The controller: the gradient command from the estimate (:func:`controller_estimate`) and the reference."""

    def command(self, t_s: float, estimate: Estimate, ref: RefSample) -> ControlCommand: ...


@runtime_checkable
class CoilStage(Protocol):
    """The gradient coil: the gradient it applies over the next period for a command."""

    def apply(self, t_s: float, g_cmd: npt.NDArray[np.float64]) -> CoilOutput: ...


_PROTOCOLS: dict[str, type] = {"plant": PlantStage, "imager": ImagerStage, "tracker": TrackerStage, "observer": ObserverStage,
                               "reference": ReferenceStage, "controller": ControllerStage, "coil": CoilStage}


# ---- kinds ------------------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class StageKind:
    """One kind of stage.

    Attributes:
        role: One of :data:`ROLES`.
        name: The name a scenario's ``kind`` key gives (``module:attr`` for a user's kind named in a scenario).
        params: The section's frozen dataclass; its ``kind`` field holds ``name``.  A plant kind's
            params subclass :class:`~vesselbot_ros.physics.params.PhysicsParams` (the controller's
            model reads them).
        build: Makes the Python stage: ``build(context) -> stage``.
        compiled: The compiled loop runs this kind (its stage types are in ``stage_types``); ``compile`` gives
            its compiled form.
        stage_types: The classes the built stage may have, for :func:`kind_of` on a stage object.
        summary: One line for ``vesselbot kinds``.
        source: ``built-in``, ``entry point <distribution>`` or ``scenario``.
        module_file: The file the kind is defined in (its hash joins a campaign run's content address).
        compile: The compiled form of a built stage, one per role: for an observer or a controller a
            :class:`~vesselbot_ros.control.compiled_stage.CompiledObserver` or ``CompiledController`` (a numba
            step of the one signature of its role that the compiled loop calls), for an imager or a coil a
            :class:`~vesselbot_ros.scanner.imager_model.CompiledImager` or
            :class:`~vesselbot_ros.scanner.actuator_limits.CompiledCoil` (the arrays the kernel's imager and
            coil read, on the scanner's sequence or none), for the plant a
            :class:`~vesselbot_ros.sim.plant.CompiledPlant` (its vessel, integrator and state) and for the
            reference a :class:`~vesselbot_ros.control.bspline_reference.CompiledReference` (its samples at the
            tick times); None: the per-tick loop runs it.
        check: ``check(params, scenario)``: the kind's own rules across the scenario's sections, run when the
            scenario is validated (its params class checks its own keys); raises ConfigError naming the keys.  It raises
            :class:`~vesselbot_ros.errors.ModelInputError` for a stage it cannot compile (a built-in kind
            over a user's part).
        frames: An imager kind that delivers MR frames (:class:`~vesselbot_ros.imaging.imager_stage.MrFrame`)
            rather than positions: the scenario's tracker turns them into measurements (and the node graph runs a
            tracker node).
    """

    role: str
    name: str
    params: type
    build: Callable[[BuildContext], Any]
    compiled: bool = False
    stage_types: tuple[type, ...] = ()
    summary: str = ""
    source: str = "built-in"
    module_file: str = ""
    compile: Callable[[Any], CompiledObserver | CompiledController] | None = None
    check: Callable[[Any, Any], None] | None = None
    frames: bool = False

    def __post_init__(self) -> None:
        if self.role not in ROLES:
            raise ConfigError(f"stage kind {self.name!r}: role must be one of {list(ROLES)}, got {self.role!r}")
        if not (dataclasses.is_dataclass(self.params) and isinstance(self.params, type)):
            raise ConfigError(f"stage kind {self.name!r}: params must be a dataclass type, got {self.params!r}")
        if "kind" not in {f.name for f in dataclasses.fields(self.params)}:
            raise ConfigError(f"stage kind {self.name!r}: its params dataclass {self.params.__name__} needs a "
                              "'kind: str' field (the scenario's kind key)")
        if self.compiled and self.compile is None:
            raise ConfigError(f"stage kind {self.name!r}: a compiled {self.role} kind needs compile")
        if self.role == "plant" and not issubclass(self.params, PhysicsParams):
            raise ConfigError(f"stage kind {self.name!r}: a plant kind's params must subclass PhysicsParams "
                              f"(the controller's model reads them), got {self.params.__name__}")


class BuildContext:
    """What a kind's builder gets: the scenario, the seed, its role's parameters, and the other stages on demand.

    Attributes:
        scenario: The :class:`~vesselbot_ros.sim.scenario.Scenario`.
        seed: The imager's seed for this run.
        role: The role being built.
        params: ``scenario``'s section of that role.
        dt_s: The control period (s).
    """

    def __init__(self, builder: Any, role: str) -> None:
        self._builder = builder
        self.scenario = builder.s
        self.seed: int = builder.seed
        self.role = role
        self.params: Any = getattr(self.scenario, SECTIONS[role])
        self.dt_s: float = self.scenario.sim.dt_control_s

    def get(self, name: str) -> Any:
        """Another stage of the same run (built once), or ``model`` (the controller's :class:`DynamicsModel`)."""
        return self._builder.get(name)

    @property
    def model(self) -> DynamicsModel:
        """The controller's and observer's model of the plant (``model.overrides`` applied)."""
        model: DynamicsModel = self._builder.get("model")
        return model

    def rng(self) -> np.random.Generator:
        """A generator seeded with the run's seed (the imager's stream; give a user's noisy stage its own)."""
        return np.random.default_rng(self.seed)


_LOCK = threading.Lock()
_REGISTRY: dict[tuple[str, str], StageKind] = {}
_ENTRY_POINTS_LOADED = False


def register(kind: StageKind) -> StageKind:
    """Register ``kind`` (a kind name is unique within its role); returns it.

    Raises:
        ConfigError: another kind of that role already has the name.
    """
    with _LOCK:
        old = _REGISTRY.get((kind.role, kind.name))
        if old is not None and old != kind:
            raise ConfigError(f"stage kind {kind.role}/{kind.name} is registered twice ({old.source}, {kind.source})")
        _REGISTRY[(kind.role, kind.name)] = kind
    return kind


def _load_entry_points() -> None:
    global _ENTRY_POINTS_LOADED
    if _ENTRY_POINTS_LOADED:
        return
    _ENTRY_POINTS_LOADED = True
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        dist = getattr(getattr(ep, "dist", None), "name", "?")
        try:
            _freshen(ep.value.partition(":")[0])
            obj = ep.load()
        except Exception as exc:  # noqa: BLE001 - a broken plug-in package is reported by name, not a traceback
            print(f"vesselbot: stage kind entry point {ep.name!r} ({ep.value}) of {dist} does not load: {exc}",
                  file=sys.stderr)
            continue
        kind = _as_kind(obj, ep.name, f"entry point {dist}", where=f"entry point {ep.name!r}")
        register(kind)


def _freshen(module_name: str) -> None:
    """Before a user's module is imported: drop its numba cache if our compiled sources changed since it was written
    (:func:`~vesselbot_ros.numba_cache.freshen_dependent`; its compiled kind calls and inlines our functions)."""
    if module_name in sys.modules:
        return
    try:
        spec = importlib.util.find_spec(module_name)
    except (ImportError, ValueError):
        return  # the import that follows names the cause
    if spec is not None and spec.origin:
        freshen_dependent(spec.origin)


def _module_file(obj: Any) -> str:
    mod = sys.modules.get(getattr(obj, "__module__", "") or "")
    return str(getattr(mod, "__file__", "") or "")


def _as_kind(obj: Any, name: str, source: str, where: str) -> StageKind:
    """A :class:`StageKind` from a registered object: a kind itself, or a class following the plug-in convention."""
    if isinstance(obj, StageKind):
        return dataclasses.replace(obj, name=name, source=source, module_file=obj.module_file or _module_file(obj.build))
    if not inspect.isclass(obj):
        raise ConfigError(f"{where}: expected a StageKind or a stage class, got {obj!r}")
    role = getattr(obj, "ROLE", None)
    params = getattr(obj, "Params", None)
    if role not in ROLES:
        raise ConfigError(f"{where}: class {obj.__name__} needs ROLE, one of {list(ROLES)}, got {role!r}")
    if params is None:
        raise ConfigError(f"{where}: class {obj.__name__} needs Params, a frozen dataclass with a 'kind: str' field")
    needed = _PROTOCOLS[role]
    missing = [m for m in ("output", "step", "frame", "track", "update", "sample", "sample_many", "command", "apply")
               if hasattr(needed, m) and not callable(getattr(obj, m, None))]
    if missing:
        raise ConfigError(f"{where}: class {obj.__name__} ({role}) lacks method(s) {missing} of the {role} protocol")
    compiled = callable(getattr(obj, "compiled", None))  # its compiled form
    cls: Any = obj  # the user's class: called with (params, context) by the convention
    return StageKind(role=role, name=name, params=params, build=lambda ctx: cls(ctx.params, ctx), compiled=compiled,
                     stage_types=(obj,), summary=(inspect.getdoc(obj) or "").split("\n")[0], source=source,
                     module_file=_module_file(obj), compile=(lambda stage: stage.compiled()) if compiled else None)


def find(role: str, name: str, where: str = "") -> StageKind:
    """The kind ``name`` of ``role``: built in, from an entry point, or ``module:attr``.

    Args:
        role: One of :data:`ROLES`.
        name: The kind's name.
        where: The scenario key that named it, for the error message.

    Raises:
        ConfigError: unknown kind (the message lists the known ones), a module
            that does not import, or an object that is not a kind of ``role``.
    """
    key = where or f"{SECTIONS.get(role, role)}.kind"
    if role not in ROLES:
        raise ConfigError(f"unknown role {role!r}; roles: {list(ROLES)}")
    if not isinstance(name, str) or not name:
        raise ConfigError(f"{key} must be a kind name or 'module:Class', got {name!r}")
    hit = _REGISTRY.get((role, name))
    if hit is not None:
        return hit
    _load_entry_points()
    hit = _REGISTRY.get((role, name))
    if hit is not None:
        return hit
    if ":" not in name:
        known = sorted(k.name for (r, _n), k in _REGISTRY.items() if r == role and k.source != "scenario")
        raise ConfigError(f"{key}: unknown {role} kind {name!r}; known: {known}, or 'module:Class' of your own")
    module_name, _, attr = name.partition(":")
    try:
        _freshen(module_name)
        module = importlib.import_module(module_name)
    except Exception as exc:  # noqa: BLE001 - any failure of a user's module is one line naming the key
        raise ConfigError(f"{key}: module {module_name!r} of kind {name!r} does not import: "
                          f"{type(exc).__name__}: {exc}") from None
    obj: Any = module
    for part in attr.split("."):
        obj = getattr(obj, part, None)
        if obj is None:
            raise ConfigError(f"{key}: module {module_name!r} has no {attr!r} (kind {name!r})")
    kind = _as_kind(obj, name, "scenario", where=key)
    if kind.role != role:
        raise ConfigError(f"{key}: {name!r} is a {kind.role} kind, not a {role} kind")
    return register(kind)


def kinds(role: str | None = None) -> list[StageKind]:
    """The registered kinds (built in and from entry points), of ``role`` or of every role, sorted."""
    _load_entry_points()
    with _LOCK:
        out = list(_REGISTRY.values())
    return sorted((k for k in out if role is None or k.role == role), key=lambda k: (ROLES.index(k.role), k.name))


def kind_of(role: str, stage: object) -> StageKind | None:
    """The kind whose builder made ``stage`` (by its exact type), or None for an object of no registered kind."""
    with _LOCK:
        candidates = [k for (r, _n), k in _REGISTRY.items() if r == role]
    for k in candidates:
        if type(stage) in k.stage_types:
            return k
    return None


def compiled_stage(role: str, stage: Any) -> Any:
    """The compiled form of a stage, through its kind (:attr:`StageKind.compile`).

    Raises:
        ModelInputError: the stage's kind has no compiled form, or cannot compile this stage.
    """
    kind = kind_of(role, stage)
    if kind is None or kind.compile is None:
        raise ModelInputError(f"{role} {type(stage).__name__}: its kind has no compiled form")
    return kind.compile(stage)


def params_type(role: str, section: Any, where: str = "") -> type:
    """The params dataclass of the kind that a scenario section names (its ``kind`` key, else the default)."""
    name: Any = getattr(section, "kind", None) if dataclasses.is_dataclass(section) and not isinstance(section, type) else (
        section.get("kind", DEFAULT_KINDS[role]) if isinstance(section, Mapping) else DEFAULT_KINDS[role])
    return find(role, name, where).params


def section_resolver(role: str) -> Callable[[Any, str], type]:
    """The config loader's hook for a role's section: picks the dataclass by the section's ``kind``."""

    def resolve(section: Any, path: str) -> type:
        return params_type(role, section, f"{path}.kind")

    resolve.__qualname__ = f"section_resolver.<{role}>"
    return resolve


def delivers_frames(scenario: Any) -> bool:
    """Whether ``scenario``'s imager delivers MR frames (a tracker makes its measurements; :attr:`StageKind.frames`)."""
    return find("imager", scenario.imager.kind, "imager.kind").frames


def build(role: str, builder: Any) -> Any:
    """Build ``role``'s stage for the run of ``builder`` (``closed_loop``'s stage builder), through its kind.

    The tracker is None when the imager delivers positions (no frame to track)."""
    if role == "tracker" and not delivers_frames(builder.s):
        return None
    ctx = BuildContext(builder, role)
    kind = find(role, ctx.params.kind, f"{SECTIONS[role]}.kind")
    if kind.source == "built-in":
        return kind.build(ctx)
    try:  # a user's kind whose constructor fails: one line naming the kind and the exception, not a traceback
        return kind.build(ctx)
    except VesselbotError:
        raise
    except Exception as exc:  # noqa: BLE001 - any failure of a user's constructor
        raise ConfigError(f"{SECTIONS[role]}.kind: the {role} kind {kind.name!r} could not be built: its constructor "
                          f"raised {type(exc).__name__}: {exc}") from None


def fingerprint(scenario: Any) -> str:
    """Hash of the source files of the non-built-in kinds ``scenario`` names ('' if none).

    A campaign adds it to a run's content address, so a run of a user's kind
    is redone when the kind's code changes.
    """
    h = hashlib.sha256()
    n = 0
    for role in ROLES:
        kind = find(role, getattr(scenario, SECTIONS[role]).kind)
        if kind.source != "built-in" and kind.module_file:
            h.update(kind.name.encode() + b"\0")
            try:
                h.update(Path(kind.module_file).read_bytes())
            except OSError:
                h.update(b"<unreadable>")
            n += 1
    return h.hexdigest()[:16] if n else ""


def switch_sections(base: Mapping[str, Any], merged: dict[str, Any],
                    explicit: Mapping[str, Any]) -> dict[str, Any]:
    """``merged`` (``base`` with overrides applied) where an override switched a stage to a kind with other parameters.

    ``--set controller.kind=my_mod:MyController`` over a scenario whose
    ``controller`` section holds the backstepping gains: those keys belonged
    to the old kind, so they are dropped; the keys the overrides set
    (``explicit``: the nested overrides, as ``{section: {key: ...}}``) stay, and
    a wrong one is still refused by the loader.  Sections whose kind keeps its
    parameters class (``backstepping`` -> ``adaptive_backstepping``) are left as merged.
    """
    out = dict(merged)
    for role in ROLES:
        sec = SECTIONS[role]
        old, new = base.get(sec), merged.get(sec)
        if not (isinstance(old, Mapping) and isinstance(new, Mapping)):
            continue
        old_kind, new_kind = old.get("kind", DEFAULT_KINDS[role]), new.get("kind", DEFAULT_KINDS[role])
        if old_kind == new_kind:
            continue
        try:
            old_cls, new_cls = find(role, old_kind).params, find(role, new_kind).params
        except ConfigError:
            continue  # the loader reports the unknown kind, naming the key
        if old_cls is new_cls:
            continue
        given = explicit.get(sec)
        kept = set(given) if isinstance(given, Mapping) else set()
        out[sec] = {k: v for k, v in new.items() if k in kept or k not in old or k == "kind"}
    return out


# ---- the controller's input -------------------------------------------------------------------------------------
_ZERO2 = np.zeros(2)


def controller_estimate(t_s: float, x_hat: npt.NDArray[np.float64], z_hat: npt.NDArray[np.float64], age_s: float,
                        flow_scale: float) -> Estimate:
    """The estimate a controller receives: what the graph's estimate message carries, in both loops.

    Position, velocity, the age of the last accepted measurement and the
    observer's blood-velocity scale; no innovation, ``used_measurement`` and
    ``rejected`` False (they do not travel between the nodes).
    """
    return Estimate(t_s, x_hat, z_hat, age_s, _ZERO2, False, False, flow_scale)


def call_controller(controller: Any, t_s: float, x_hat: npt.NDArray[np.float64], z_hat: npt.NDArray[np.float64],
                    age_s: float, flow_scale: float, p_ref: npt.NDArray[np.float64], v_ref: npt.NDArray[np.float64],
                    a_ref: npt.NDArray[np.float64]) -> ControlCommand:
    """One command of any controller, as the per-tick loop and the controller node call it (the same numbers): its
    ``command(t, estimate, reference)`` with the estimate the graph carries (:func:`controller_estimate`)."""
    cmd: ControlCommand = controller.command(t_s, controller_estimate(t_s, x_hat, z_hat, age_s, flow_scale),
                                             RefSample(p_ref, v_ref, a_ref))
    return cmd


# ---- a command the coil can take, or a rejection ------------------------------------------------------------------
#: Codes of the loops' ``cmd_rejected`` column: why the tick's command was rejected (0: it was not).  A rejected
#: command reaches the coil as non-finite, so the coil ramps towards zero at the slew limit from that tick on.
REJECT_NONE, REJECT_NONFINITE, REJECT_ESTIMATE, REJECT_RAISED, REJECT_MALFORMED = 0, 1, 2, 3, 4
#: Words of each rejection code (the warning line of ``simulate`` and ``campaign`` names them).
REJECT_REASONS: dict[int, str] = {REJECT_NONFINITE: "non-finite", REJECT_ESTIMATE: "non-finite estimate",
                                  REJECT_RAISED: "the controller raised", REJECT_MALFORMED: "not a command"}
#: The controller statuses a command may carry (the ``cmd_status`` codes).
COMMAND_STATUSES = ("ok", "stale", "nonfinite")


def checked_command(controller: Any, t_s: float, x_hat: npt.NDArray[np.float64], z_hat: npt.NDArray[np.float64],
                    age_s: float, flow_scale: float, p_ref: npt.NDArray[np.float64], v_ref: npt.NDArray[np.float64],
                    a_ref: npt.NDArray[np.float64], dims: int = 2) -> tuple[ControlCommand, int, str]:
    """:func:`call_controller`, contained: ``(command, rejection code, detail)``; never raises for a bad command.

    * a non-finite estimate: the controller is not called (code :data:`REJECT_ESTIMATE`);
    * the controller raises (anything but a deliberate :class:`~vesselbot_ros.errors.VesselbotError`, which
      stops the run in one line as before): :data:`REJECT_RAISED`, ``detail`` names the exception;
    * it returns a :class:`ControlCommand` (or an object with its fields) whose gradient is not ``(dims,)`` or whose status is not one of
      :data:`COMMAND_STATUSES`, ``None`` or anything else: :data:`REJECT_MALFORMED`;
    * a bare array (or sequence) of ``dims`` numbers is a command (the gradient, T/m; ``u`` unknown: NaN);
    * a gradient with a NaN or an infinity: :data:`REJECT_NONFINITE`.

    A rejected command comes back with a NaN gradient (the coil's rejection: it ramps to zero) and status
    ``nonfinite``; a non-finite gradient keeps its values (the ``g_cmd`` column shows what was commanded).
    """
    nan = np.full(dims, np.nan)
    if not all(math.isfinite(float(v)) for v in (*x_hat, *z_hat)):
        return ControlCommand(nan, nan.copy(), "nonfinite"), REJECT_ESTIMATE, "non-finite estimate"
    try:
        cmd: Any = call_controller(controller, t_s, x_hat, z_hat, age_s, flow_scale, p_ref, v_ref, a_ref)
    except VesselbotError:
        raise
    except Exception as exc:  # noqa: BLE001 - a user's controller that raises is a rejected command, counted
        return ControlCommand(nan, nan.copy(), "nonfinite"), REJECT_RAISED, f"{type(exc).__name__}: {exc}"
    g: Any
    u: Any
    if isinstance(cmd, ControlCommand):
        g, u, status = cmd
    elif hasattr(cmd, "gradient_T_per_m"):  # a command of the user's own type, with the ControlCommand fields
        g, u, status = cmd.gradient_T_per_m, getattr(cmd, "u_m_per_s2", nan), getattr(cmd, "status", "ok")
    elif isinstance(cmd, (np.ndarray, list, tuple)):
        g, u, status = cmd, nan.copy(), "ok"
    else:
        return (ControlCommand(nan, nan.copy(), "nonfinite"), REJECT_MALFORMED,
                f"returned {type(cmd).__name__}, not a command")
    try:
        ga = np.array(g, dtype=np.float64).reshape(-1) if np.ndim(g) == 1 else None
        ua = np.array(u, dtype=np.float64).reshape(-1) if np.ndim(u) == 1 else None
    except (TypeError, ValueError):
        ga = ua = None
    if ga is None or ga.shape != (dims,):
        return (ControlCommand(nan, nan.copy(), "nonfinite"), REJECT_MALFORMED,
                f"gradient of shape {np.shape(g)}, expected ({dims},)")
    if ua is None or ua.shape != (dims,):
        ua = nan.copy()
    if status not in COMMAND_STATUSES:
        return (ControlCommand(nan, ua, "nonfinite"), REJECT_MALFORMED,
                f"status {status!r}, not one of {list(COMMAND_STATUSES)}")
    if not all(math.isfinite(v) for v in ga):
        return ControlCommand(ga, ua, "nonfinite"), REJECT_NONFINITE, "non-finite"
    return ControlCommand(ga, ua, status), REJECT_NONE, ""


def rejection_warning(metrics: Mapping[str, Any], what: str = "controller commands") -> str | None:
    """The one warning line of a run whose commands were rejected (None if none was), from its metrics."""
    n = int(metrics.get("rejected_commands") or 0)
    if n <= 0:
        return None
    reasons = str(metrics.get("rejected_command_reasons") or "rejected")
    for key in ("rejected_command_error", "rejected_command_malformed"):  # the first detail of each, per-tick loop
        if metrics.get(key):
            reasons += f"; first: {metrics[key]}"
    t0 = metrics.get("first_rejected_command_s")
    when = f" from t = {float(t0):.3f} s" if t0 is not None and math.isfinite(float(t0)) else ""
    total = metrics.get("n_ticks")
    of = f" of {int(total)}" if total is not None else ""
    return f"{n}{of} {what} rejected ({reasons}){when}; the coil ramped to zero"


# ---- the built-in kinds -----------------------------------------------------------------------------------------
# Each built-in kind builds one class for every vessel: its stage takes the axis count of the scenario (Scenario.dims: 3
# in a 3-D tree) or of the model; the scenario refuses the kinds and options that have no 3-D form yet, in one line.
def _plant(ctx: BuildContext) -> PlantSimulator:
    s = ctx.scenario
    return PlantSimulator(s.physics, s.sim.integrator, ctx.dt_s, s.initial.p0_m, s.initial.v0_m_per_s)


def _imager(ctx: BuildContext) -> ImagerModel | SequencedImager:
    s = ctx.scenario
    imager = ImagerModel(s.imager, ctx.rng(), dims=s.dims)
    if s.sequence.mode == "multiplexed":  # the scanner: imaging and propulsion take turns
        return SequencedImager(imager, s.sequence)
    return imager


def _mr_imager(ctx: BuildContext) -> Any:
    from vesselbot_ros.imaging.imager_stage import MrImager  # deferred: the trackers' scipy.optimize, where it is built

    s = ctx.scenario
    return MrImager(s.imager, s.physics, s.sequence, ctx.rng(), dims=s.dims, tick_s=ctx.dt_s)


def _check_mr_images(params: MrImagerParams, scenario: Any) -> None:
    """An acquisition fits the time it is given: a tracking window (multiplexed), or a frame period (continuous)."""
    imaging = params.imaging
    what = f"imager.preset {params.preset!r}" if params.preset else "imager.acquisition"
    takes = f"takes {imaging.frame_time_s:.4g} s per frame ({imaging.acquisition}, {imaging.matrix} x " \
            f"{imaging.repetition_time_s:.4g} s TR)" if imaging.acquisition == "slice" else \
            f"takes {imaging.frame_time_s:.4g} s per frame (3 x {imaging.repetition_time_s:.4g} s TR)"
    if scenario.sequence.mode == "multiplexed":
        if imaging.frame_time_s > scenario.sequence.tracking_window_s * (1.0 + 1e-9):
            raise ConfigError(f"{what} {takes}: longer than sequence.tracking_window_s "
                              f"({scenario.sequence.tracking_window_s!r} s)")
    elif imaging.frame_time_s > (1.0 + 1e-9) / params.frame_rate_Hz:
        raise ConfigError(f"{what} {takes}: longer than the frame period 1 / imager.frame_rate_Hz "
                          f"({1.0 / params.frame_rate_Hz:.4g} s)")


def _dipole_fit(ctx: BuildContext) -> Any:
    from vesselbot_ros.imaging.imager_stage import DipoleFitTracker  # deferred: scipy.optimize, where it is built

    s = ctx.scenario
    if not isinstance(s.imager, MrImagerParams):
        raise ConfigError(f"tracker.kind: 'dipole_fit' tracks the frames of the 'mr_images' imager, not of "
                          f"imager.kind {s.imager.kind!r}")
    return DipoleFitTracker(ctx.params, s.imager.imaging, s.physics.robot, s.imager.vessel_diameter_m, s.dims)


def make_observer(params: ObserverParams, model: DynamicsModel, x_hat0: npt.ArrayLike, z_hat0: npt.ArrayLike,
                  tick_s: float) -> HighGainObserver | ExtendedKalmanObserver:
    """The built-in observer ``params.kind`` selects: high-gain (25) or the extended Kalman filter, prior at t = 0."""
    if params.kind == "ekf":
        return ExtendedKalmanObserver(params.ekf, model, x_hat0, z_hat0, 0.0, tick_s)
    return HighGainObserver(params, model, x_hat0, z_hat0, 0.0)


def _observer(ctx: BuildContext) -> HighGainObserver | ExtendedKalmanObserver:
    s = ctx.scenario
    return make_observer(s.observer, ctx.model, ctx.get("reference").sample(0.0).p, s.initial.z_hat0_m_per_s, ctx.dt_s)


def _reference(ctx: BuildContext) -> ReferenceTrajectory:
    phys = ctx.get("model_physics")
    p_model, packed = packed_vessel(phys, ctx.scenario.dims)
    geom = vessel_geom(p_model, packed)  # the model's vessel: what the controller believes
    still_p = p_model.copy()
    still_p[I_D_PULSE] = 0.0
    still = vessel_geom(still_p, packed)  # its wall at rest

    def flow(t: float, p: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        return np.asarray(blood_velocity(t, np.ascontiguousarray(p, dtype=np.float64), geom))

    def offset(points: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        return np.asarray(floor_offsets(np.ascontiguousarray(points, dtype=np.float64), still))

    motion = WallMotion(offset, float(p_model[I_D_PULSE]), float(p_model[I_OMEGA_F]), float(p_model[I_PHI_F]))
    return ReferenceTrajectory(planned_reference(ctx.scenario), flow_velocity=flow, wall_shift=wall_shift_of(phys),
                               wall_motion=motion)


def _controller(ctx: BuildContext) -> BacksteppingController:
    s = ctx.scenario
    model = ctx.model
    return BacksteppingController(s.controller, model.F, model.input_matrix, ctx.dt_s, duty_cycle(s.sequence))


def _predictive(ctx: BuildContext) -> PredictiveController:
    s = ctx.scenario
    return PredictiveController(s.controller, ctx.model, effective_coil_limits(s.coil, s.dbdt, axes=s.dims), s.sequence,
                                ctx.dt_s)


def _action_replay(ctx: BuildContext) -> ActionReplayController:
    return ActionReplayController(load_actions(ctx.params.actions_file, ctx.scenario.dims), ctx.dt_s)


def _policy(ctx: BuildContext) -> PolicyController:
    s = ctx.scenario
    return PolicyController(load_policy(ctx.params.policy), _coil(ctx), s.sequence, s.dims)  # its own replica of the coil


def _check_high_gain(params: ObserverParams, scenario: Any) -> None:
    """Observer (25) is stable at the rate it gets frames: the MRI imager's ``frame_rate_Hz``, or one frame per
    sequence period under multiplexing (:func:`~vesselbot_ros.control.high_gain_observer.check_frame_period`)."""
    if not isinstance(scenario.imager, ImagerParams):
        return  # a user's imager: its frames' rate is its own
    if scenario.sequence.mode == "multiplexed":
        check_frame_period(params, scenario.sequence.period_s)
    else:
        rate = scenario.imager.frame_rate_Hz
        check_frame_period(params, 1.0 / rate, rate)


def _coil(ctx: BuildContext) -> CoilLimiter | SequencedCoil:
    s = ctx.scenario
    # The coil was idle (zero) before t = 0 and ramps during the period before the first command, exactly as
    # between any two later ticks: the first command may move S * dt, not 0 (which left the robot unactuated for
    # the first 1 ms and cost ~350 um of start-up transient, docs/control.md).
    # Its axes are the scenario's (a 3-D tree's dB/dt counts three axes slewing at once).
    coil = CoilLimiter(effective_coil_limits(s.coil, s.dbdt, axes=s.dims), -ctx.dt_s, dims=s.dims)
    if s.sequence.mode == "multiplexed":
        return SequencedCoil(coil, s.sequence, ctx.dt_s)
    return coil


for _kind in (
    StageKind("plant", "vessel", PhysicsParams, _plant, compiled=True, stage_types=(PlantSimulator,),
              compile=lambda stage: stage.compiled(),
              summary="the vessel physics of the paper (eq. (1)): a straight vessel or a meshed network"),
    StageKind("imager", "mri", ImagerParams, _imager, compiled=True,
              stage_types=(ImagerModel, SequencedImager), compile=lambda stage: stage.compiled(),
              summary="MRI tracking: Gaussian noise, latency, frame rate, aberrant frames, dropouts; the sequence's windows"),
    StageKind("imager", "mr_images", MrImagerParams, _mr_imager, compiled=False, frames=True, check=_check_mr_images,
              summary="MR frames synthesised from the bead's field (a slice or MS-SET projections); per tick"),
    StageKind("tracker", "dipole_fit", TrackerParams, _dipole_fit, compiled=False,
              summary="the bead's position in each MR frame: a fit of its dipole artefact (projection peaks for MS-SET)"),
    StageKind("observer", "high_gain", ObserverParams, _observer, compiled=True, stage_types=(HighGainObserver,),
              summary="high-gain observer (25)", compile=HighGainObserver.compiled, check=_check_high_gain),
    StageKind("observer", "ekf", ObserverParams, _observer, compiled=True, stage_types=(ExtendedKalmanObserver,),
              summary="extended Kalman filter: delay compensation, blood-velocity scale estimate",
              compile=ExtendedKalmanObserver.compiled),
    StageKind("reference", "bspline", ReferenceParams, _reference, compiled=True, stage_types=(ReferenceTrajectory,),
              compile=lambda stage: stage.compiled(),
              summary="C2 cubic B-spline through the anchors (or the planned route of a network)"),
    StageKind("controller", "backstepping", ControllerParams, _controller, compiled=True,
              stage_types=(BacksteppingController,), summary="backstepping law (24)",
              compile=BacksteppingController.compiled),
    StageKind("controller", "adaptive_backstepping", ControllerParams, _controller, compiled=True,
              stage_types=(BacksteppingController,),
              summary="law (24) with on-line blood-velocity and magnetisation scales",
              compile=BacksteppingController.compiled),
    StageKind("controller", "predictive", PredictiveParams, _predictive, compiled=True,
              stage_types=(PredictiveController,), compile=PredictiveController.compiled,
              summary="plans each propulsion window for the coast after it (the model, the coil and the sequence)"),
    StageKind("controller", "action_replay", ActionReplayParams, _action_replay, compiled=True,
              stage_types=(ActionReplayController,), compile=ActionReplayController.compiled,
              summary="replays recorded gradient commands, one per tick (an environment episode's actions, a .npy file)"),
    StageKind("controller", "policy", PolicyParams, _policy, compiled=False, stage_types=(PolicyController,),
              summary="a user's policy (module:callable) from the environments' observation to the gradient"),
    StageKind("coil", "gradient_coil", CoilLimits, _coil, compiled=True,
              stage_types=(CoilLimiter, SequencedCoil), compile=lambda stage: stage.compiled(),
              summary="gradient saturation, slew and dB/dt; gated by the sequence's propulsion windows"),
):
    register(_kind)
