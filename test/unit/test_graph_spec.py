"""The graph spec is consistent, is the only place that names topics and services, and the README shows it."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from vesselbot_ros import graph_spec as spec

REPO = Path(__file__).resolve().parents[2]
#: Source trees that must take every topic / service name from the spec.
SCANNED = ("vesselbot_ros", "bench", "examples", "tools")


def _forbidden_names() -> set[str]:
    names = set()
    for t in spec.TOPICS:
        names.add(t.name)
        if "/" in t.rel:  # a bare relative name ("truth") is also a key; slashed ones are names only
            names.add(t.rel)
    for s in spec.SERVICES:
        names.add(s.name)
        if "/" in s.rel:
            names.add(s.rel)
    names.add(spec.DEFAULT_NAMESPACE + "/" + spec.REPLAY_PREFIX)
    return names


def _docstring_nodes(tree: ast.AST) -> set[int]:
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                out.add(id(first.value))
    return out


def spelled_names(path: Path) -> list[str]:
    """``file:line: text`` of every string literal in ``path`` (docstrings aside) that spells a graph name.

    A literal spells a name if it is a topic or service name of the spec, starts
    with the default namespace (``/vesselbot/...``), or is a tuple / list of
    three or more role names (a second role registry).
    """
    forbidden = _forbidden_names()
    roles = set(spec.LOOP_ROLES)
    tree = ast.parse(path.read_text(), str(path))
    docs = _docstring_nodes(tree)
    hits = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs:
            v = node.value
            if v in forbidden or v.startswith(spec.DEFAULT_NAMESPACE + "/") or v == spec.DEFAULT_NAMESPACE:
                hits.append(f"{path}:{node.lineno}: {v!r}")
        elif isinstance(node, (ast.Tuple, ast.List, ast.Set)):
            vals = {e.value for e in node.elts if isinstance(e, ast.Constant) and isinstance(e.value, str)}
            if len(vals & roles) >= 3:
                hits.append(f"{path}:{node.lineno}: role list {sorted(vals & roles)}")
    return hits


#: The one other home of role-like names: the pure loop's stages (vesselbot_ros.sim.kinds.ROLES), a floor below the
#: graph spec, which cannot import it; each graph role's ``stage`` names one of them (test below).
STAGE_REGISTRY = REPO / "vesselbot_ros" / "sim" / "kinds.py"


def test_no_module_but_the_spec_spells_a_topic_or_service_name():
    hits = []
    for tree in SCANNED:
        for path in sorted((REPO / tree).rglob("*.py")):
            if path.name == "graph_spec.py" or ".venv" in path.parts:
                continue
            found = spelled_names(path)
            if path == STAGE_REGISTRY:  # its stage list is allowed; a topic or service name is not
                found = [h for h in found if ": role list " not in h]
            hits += found
    assert not hits, "take these names from vesselbot_ros.graph_spec:\n" + "\n".join(hits)


@pytest.mark.parametrize("source", [
    'PUB = "/vesselbot/gradient_command"\n',
    'def f(node):\n    node.create_subscription(X, "coil/applied", cb, 10)\n',
    'CLOCK = "/clock"\n',
    'SRV = "/vesselbot/run_control"\n',
    'ROLES = ("plant", "imager", "observer")\n',
])
def test_the_guard_fails_when_a_name_is_spelled_elsewhere(tmp_path, source):
    f = tmp_path / "offender.py"
    f.write_text(source)
    assert spelled_names(f), source


def test_the_guard_ignores_docstrings_and_keys(tmp_path):
    f = tmp_path / "fine.py"
    f.write_text('"""Publishes ``/vesselbot/estimate``."""\nKEY = "truth"\n')
    assert spelled_names(f) == []


def test_topic_keys_and_names_are_unique():
    keys = [t.key for t in spec.TOPICS]
    names = [t.name for t in spec.TOPICS]
    assert len(set(keys)) == len(keys)
    assert len(set(names)) == len(names)
    assert all(n.startswith("/") for n in names)


def test_every_port_is_declared_by_its_roles():
    roles = {r.name for r in spec.ALL_ROLES} | {"all"}
    assert {t.publisher for t in spec.TOPICS} <= roles
    assert {s.server for s in spec.SERVICES} <= roles
    for frames in (False, True):  # a graph whose imager delivers positions, and one of MR frames (with a tracker)
        roles_in = [spec.role(name) for name in spec.loop_roles(frames)]
        for r in roles_in:
            for key in r.outputs_for(frames):
                t = spec.topic(key)
                assert (t.frames_publisher if frames and t.frames_publisher else t.publisher) == r.name, (r.name, key)
            for key in r.inputs_for(frames):
                assert r.name in spec.topic(key).subscribers, (r.name, key)
            for key in r.services:
                assert spec.service(key).server == r.name
        # every topic a loop role publishes has exactly one publishing role
        published = [k for r in roles_in for k in r.outputs_for(frames)]
        assert len(published) == len(set(published))
    assert spec.loop_roles(False) == tuple(r for r in spec.LOOP_ROLES if r != "tracker")
    assert set(spec.frame_topics()) == {"mr_frame", "mr_image"}


def test_names_resolve_in_a_namespace():
    assert spec.resolve("coil/applied") == "/vesselbot/coil/applied"
    assert spec.resolve("coil/applied", "robot2") == "/robot2/coil/applied"
    assert spec.resolve("/clock") == "/clock"
    assert spec.resolve("/clock", "/robot2") == "/robot2/clock"
    assert spec.remap_args() == []
    args = spec.remap_args("robot2")
    assert "__ns:=/robot2" in args and "/clock:=/robot2/clock" in args and "/diagnostics:=/robot2/diagnostics" in args


def test_console_scripts_and_counters_derive_from_the_roles():
    scripts = spec.console_scripts()
    assert len(scripts) == 1 + len(spec.ALL_ROLES)
    for r in spec.ALL_ROLES:
        assert f"{r.node_name} = {r.module}:main" in scripts
    assert spec.diagnostic_counters()["plant"] == spec.role("plant").counters


def test_each_loop_role_runs_one_stage_of_the_pure_loop():
    """The spec says which stage of ``closed_loop.Stages`` each node builds and warms: each one once (the model
    is the controller's and the observer's, built with them)."""
    from vesselbot_ros.sim.closed_loop import Stages

    stages = [spec.role(r).stage for r in spec.LOOP_ROLES]
    assert sorted(stages) == sorted(f for f in Stages._fields if f != "model")
    from vesselbot_ros.sim.kinds import ROLES as STAGE_ROLES

    assert sorted(stages) == sorted(STAGE_ROLES)  # the stage registry's roles are the graph's stages
    assert spec.RECORDER.stage == ""


def test_contract_names_every_port_of_the_slot():
    text = spec.role_contract("controller", "robot2")
    assert "/robot2/estimate" in text and "/robot2/reference" in text and "/robot2/gradient_command" in text
    assert "keep last 10000" in text


def test_readme_sections_are_generated_from_the_spec(repo):
    import importlib.util

    mod_spec = importlib.util.spec_from_file_location("gen_readme_sections", repo / "tools" / "gen_readme_sections.py")
    gen = importlib.util.module_from_spec(mod_spec)
    mod_spec.loader.exec_module(gen)
    for rel, names in gen.TARGETS.items():
        text = (repo / rel).read_text()
        assert gen.render(text, names, rel) == text, f"{rel} is stale: run .venv/bin/python tools/gen_readme_sections.py"
    graph = (repo / "docs" / "graph.md").read_text()
    for body in (spec.markdown_table(), spec.architecture_table(), spec.contract_table()):
        assert body in graph
    assert spec.faults_table() in (repo / "docs" / "faults_and_safety.md").read_text()


def test_contract_explains_the_phase_stamps_and_latency():
    ctl = spec.role_contract("controller")
    assert "may subscribe /vesselbot/scanner/phase [vesselbot_msgs/msg/SequencePhase]" in ctl
    assert "window_start, window_end" in ctl and "PROPULSION (3" in ctl
    obs = spec.role_contract("observer")
    assert "acquisition time" in obs and "latency" in obs and "may subscribe /vesselbot/scanner/phase" in obs
    assert "publish   /vesselbot/scanner/phase" in spec.role_contract("coil_driver")
    assert spec.topic("sequence_phase").publisher == "coil_driver"
