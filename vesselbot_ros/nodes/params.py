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

from vesselbot_ros.config import ConfigError, parse_yaml_text, to_mapping, unflatten
from vesselbot_ros.sim.scenario import Scenario, scenario_from_mapping

__all__ = [
    "ParamSpec",
    "scenario_schema",
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


def _walk(cls: type, prefix: str, value: Any, out: dict[str, ParamSpec]) -> None:
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        name = f"{prefix}{f.name}"
        v = getattr(value, f.name)
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


_SCHEMA: dict[str, ParamSpec] | None = None


def scenario_schema() -> dict[str, ParamSpec]:
    """Every scenario parameter, by dotted name, with its default (cached)."""
    global _SCHEMA
    if _SCHEMA is None:
        out: dict[str, ParamSpec] = {}
        _walk(Scenario, "", Scenario(), out)
        _SCHEMA = out
    return _SCHEMA


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
    schema = scenario_schema()
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
    p.write_text(yaml.safe_dump(data, sort_keys=False, width=10**6), encoding="utf-8")
    return p
