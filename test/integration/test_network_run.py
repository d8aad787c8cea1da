"""`vesselbot run` through the Section III-C vessel network: recorded, reported, the chosen branch reached.

One lockstep run (all nodes composed in one process, seed 0, --report) of paper_iiic_network_lower.yaml; the
launcher's metrics equal the ROS-free loop's, the bag holds the network markers and the planned path,
and the report states the branch reached.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

from vesselbot_ros.bag.reader import iter_messages, open_bag
from vesselbot_ros.control.route import planned_reference
from vesselbot_ros.graph_spec import topic
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario
from vesselbot_ros.vessels.cfd import network_wall
from vesselbot_ros.vessels.network import load_network

REPO = Path(__file__).resolve().parents[2]
CONFIG = "config/paper_iiic_network_lower.yaml"


@pytest.fixture(scope="module")
def run(tmp_path_factory):  # type: ignore[no-untyped-def]
    tmp = tmp_path_factory.mktemp("network_run")
    bag, metrics = tmp / "bag", tmp / "metrics.json"
    cmd = [sys.executable, "-m", "vesselbot_ros.cli", "run", "--config", CONFIG, "--seed", "0", "--quiet", "--single-process",
           "--record-dir", str(bag), "--metrics-json", str(metrics), "--report"]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return bag, json.loads(metrics.read_text())["metrics"]


def test_run_reaches_the_chosen_branch_with_the_pure_loops_numbers(run) -> None:  # type: ignore[no-untyped-def]
    _bag, m = run
    assert m["branch_final"] == "lower" and m["reached_target"] == 1
    assert m["outside_lumen_time_s"] == 0.0
    pure = run_closed_loop(load_scenario(REPO / CONFIG), 0).metrics
    for k in ("tracking_error_max_m", "estimation_error_max_m", "contact_time_s", "n_ticks"):
        assert m[k] == pure[k], k  # lockstep: bit for bit


def test_report_states_the_branch_and_the_bag_holds_network_and_route(run) -> None:  # type: ignore[no-untyped-def]
    bag, _m = run
    report = bag.with_name(f"{bag.name}.report")  # beside the bag
    rep = json.loads((report / "metrics.json").read_text())
    assert rep["branch_final"] == "lower" and rep["reached_target"] == 1 and rep["route_outlet"] == "lower"
    assert (report / "fig9a_trajectory.png").stat().st_size > 10_000
    info = open_bag(bag)
    markers = [bm.decode() for bm in iter_messages(info, [topic("vessel_markers").name])]
    assert len(markers) == 1
    ns = {mk.ns for mk in markers[0].markers}
    assert {"wall", "lower/centreline", "side_down/centreline"} <= ns and len(ns) == 1 + 7
    wall = next(mk for mk in markers[0].markers if mk.ns == "wall")
    segs = network_wall(load_network(load_scenario(REPO / CONFIG).physics.vessel.network)).segments
    assert len(wall.points) == 2 * len(segs)  # the meshed wall the plant sees, segment by segment
    assert (wall.points[0].x, wall.points[0].z) == pytest.approx(tuple(segs[0, :2]), abs=1e-12)
    paths = [bm.decode() for bm in iter_messages(info, [topic("reference_path").name])]
    ref = planned_reference(load_scenario(REPO / CONFIG))
    first, last = paths[0].poses[0].pose.position, paths[0].poses[-1].pose.position
    assert (first.x, first.z) == pytest.approx((ref.anchors_x_m[0], ref.anchors_z_m[0]), abs=1e-12)
    assert (last.x, last.z) == pytest.approx((ref.anchors_x_m[-1], ref.anchors_z_m[-1]), abs=1e-12)
