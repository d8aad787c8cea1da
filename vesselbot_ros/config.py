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

Configuration files are found the same way by every command
(:func:`resolve_config_path`): a path that exists, else a shipped file by name
(``sound_small_artery``) or by its repository path (``config/...``), looked up
in :func:`shipped_config_dir`, so every ``vesselbot`` command works from any
directory, from a checkout as from an installed wheel.

Nothing here imports rclpy: nodes flatten their ROS parameters with
:func:`flatten` / :func:`unflatten` and pass them through the same loader.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import math
import os
import re
import sys
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

from vesselbot_ros.errors import ConfigError  # defined with the package's error root; re-exported here

T = TypeVar("T")

#: Field metadata key of :func:`load_dataclass`: ``resolve(value, dotted_key) -> dataclass type`` picks the
#: field's dataclass from its value (a stage's scenario section, by its ``kind``: :mod:`vesselbot_ros.sim.kinds`).
RESOLVE_TYPE = "vesselbot_resolve_type"

#: Field metadata key of :func:`to_mapping`: ``omit(value) -> bool``; a field whose value it calls omittable is
#: left out of the mapping (an optional key added later, e.g. a branch's ``y_m``, so that the mappings -- and the
#: hashes taken of them -- of files without it stay what they were).
OMIT_IF = "vesselbot_omit_if"

__all__ = [
    "ConfigError",
    "RESOLVE_TYPE",
    "OMIT_IF",
    "check_finite",
    "check_positive",
    "check_nonnegative",
    "check_range",
    "check_choice",
    "load_dataclass",
    "load_yaml",
    "parse_yaml_text",
    "parse_set_items",
    "apply_overrides",
    "to_mapping",
    "flatten",
    "unflatten",
]


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
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
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
            str, Literal, tuple, Optional or nested dataclasses.  A field whose
            metadata has :data:`RESOLVE_TYPE` gets the dataclass that resolver
            returns for its value (a stage's section, chosen by its ``kind``).
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
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]  # cls: a dataclass type
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
            # a field whose dataclass depends on its value (a stage's section, by its ``kind``) names a resolver
            resolve = field.metadata.get(RESOLVE_TYPE)
            tp = resolve(data[name], f"{prefix}{name}") if resolve is not None else hints[name]
            kwargs[name] = _coerce(f"{prefix}{name}", tp, data[name])
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
    """Inverse of :func:`load_dataclass`: dataclass -> plain YAML-able mapping.

    A field whose metadata's :data:`OMIT_IF` calls its value omittable is left out.
    """
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_mapping(getattr(obj, f.name)) for f in dataclasses.fields(obj)
                if not (OMIT_IF in f.metadata and f.metadata[OMIT_IF](getattr(obj, f.name)))}
    if isinstance(obj, (list, tuple)):
        return [to_mapping(v) for v in obj]
    if isinstance(obj, Mapping):
        return {k: to_mapping(v) for k, v in obj.items()}
    return obj


# Bounds on what the loaders parse: a scenario is a few kB, a handful of levels
# deep, and never needs more than a few thousand values.
MAX_CONFIG_BYTES = 1 << 20
MAX_CONFIG_DEPTH = 32
MAX_CONFIG_NODES = 100_000


class _Loader(yaml.SafeLoader):
    """SafeLoader that reads ``1e-6`` and ``1.72e6`` as floats, refuses duplicate keys and bounds its input.

    PyYAML implements YAML 1.1, whose float pattern needs a dot and a signed
    exponent, so ``1e-6`` would silently load as the *string* "1e-6".  It also
    silently keeps the last of two equal keys; here that is an error naming the
    key and both lines.  Nesting deeper than :data:`MAX_CONFIG_DEPTH` is
    refused while composing (before Python's recursion limit is reached).
    """

    _depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        self._depth += 1
        try:
            if self._depth > MAX_CONFIG_DEPTH:
                mark = self.peek_event().start_mark
                raise yaml.YAMLError(
                    f"nesting deeper than {MAX_CONFIG_DEPTH} levels at line {mark.line + 1} column {mark.column + 1}"
                )
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if not isinstance(key_node, yaml.ScalarNode):
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.get(key)
                except TypeError:
                    continue
                if first is not None:
                    raise yaml.YAMLError(
                        f"duplicate key {key!r} at line {first.start_mark.line + 1} "
                        f"and line {key_node.start_mark.line + 1}"
                    )
                seen[key] = key_node
        return super().construct_mapping(node, deep=deep)


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


