"""The import contract: every import of the package points down the floors, and nothing imports in a circle.

``LAYERS`` is the one table of the package's floors (docs/graph.md's "Layers"
section shows it, and :func:`test_readme_shows_the_layer_table` keeps the two
equal).  A module may import modules of its own floor or of a floor below,
never above; imports inside functions count the same as top-level ones (they
defer a cost, they do not change who depends on whom).  No circle either:
neither between the units of the table (a package or a top-level module) nor
between modules.  A new unit must be placed in the table before it can pass.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

#: Floors from the bottom up: (name, the units on it).  A unit is a subpackage of vesselbot_ros or
#: one of its top-level modules; ``vesselbot_ros`` is the package's own ``__init__``.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("base", ("vesselbot_ros", "errors", "atomic_io", "resources", "config", "blas_free", "numba_cache", "progress")),
    ("geometry", ("geometry",)),
    ("physics", ("physics",)),
    ("vessels", ("vessels",)),
    ("scanner", ("scanner",)),
    ("imaging", ("imaging",)),
    ("control", ("control",)),
    ("sim", ("sim",)),
    ("envs", ("envs",)),
    ("studies", ("analysis", "campaign")),
    ("graph", ("graph_spec", "topics", "ros_env", "live_front", "live_view", "live")),
    ("bag", ("bag",)),
    ("nodes", ("nodes",)),
    ("launch", ("launch",)),
    ("entry", ("cli", "testing")),
)

PACKAGE = "vesselbot_ros"
ROOT = Path(__file__).resolve().parents[2] / PACKAGE


def _module_name(path: Path, root: Path, package: str) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join([package, *parts])


def _unit(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def package_imports(root: Path, package: str = PACKAGE) -> list[tuple[str, int, str, str]]:
    """Every import of a module of ``package`` below ``root``: (source file, line, importing module, imported module).

    Top-level and function-level imports alike; ``from a import b`` names ``a.b`` when ``b`` is a module.
    """
    modules = {_module_name(p, root, package) for p in root.rglob("*.py")}
    out = []
    for path in sorted(root.rglob("*.py")):
        src = _module_name(path, root, package)
        is_pkg = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = src.split(".") if is_pkg else src.split(".")[:-1]
                    base = base[:len(base) - node.level + 1]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in modules else mod for a in node.names]
            else:
                continue
            for target in dict.fromkeys(targets):
                if target == package or target.startswith(package + "."):
                    out.append((str(path.relative_to(root.parent)), node.lineno, src, target))
    return out


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The graph's circles: its strongly connected components of more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def violations(root: Path, layers: tuple[tuple[str, tuple[str, ...]], ...] = LAYERS, package: str = PACKAGE) -> list[str]:
    """Every breach of the contract under ``root``, one line each naming file, line and import."""
    floor = {unit: i for i, (_name, units) in enumerate(layers) for unit in units}
    names = [name for name, _units in layers]
    imports = package_imports(root, package)
    out = []
    units = {_unit(_module_name(p, root, package)) for p in root.rglob("*.py")}
    out += [f"{package}.{u}: not in the layer table (place it on a floor)" for u in sorted(units - floor.keys())]
    unit_edges: dict[str, set[str]] = {}
    module_edges: dict[str, set[str]] = {}
    for path, line, src, target in imports:
        a, b = _unit(src), _unit(target)
        module_edges.setdefault(src, set()).add(target)
        if a == b or a not in floor or b not in floor:
            continue
        unit_edges.setdefault(a, set()).add(b)
        if floor[b] > floor[a]:
            out.append(f"{path}:{line}: {src} imports {target}, which is above it "
                       f"(floor {names[floor[a]]!r} imports floor {names[floor[b]]!r})")
    out += [f"circle between units: {' <-> '.join(c)}" for c in _cycles(unit_edges)]
    out += [f"circle between modules: {' <-> '.join(c)}" for c in _cycles(module_edges)]
    return out


def test_every_import_points_down_and_nothing_imports_in_a_circle() -> None:
    found = violations(ROOT)
    assert not found, "the import contract (LAYERS in test/unit/test_layers.py) is broken:\n" + "\n".join(found)


def test_the_floors_below_graph_never_import_rclpy_or_messages() -> None:
    """The pure cores (floors base to studies) run without ROS: no rclpy, no message package, anywhere in them."""
    pure = {u for name, units in LAYERS[:[n for n, _u in LAYERS].index("graph")] for u in units}
    found = []
    for path in sorted(ROOT.rglob("*.py")):
        if _unit(_module_name(path, ROOT, PACKAGE)) not in pure:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else (
                [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            found += [f"{path.relative_to(ROOT.parent)}:{node.lineno}: {n}" for n in names
                      if n.split(".")[0] == "rclpy" or n.split(".")[0].endswith("_msgs")]
    assert not found, "\n".join(found)


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    root = tmp_path / PACKAGE
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


@pytest.mark.parametrize("where", ["top", "function", "relative"])
def test_an_upward_import_fails_naming_file_line_and_import(tmp_path: Path, where: str) -> None:
    body = {"top": "from vesselbot_ros.sim.runner import run\n",
            "function": "def f():\n    import vesselbot_ros.sim.runner\n",
            "relative": "from ..sim import runner\n"}[where]
    root = _tree(tmp_path, {"__init__.py": "", "physics/__init__.py": "", "physics/kernel.py": body,
                            "sim/__init__.py": "", "sim/runner.py": "from vesselbot_ros.physics import kernel\n"})
    layers = (("base", ("vesselbot_ros",)), ("physics", ("physics",)), ("sim", ("sim",)))
    found = violations(root, layers)
    line = 2 if where == "function" else 1
    assert f"vesselbot_ros/physics/kernel.py:{line}: vesselbot_ros.physics.kernel imports vesselbot_ros.sim.runner, " \
           "which is above it (floor 'physics' imports floor 'sim')" in found
    assert "circle between units: physics <-> sim" in found
    assert "circle between modules: vesselbot_ros.physics.kernel <-> vesselbot_ros.sim.runner" in found


def test_a_circle_on_one_floor_and_an_unplaced_unit_fail(tmp_path: Path) -> None:
    root = _tree(tmp_path, {"__init__.py": "", "nodes/__init__.py": "",
                            "nodes/plant.py": "from vesselbot_ros.nodes.control import X\n",
                            "nodes/control.py": "def f():\n    from vesselbot_ros.nodes.plant import Y\n",
                            "extra.py": ""})
    found = violations(root, (("base", ("vesselbot_ros",)), ("nodes", ("nodes",))))
    assert found == ["vesselbot_ros.extra: not in the layer table (place it on a floor)",
                     "circle between modules: vesselbot_ros.nodes.control <-> vesselbot_ros.nodes.plant"]


def test_the_real_tree_fails_once_an_upward_import_is_added(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The contract catches a breach in the package itself: control moved above sim breaks it."""
    swapped = tuple((name, units) for name, units in LAYERS if name != "control") + (("control", ("control",)),)
    found = violations(ROOT, swapped)
    assert found and all("imports floor 'control'" in f for f in found if "above it" in f)


def test_readme_shows_the_layer_table() -> None:
    readme = (ROOT.parent / "docs" / "graph.md").read_text()
    section = readme.split("### Layers", 1)[1].split("\n#", 1)[0]
    rows = re.findall(r"^\| (\d+) \| (\w+) \| ([^|]+) \|", section, re.M)
    shown = tuple((name, tuple(u.strip(" `") for u in units.split(","))) for _i, name, units in rows)
    assert [int(i) for i, _n, _u in rows] == list(range(len(LAYERS)))
    assert shown == LAYERS
