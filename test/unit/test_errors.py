"""The package's one error root: every error class derives from VesselbotError, the CLI catches it once."""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
from pathlib import Path

import pytest

import vesselbot_ros
from vesselbot_ros import errors
from vesselbot_ros.cli import main
from vesselbot_ros.errors import BagError, ConfigError, ModelInputError, RunError, VesselbotError


def _error_classes() -> dict[str, type[BaseException]]:
    """Every public exception class defined in a vesselbot_ros module, by ``module.Name``."""
    found: dict[str, type[BaseException]] = {}
    for info in pkgutil.walk_packages(vesselbot_ros.__path__, "vesselbot_ros."):
        if info.name.rsplit(".", 1)[-1] == "__main__":
            continue
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if (inspect.isclass(obj) and issubclass(obj, BaseException) and obj.__module__ == info.name
                    and not name.startswith("_")):
                found[f"{info.name}.{name}"] = obj
    return found


def test_every_public_error_class_derives_from_the_root():
    classes = _error_classes()
    # the walk sees the classes outside errors.py too (a broken walk must not pass vacuously)
    assert {"vesselbot_ros.launch.supervision.NodeDied", "vesselbot_ros.launch.graph.RecordingMismatch"} <= set(classes)
    unrooted = sorted(name for name, cls in classes.items() if not issubclass(cls, VesselbotError))
    assert unrooted == [], f"error classes not derived from vesselbot_ros.errors.VesselbotError: {unrooted}"


@pytest.mark.parametrize("cls", [ConfigError, ModelInputError])
def test_input_errors_are_still_value_errors(cls):
    with pytest.raises(ValueError, match="radius_m must be > 0, got -1"):
        raise cls("radius_m must be > 0, got -1")


@pytest.mark.parametrize("cls", [ConfigError, ModelInputError, BagError, RunError])
def test_each_kind_is_caught_by_the_root(cls):
    with pytest.raises(VesselbotError, match="bad"):
        raise cls("bad")
    assert not issubclass(BagError, ValueError) and not issubclass(RunError, ValueError)


def test_old_import_paths_still_work():
    from vesselbot_ros.config import ConfigError as from_config
    from vesselbot_ros.launch.graph import NodeDied, RecordingMismatch

    assert from_config is ConfigError
    assert issubclass(NodeDied, RunError) and issubclass(RecordingMismatch, RunError)


def test_errors_module_imports_nothing_from_the_package():
    tree = ast.parse(Path(errors.__file__).read_text(encoding="utf-8"))
    imported = [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    imported += [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    assert [m for m in imported if m.startswith("vesselbot_ros")] == []


@pytest.mark.parametrize("cls", [ConfigError, ModelInputError, BagError, RunError, VesselbotError])
def test_cli_prints_any_package_error_as_one_line_exit_2(cls, capsys, monkeypatch):
    import vesselbot_ros.sim.scenarios_cli as scenarios_cli

    def fail(args):
        raise cls("physics.robot.radius_m must be > 0, got -0.00025")

    monkeypatch.setattr(scenarios_cli, "run", fail)
    assert main(["scenarios"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["vesselbot scenarios: error: physics.robot.radius_m must be > 0, got -0.00025"]


def test_cli_does_not_swallow_other_errors(monkeypatch):
    import vesselbot_ros.sim.scenarios_cli as scenarios_cli

    def fail(args):
        raise ZeroDivisionError("a bug, not bad input")

    monkeypatch.setattr(scenarios_cli, "run", fail)
    with pytest.raises(ZeroDivisionError, match="a bug"):
        main(["scenarios"])
