"""Validated, frozen configuration: one loader for YAML files and ROS parameters.

Every configuration concept in vesselbot_ros is a frozen dataclass whose
``__post_init__`` validates its fields.  This module is the single place that
turns plain mappings (parsed YAML, or flattened ROS parameters) into those
dataclasses:

* unknown keys are errors (typos must not silently fall back to defaults);
* values are type-checked and coerced (int -> float, list -> tuple);
* nested dataclasses are loaded recursively;
* every error is a :class:`ConfigError` that names the dotted field path,
  the offending value and the rule, e.g.
  ``robot.radius_m must be > 0, got -0.00025``.

Nothing here imports rclpy: nodes flatten their ROS parameters with
:func:`flatten` / :func:`unflatten` and pass them through the same loader.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

T = TypeVar("T")

__all__ = [
    "ConfigError",
    "check_finite",
    "check_positive",
    "check_nonnegative",
    "check_range",
    "check_choice",
    "load_dataclass",
    "load_yaml",
    "parse_yaml_text",
    "to_mapping",
    "flatten",
    "unflatten",
]


class ConfigError(ValueError):
    """A configuration value is missing, unknown, of the wrong type or out of range.

    The message always names the field (dotted path) and the offending value.
    """


# ---------------------------------------------------------------------------
# Field validators, for use in ``__post_init__``.  ``name`` is the field name
# as the user wrote it; the loader prefixes the section path on re-raise.
# ---------------------------------------------------------------------------


def check_finite(name: str, value: float) -> None:
    """Raise ConfigError unless ``value`` is a finite real number."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ConfigError(f"{name} must be finite, got {value!r}")


def check_positive(name: str, value: float) -> None:
    """Raise ConfigError unless ``value`` is finite and > 0."""
    check_finite(name, value)
    if value <= 0:
        raise ConfigError(f"{name} must be > 0, got {value!r}")


def check_nonnegative(name: str, value: float) -> None:
    """Raise ConfigError unless ``value`` is finite and >= 0."""
    check_finite(name, value)
    if value < 0:
        raise ConfigError(f"{name} must be >= 0, got {value!r}")


def check_range(
    name: str,
    value: float,
    lo: float,
    hi: float,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
) -> None:
    """Raise ConfigError unless ``lo <=/< value <=/< hi``."""
    check_finite(name, value)
    bad_lo = value <= lo if lo_open else value < lo
    bad_hi = value >= hi if hi_open else value > hi
    if bad_lo or bad_hi:
        lb = "(" if lo_open else "["
        rb = ")" if hi_open else "]"
        raise ConfigError(f"{name} must be in {lb}{lo}, {hi}{rb}, got {value!r}")


def check_choice(name: str, value: str, choices: typing.Iterable[str]) -> None:
    """Raise ConfigError unless ``value`` is one of ``choices``."""
    choices = tuple(choices)
    if value not in choices:
        raise ConfigError(f"{name} must be one of {list(choices)}, got {value!r}")


# ---------------------------------------------------------------------------
# Loader
# ---------------------------------------------------------------------------


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", str(tp))


def _coerce(path: str, tp: Any, value: Any) -> Any:
    """Coerce ``value`` to the annotated type ``tp`` or raise ConfigError."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)

    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(path, arg, value)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if len(errors) == 1 else f"{path}: no variant matches {value!r}")
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f"{path} must be one of {list(args)}, got {value!r}")
        return value
    if dataclasses.is_dataclass(tp):
        return load_dataclass(tp, value, path)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{path} must be a number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ConfigError(f"{path} must be an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{path} must be true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{path} must be a string, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{path} must be a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(f"{path}[{i}]", args[0], v) for i, v in enumerate(value))
        if len(args) != len(value):
            raise ConfigError(f"{path} must have {len(args)} elements, got {value!r}")
        return tuple(_coerce(f"{path}[{i}]", a, v) for i, (a, v) in enumerate(zip(args, value)))
    if origin in (dict, Mapping) or tp is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(f"{path} must be a mapping, got {value!r}")
        return dict(value)
    raise ConfigError(f"{path}: unsupported field type {_type_name(tp)}")


def load_dataclass(cls: type[T], data: Any, path: str = "") -> T:
    """Build the frozen dataclass ``cls`` from a plain mapping, strictly.

    Args:
        cls: A dataclass type whose fields are annotated with float, int, bool,
            str, Literal, tuple, Optional or nested dataclasses.
        data: Mapping of field name to value (``None`` means "all defaults").
        path: Dotted prefix used in error messages (e.g. ``"robot"``).

    Returns:
        An instance of ``cls``; its ``__post_init__`` validation has run.

    Raises:
        ConfigError: on unknown keys, missing required keys, wrong types or a
            validation failure; the message names ``path.field`` and the value.
    """
    if data is None:
        data = {}
    if isinstance(data, cls):
        return data
    if not isinstance(data, Mapping):
        where = path or _type_name(cls)
        raise ConfigError(f"{where} must be a mapping, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    prefix = f"{path}." if path else ""
    if unknown:
        raise ConfigError(
            f"unknown key {prefix}{unknown[0]!s} (value {data[unknown[0]]!r}); "
            f"allowed keys: {sorted(fields)}"
        )
    kwargs: dict[str, Any] = {}
    for name, field in fields.items():
        if name in data:
            kwargs[name] = _coerce(f"{prefix}{name}", hints[name], data[name])
        elif field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
            raise ConfigError(f"missing required key {prefix}{name}")
    try:
        return cls(**kwargs)
    except ConfigError as exc:
        msg = str(exc)
        if prefix and not msg.startswith(prefix):
            msg = prefix + msg
        raise ConfigError(msg) from None


def to_mapping(obj: Any) -> Any:
    """Inverse of :func:`load_dataclass`: dataclass -> plain YAML-able mapping."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_mapping(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_mapping(v) for v in obj]
    if isinstance(obj, Mapping):
        return {k: to_mapping(v) for k, v in obj.items()}
    return obj


class _Loader(yaml.SafeLoader):
    """SafeLoader that reads ``1e-6`` and ``1.72e6`` as floats.

    PyYAML implements YAML 1.1, whose float pattern needs a dot and a signed
    exponent, so ``1e-6`` would silently load as the *string* "1e-6".
    """


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)


def parse_yaml_text(text: str) -> Any:
    """Parse YAML text with the project's float-aware loader (see :class:`_Loader`)."""
    return yaml.load(text, Loader=_Loader)  # noqa: S506 - _Loader is a SafeLoader


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping from ``path`` with a clear error for every failure mode."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"config file {str(p)!r} does not exist")
    try:
        data = parse_yaml_text(p.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise ConfigError(f"config file {str(p)!r} is not valid YAML: {exc}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"config file {str(p)!r} must hold a mapping at top level, got {type(data).__name__}")
    return data


def flatten(mapping: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Flatten nested mappings to dotted keys (ROS parameter names)."""
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten(value, name + "."))
        else:
            out[name] = value
    return out


def unflatten(flat: Mapping[str, Any]) -> dict[str, Any]:
    """Inverse of :func:`flatten`."""
    out: dict[str, Any] = {}
    for key, value in flat.items():
        parts = key.split(".")
        node = out
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(f"parameter {key!r} conflicts with a scalar at {part!r}")
        node[parts[-1]] = value
    return out
