"""The strict loader: unknown keys, wrong types, range checks, nesting, round trip."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import pytest

from vesselbot_ros.config import (
    ConfigError,
    check_positive,
    check_range,
    flatten,
    load_dataclass,
    load_yaml,
    to_mapping,
    unflatten,
)


@dataclass(frozen=True)
class Inner:
    radius_m: float = 2.5e-4
    ratio: float = 0.15

    def __post_init__(self) -> None:
        check_positive("radius_m", self.radius_m)
        check_range("ratio", self.ratio, 0.0, 1.0, hi_open=True)


@dataclass(frozen=True)
class Outer:
    name: str = "x"
    count: int = 3
    mode: Literal["a", "b"] = "a"
    anchors: tuple[tuple[float, float], ...] = ((0.0, 1.0),)
    inner: Inner = field(default_factory=Inner)


def test_defaults_and_coercion():
    cfg = load_dataclass(Outer, {"count": 4.0, "inner": {"radius_m": 1}, "anchors": [[0, 1], [2, 3.5]]})
    assert cfg.count == 4 and isinstance(cfg.count, int)
    assert cfg.inner.radius_m == 1.0 and isinstance(cfg.inner.radius_m, float)
    assert cfg.anchors == ((0.0, 1.0), (2.0, 3.5))


def test_unknown_key_names_the_dotted_path_and_value():
    with pytest.raises(ConfigError, match=r"unknown key inner\.radius \(value 3\)"):
        load_dataclass(Outer, {"inner": {"radius": 3}})


def test_wrong_type_names_the_key():
    with pytest.raises(ConfigError, match=r"inner\.radius_m must be a number, got 'big'"):
        load_dataclass(Outer, {"inner": {"radius_m": "big"}})
    with pytest.raises(ConfigError, match=r"count must be an integer, got 2\.5"):
        load_dataclass(Outer, {"count": 2.5})
    with pytest.raises(ConfigError, match=r"mode must be one of \['a', 'b'\], got 'c'"):
        load_dataclass(Outer, {"mode": "c"})


def test_range_errors_are_prefixed_with_the_section():
    with pytest.raises(ConfigError, match=r"inner\.radius_m must be > 0, got -0\.00025"):
        load_dataclass(Outer, {"inner": {"radius_m": -2.5e-4}})
    with pytest.raises(ConfigError, match=r"inner\.ratio must be in \[0\.0, 1\.0\), got 1\.0"):
        load_dataclass(Outer, {"inner": {"ratio": 1.0}})
    with pytest.raises(ConfigError, match=r"inner\.radius_m must be finite, got nan"):
        load_dataclass(Outer, {"inner": {"radius_m": float("nan")}})


def test_round_trip_through_mapping_and_flat_parameters():
    cfg = load_dataclass(Outer, {"name": "y", "inner": {"ratio": 0.3}})
    mapping = to_mapping(cfg)
    assert load_dataclass(Outer, mapping) == cfg
    flat = flatten(mapping)
    assert flat["inner.ratio"] == 0.3
    assert load_dataclass(Outer, unflatten(flat)) == cfg


def test_load_yaml_errors(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_yaml(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("a: [1, 2\n")
    with pytest.raises(ConfigError, match="is not valid YAML"):
        load_yaml(bad)
    scalar = tmp_path / "scalar.yaml"
    scalar.write_text("3\n")
    with pytest.raises(ConfigError, match="must hold a mapping"):
        load_yaml(scalar)


def test_yaml_exponent_floats_without_a_dot_are_numbers(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("a: 1e-6\nb: 1.72e6\nc: 3\nd: -2E+3\ne: text1e5\n")
    data = load_yaml(f)
    assert data == {"a": 1e-6, "b": 1.72e6, "c": 3, "d": -2000.0, "e": "text1e5"}
    assert isinstance(data["c"], int)