def _expanded_size(node: Any, limit: int) -> int:
    """Nodes in ``node`` with every alias expanded; raise past ``limit`` or on a cycle."""
    memo: dict[int, int] = {}
    active: set[int] = set()

    def size(n: Any) -> int:
        key = id(n)
        if key in memo:
            return memo[key]
        if key in active:
            mark = n.start_mark
            raise yaml.YAMLError(f"recursive alias at line {mark.line + 1} column {mark.column + 1}")
        total = 1
        if isinstance(n, (yaml.SequenceNode, yaml.MappingNode)):
            active.add(key)
            for child in n.value:
                parts = child if isinstance(child, tuple) else (child,)
                for part in parts:
                    total += size(part)
                    if total > limit:
                        raise yaml.YAMLError(
                            f"more than {limit} values once aliases are expanded (a self-expanding document?)"
                        )
            active.discard(key)
        memo[key] = total
        return total

    return size(node)


def _where(exc: yaml.YAMLError) -> str:
    """``line L column C: problem`` from a PyYAML error (no Python repr, no Mark object)."""
    mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
    problem = getattr(exc, "problem", None) or getattr(exc, "context", None)
    if isinstance(exc, yaml.reader.ReaderError):
        return f"character {exc.position}: {exc.reason} (not a text file?)"
    if problem is None:
        return str(exc)
    if mark is None:
        return str(problem)
    return f"line {mark.line + 1} column {mark.column + 1}: {problem}"


def parse_yaml_text(text: str, source: str = "YAML text") -> Any:
    """Parse YAML text with the project's one loader (see :class:`_Loader`).

    This is the only YAML reader of configuration values: scenario files,
    ``--set KEY=VALUE`` values and the YAML-encoded ROS parameters all go
    through it, so ``1e-6`` is a float everywhere.  Size, nesting depth and
    alias expansion are bounded (:data:`MAX_CONFIG_BYTES`,
    :data:`MAX_CONFIG_DEPTH`, :data:`MAX_CONFIG_NODES`).

    Raises:
        ConfigError: naming ``source``, the line and the column.
    """
    if len(text) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{source} is {len(text)} characters; a configuration is at most {MAX_CONFIG_BYTES}")
    loader = None
    try:
        loader = _Loader(text)
        node = loader.get_single_node()
        if node is None:
            return None
        _expanded_size(node, MAX_CONFIG_NODES)
        return loader.construct_document(node)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source} is not valid YAML: {_where(exc)}") from None
    except RecursionError:
        raise ConfigError(f"{source} is nested too deeply") from None
    finally:
        if loader is not None:
            loader.dispose()


def shipped_config_dir() -> Path:
    """The folder of the shipped configuration files (scenarios, parameter sets, campaigns).

    From a checkout (``make``, an editable install) it is the repository's
    ``config/``; from an installed wheel it is ``<prefix>/share/vesselbot_ros/config``,
    where ``setup.py`` installs the same files (the ament layout colcon uses too).
    """
    src = Path(__file__).resolve().parents[1] / "config"
    if src.is_dir() and (src.parent / "setup.py").is_file():
        return src
    return Path(sys.prefix) / "share" / "vesselbot_ros" / "config"


