"""Shared CLI plumbing of the analysis commands: config loading and overrides."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import yaml

from vesselbot_ros.config import ConfigError, load_dataclass, load_yaml, unflatten
from vesselbot_ros.physics.params import PhysicsParams

__all__ = ["add_config_arguments", "load_physics", "load_study_mapping", "parse_sets"]

REPO_CONFIG = Path(__file__).resolve().parents[2] / "config"


def add_config_arguments(parser: argparse.ArgumentParser, out_default: str, study: bool = False) -> None:
    """Add --physics-config, [--study-config], --set and --out to ``parser``."""
    parser.add_argument("--physics-config", default=str(REPO_CONFIG / "physics_default.yaml"),
                        help="YAML file with a 'physics:' section (default: config/physics_default.yaml)")
    if study:
        parser.add_argument("--study-config", default=str(REPO_CONFIG / "design_study.yaml"),
                            help="YAML file with a 'design_study:' section (default: config/design_study.yaml)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a config value, e.g. physics.interactions.electrostatic_model=paper_printed "
                             "or design_study.grid.n_lambda=100 (repeatable)")
    parser.add_argument("--out", default=out_default, help=f"output directory (default: {out_default})")


def parse_sets(items: list[str]) -> dict[str, Any]:
    """Parse ``KEY=VALUE`` strings (VALUE as YAML) into a nested mapping."""
    flat: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise ConfigError(f"--set expects KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        try:
            parsed = yaml.safe_load(value)
        except yaml.YAMLError as exc:
            raise ConfigError(f"--set {key}: value {value!r} is not valid YAML: {exc}") from None
        if isinstance(parsed, str):
            try:  # YAML 1.1 reads 1e-6 (no dot) as a string
                parsed = float(parsed)
            except ValueError:
                pass
        flat[key.strip()] = parsed
    return unflatten(flat)


def _merge(base: dict[str, Any], upd: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in upd.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _section(path: str, name: str) -> dict[str, Any]:
    data = load_yaml(path)
    unknown = sorted(set(data) - {name})
    if unknown:
        raise ConfigError(f"config file {path!r}: unknown top-level key {unknown[0]!r}; expected {name!r}")
    return dict(data.get(name) or {})


def load_physics(args: argparse.Namespace) -> PhysicsParams:
    """PhysicsParams from --physics-config plus ``physics.*`` --set overrides."""
    sets = parse_sets(args.set)
    unknown = sorted(set(sets) - {"physics", "design_study"})
    if unknown:
        raise ConfigError(f"--set key must start with 'physics.' or 'design_study.', got {unknown[0]!r}")
    mapping = _merge(_section(args.physics_config, "physics"), sets.get("physics", {}))
    return load_dataclass(PhysicsParams, mapping, "physics")


def load_study_mapping(args: argparse.Namespace) -> dict[str, Any]:
    """The ``design_study`` mapping from --study-config plus --set overrides."""
    sets = parse_sets(args.set)
    return _merge(_section(args.study_config, "design_study"), sets.get("design_study", {}))
