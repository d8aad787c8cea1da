"""Shared CLI plumbing of the analysis commands: config loading and overrides."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from vesselbot_ros.config import ConfigError, apply_overrides, load_dataclass, load_yaml, parse_set_items
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
    """Parse ``KEY=VALUE`` strings (VALUE read by the project's one YAML parser) into dotted overrides."""
    return parse_set_items(items)


def _prefixed(sets: dict[str, Any], name: str) -> dict[str, Any]:
    return {k[len(name) + 1:]: v for k, v in sets.items() if k.startswith(name + ".")}


def _section(path: str, name: str) -> dict[str, Any]:
    data = load_yaml(path)
    unknown = sorted(set(data) - {name})
    if unknown:
        raise ConfigError(f"config file {path!r}: unknown top-level key {unknown[0]!r}; expected {name!r}")
    return dict(data.get(name) or {})


def load_physics(args: argparse.Namespace) -> PhysicsParams:
    """PhysicsParams from --physics-config plus ``physics.*`` --set overrides."""
    sets = parse_sets(args.set)
    unknown = sorted(k for k in sets if k.split(".", 1)[0] not in ("physics", "design_study") or "." not in k)
    if unknown:
        raise ConfigError(f"--set key must start with 'physics.' or 'design_study.', got {unknown[0]!r}")
    mapping = apply_overrides(_section(args.physics_config, "physics"), _prefixed(sets, "physics"))
    return load_dataclass(PhysicsParams, mapping, "physics")


def load_study_mapping(args: argparse.Namespace) -> dict[str, Any]:
    """The ``design_study`` mapping from --study-config plus --set overrides."""
    return apply_overrides(_section(args.study_config, "design_study"), _prefixed(parse_sets(args.set), "design_study"))
