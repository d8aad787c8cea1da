"""third_party/simulation_interfaces: the standard's files unchanged, built with the standard's type hashes."""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PKG = REPO / "third_party" / "simulation_interfaces"
SHARE = Path(sys.prefix) / "share" / "simulation_interfaces"


def test_vendored_files_are_the_standards_jazzy_files_byte_for_byte():
    """SHA256SUMS was taken from the upstream jazzy branch (VENDORED.md names the commit)."""
    listed = {}
    for line in (PKG / "SHA256SUMS").read_text().splitlines():
        digest, name = line.split(maxsplit=1)
        listed[name.removeprefix("./")] = digest
    on_disk = {str(p.relative_to(PKG)) for p in PKG.rglob("*")
               if p.suffix in (".msg", ".srv", ".action") or p.name in ("CMakeLists.txt", "package.xml", "LICENSE")}
    assert set(listed) == on_disk
    for name, digest in listed.items():
        assert hashlib.sha256((PKG / name).read_bytes()).hexdigest() == digest, name
    assert len([n for n in listed if n.endswith(".msg")]) == 15
    assert len([n for n in listed if n.endswith(".srv")]) == 22
    assert [n for n in listed if n.endswith(".action")] == ["action/SimulateSteps.action"]


@pytest.mark.parametrize("msg", sorted(p.stem for p in (PKG / "msg").glob("*.msg")))
def test_built_message_hashes_equal_an_independent_computation_from_the_standards_text(msg):
    """rosidl's RIHS01 of the installed package equals rosbags' RIHS01 of the vendored .msg texts."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for f in sorted((PKG / "msg").glob("*.msg")):
        types.update(get_types_from_msg(f.read_text(), f"simulation_interfaces/msg/{f.stem}"))
    ts.register(types)
    built = json.loads((SHARE / "msg" / f"{msg}.json").read_text())["type_hashes"]
    name = f"simulation_interfaces/msg/{msg}"
    assert next(h["hash_string"] for h in built if h["type_name"] == name) == ts.hash_rihs01(name)


def test_services_and_action_are_built_and_import():
    from simulation_interfaces.action import SimulateSteps
    from simulation_interfaces.srv import GetSimulationState, GetSimulatorFeatures, ResetSimulation, SetSimulationState, StepSimulation

    assert StepSimulation.Request().steps == 1  # the standard's default
    assert SetSimulationState.Response.ALREADY_IN_TARGET_STATE == 101
    assert ResetSimulation.Request.SCOPE_ALL == 255
    assert {f.name for f in (SHARE / "srv").glob("*.json")} >= {"StepSimulation.json", "GetSimulationState.json"}
    assert SimulateSteps.Feedback().remaining_steps == 0 and GetSimulatorFeatures and GetSimulationState
