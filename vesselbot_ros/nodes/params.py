"""Scenario <-> ROS parameters: one schema, the same validation as the pure core.

Every vesselbot node declares the *whole* :class:`~vesselbot_ros.sim.scenario.Scenario`
as ROS parameters with dotted names (``imager.noise_sigma_m``,
``sim.control_rate_Hz``, ...), reads them back, and builds the Scenario with
:func:`~vesselbot_ros.sim.scenario.scenario_from_mapping`: the very loader that
validates ``config/*.yaml`` for the pure runner.  A bad value therefore fails
with the same message in both worlds, naming the dotted parameter.

ROS parameters hold scalars and homogeneous arrays only.  Fields that are
neither (``model.overrides``, a mapping with free keys; ``imager.outliers``, a
list of records) are declared as *YAML strings*, e.g.::

    imager.outliers: "[{start_s: 0.5, duration_s: 0.02, magnitude_m: 0.001}]"
    model.overrides: "{flow: {centreline_velocity_m_per_s: 0.02625}}"

:func:`scenario_to_parameters` writes a Scenario in exactly this form (the
launcher uses it to write a ``--params-file``), and
:func:`scenario_from_parameters` reads it back: the round trip is exact.

No rclpy import here.
"""

from __future__ import annotations

import dataclasses
import json
import math
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from vesselbot_ros.atomic_io import write_text
from vesselbot_ros.config import RESOLVE_TYPE, ConfigError, parse_yaml_text, to_mapping, unflatten
from vesselbot_ros.sim.kinds import DEFAULT_KINDS, ROLES, SECTIONS, find
from vesselbot_ros.sim.scenario import Scenario, scenario_from_mapping

__all__ = [
    "ParamSpec",
    "scenario_schema",
    "kind_parameters",
    "scenario_to_parameters",
    "scenario_from_parameters",
    "write_params_file",
]


@dataclasses.dataclass(frozen=True)
class ParamSpec:
    """One declared parameter.

    Attributes:
        name: Dotted parameter name (``imager.noise_sigma_m``).
        default: Default ROS value (already encoded).
        yaml_encoded: True if the ROS value is a YAML string standing for a
            mapping or a list of records.
    """

    name: str
    default: Any
    yaml_encoded: bool


def _is_scalar_type(tp: Any) -> bool:
    origin = typing.get_origin(tp)
    if origin is typing.Literal:
        return True
    return tp in (float, int, bool, str)


def _is_scalar_array(tp: Any) -> bool:
    if typing.get_origin(tp) is not tuple:
        return False
    return all(a is Ellipsis or a in (float, int, bool, str) for a in typing.get_args(tp))


def _field_default(f: dataclasses.Field[Any]) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    raise ConfigError(f"parameter {f.name!r} has no default: a stage kind run in the graph gives every parameter one")


def _walk(cls: type, prefix: str, value: Any, out: dict[str, ParamSpec], section_kinds: Mapping[str, type] | None = None) -> None:
    """Declare ``cls``'s fields under ``prefix``, with ``value``'s values (None: the fields' defaults).

    A stage's section (:mod:`vesselbot_ros.sim.kinds`) is walked as its kind's dataclass: the value's type, or
    ``section_kinds[name]`` for a schema of defaults.
    """
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        name = f"{prefix}{f.name}"
        v = _field_default(f) if value is None else getattr(value, f.name)
        if RESOLVE_TYPE in f.metadata:
            tp = type(v) if value is not None else (section_kinds or {}).get(name, tp)
            if value is None:
                v = None
        if isinstance(tp, type) and dataclasses.is_dataclass(tp):
            _walk(tp, name + ".", v, out)
        elif _is_scalar_type(tp):
            out[name] = ParamSpec(name, v, False)
        elif _is_scalar_array(tp) and len(v) > 0:
            out[name] = ParamSpec(name, list(v), False)
        else:
            out[name] = ParamSpec(name, _encode(v), True)


def _encode(value: Any) -> str:
    # JSON is YAML, and it is compact and unambiguous (None -> null, () -> []).
    return json.dumps(to_mapping(value), separators=(", ", ": "))


_SCHEMAS: dict[tuple[tuple[str, str], ...], dict[str, ParamSpec]] = {}


def kind_parameters() -> dict[str, str]:
    """The parameter naming each stage's kind (``controller.kind`` ...), with the built-in default kind.

    A node declares these first: the kinds they name decide the rest of the schema (:func:`scenario_schema`).
    """
    return {f"{SECTIONS[role]}.kind": DEFAULT_KINDS[role] for role in ROLES}


def scenario_schema(stage_kinds: Mapping[str, str] | None = None) -> dict[str, ParamSpec]:
    """Every scenario parameter, by dotted name, with its default (cached per set of kinds).

    Args:
        stage_kinds: ``{"controller.kind": "my_mod:MyController", ...}`` (the values of
            :func:`kind_parameters`); missing sections take the built-in default kind.

    Raises:
        ConfigError: a kind that cannot be found (named by its parameter).
    """
    given = dict(kind_parameters(), **(stage_kinds or {}))
    key = tuple(sorted(given.items()))
    hit = _SCHEMAS.get(key)
    if hit is None:
        classes = {}
        for role in ROLES:
            pname = f"{SECTIONS[role]}.kind"
            classes[SECTIONS[role]] = find(role, given[pname], pname).params
        hit = {}
        _walk(Scenario, "", None, hit, classes)
        for role in ROLES:  # the kind's own name is the section's kind
            pname = f"{SECTIONS[role]}.kind"
            hit[pname] = ParamSpec(pname, given[pname], False)
        _SCHEMAS[key] = hit
    return hit


def scenario_to_parameters(scenario: Scenario) -> dict[str, Any]:
    """Encode a Scenario as flat ROS parameter values (dotted names)."""
    out: dict[str, ParamSpec] = {}
    _walk(Scenario, "", scenario, out)
    return {k: s.default for k, s in out.items()}


def _decode(name: str, value: Any, spec: ParamSpec) -> Any:
    if spec.yaml_encoded and isinstance(value, str):
        # the project's one YAML reader: JSON's 4e-19 is a float here, as in a scenario file
        return parse_yaml_text(value, source=f"parameter {name}")
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"{name} must be finite, got {value!r}")
    return value


def scenario_from_parameters(values: Mapping[str, Any]) -> Scenario:
    """Build and validate the Scenario from flat parameter values.

    Args:
        values: Dotted parameter name -> ROS value (a subset of
            :func:`scenario_schema`; missing names take their defaults).

    Raises:
        ConfigError: unknown name, wrong type, or a value the dataclasses
            reject; the message names the dotted parameter and the value.
    """
    schema = scenario_schema({k: v for k, v in values.items() if k in kind_parameters() and isinstance(v, str)})
    flat: dict[str, Any] = {}
    for name, value in values.items():
        spec = schema.get(name)
        if spec is None:
            raise ConfigError(f"unknown parameter {name!r} (value {value!r})")
        decoded = _decode(name, value, spec)
        if isinstance(decoded, list) and not spec.yaml_encoded:
            decoded = list(decoded)
        flat[name] = decoded
    return scenario_from_mapping(unflatten(flat))


def write_params_file(path: str | Path, parameters: Mapping[str, Any], node_name: str = "/**") -> Path:
    """Write a ROS ``--params-file`` holding ``parameters`` for ``node_name``."""
    p = Path(path)
    data = {node_name: {"ros__parameters": dict(parameters)}}
    return write_text(p, yaml.safe_dump(data, sort_keys=False, width=10**6))