def resolve_config_path(path: str | Path) -> Path:
    """``path`` if it is a file; else the shipped file it names; else ``path`` unchanged.

    A bare name (``sound_small_artery`` or ``sound_small_artery.yaml``) and a
    repository path (``config/campaigns/x.yaml``) are looked up in
    :func:`shipped_config_dir`.
    """
    p = Path(path).expanduser()
    if p.is_file():
        return p
    text = str(path)
    d = shipped_config_dir()
    candidates: list[Path] = []
    if text and "/" not in text and os.sep not in text:
        candidates += [d / text, d / f"{text}.yaml"]
    parts = Path(text).parts
    if not p.is_absolute() and len(parts) > 1 and parts[0] == "config":
        candidates.append(d.joinpath(*parts[1:]))
    return next((c for c in candidates if c.is_file()), p)


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Read a non-empty YAML mapping from ``path`` (or a shipped file it names, :func:`resolve_config_path`).

    Refused, each with one line naming the file: a missing file, a file larger
    than :data:`MAX_CONFIG_BYTES`, one that is not UTF-8 text, invalid YAML
    (line and column), duplicate keys (both lines), nesting or alias
    expansion past the bounds of :func:`parse_yaml_text`, an empty document
    and a document that is not a mapping.
    """
    p = resolve_config_path(path)
    if not p.is_file():
        names = ""
        if shipped_config_dir().is_dir():
            names = "; shipped: " + ", ".join(sorted(q.stem for q in shipped_config_dir().glob("*.yaml")))
        raise ConfigError(f"config file {str(p)!r} does not exist{names}")
    try:
        size = p.stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise ConfigError(f"config file {str(p)!r} is {size} bytes; a configuration is at most {MAX_CONFIG_BYTES}")
        raw = p.read_bytes()
    except OSError as exc:
        raise ConfigError(f"config file {str(p)!r} cannot be read: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"config file {str(p)!r} is not UTF-8 text (byte {exc.start}); is it a YAML file?") from None
    key = (str(p), hashlib.sha256(raw).digest())
    hit = _PARSED.get(key)
    if hit is not None:
        return copy.deepcopy(hit)  # the caller may change its copy
    data = parse_yaml_text(text, source=f"config file {str(p)!r}")
    if data is None or data == {}:
        raise ConfigError(f"config file {str(p)!r} is empty; it must hold a mapping of configuration keys")
    if not isinstance(data, dict):
        raise ConfigError(f"config file {str(p)!r} must hold a mapping at top level, got {type(data).__name__}")
    if len(_PARSED) >= _PARSED_MAX:
        _PARSED.pop(next(iter(_PARSED)))
    _PARSED[key] = copy.deepcopy(data)
    return data


#: Mappings :func:`load_yaml` parsed, by file and content (sha256 of its bytes: a file rewritten is parsed again):
#: the YAML parser is pure Python (a large scenario file takes tens of milliseconds), and a process reads the
#: same shipped files many times.
_PARSED: dict[tuple[str, bytes], dict[str, Any]] = {}
_PARSED_MAX = 128


def parse_set_items(items: typing.Iterable[str], option: str = "--set") -> dict[str, Any]:
    """Parse ``KEY=VALUE`` strings into ``{dotted key: value}`` (VALUE read by :func:`parse_yaml_text`).

    Raises:
        ConfigError: on a missing ``=``, an empty key or a value that is not YAML.
    """
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key or any(not part for part in key.split(".")):
            raise ConfigError(f"{option} expects KEY=VALUE with a dotted KEY, got {item!r}")
        out[key] = parse_yaml_text(value, source=f"{option} {key}")
    return out


def apply_overrides(mapping: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """Return a copy of ``mapping`` with each dotted key of ``overrides`` set to its value.

    The one override path of every command (``--set``, ``--duration``,
    ``--seed``): a value *replaces* what is at its key, so ``model.overrides={}``
    clears a mapping instead of being merged into it.  Missing intermediate
    mappings are created; the result is validated later by the loader, which
    rejects unknown keys.

    Raises:
        ConfigError: if a key runs through a value that is not a mapping.
    """
    out = _copy_tree(mapping)
    for dotted, value in overrides.items():
        parts = dotted.split(".")
        node = out
        for i, part in enumerate(parts[:-1]):
            child = node.get(part)
            if child is None:
                child = node[part] = {}
            if not isinstance(child, dict):
                where = ".".join(parts[: i + 1])
                raise ConfigError(f"cannot set {dotted}: {where} is {child!r}, not a mapping")
            node = child
        node[parts[-1]] = _copy_tree(value)
    return out


def _copy_tree(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: _copy_tree(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_copy_tree(v) for v in value]
    return value


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
