"""The live view of a 3-D vessel tree, decoded over the Foxglove protocol by Foxglove's own client.

The scene comes over the live view's WebSocket (``tools/js/ws_live.mjs --scene``: @foxglove/ws-protocol and
Foxglove's ROS 2 deserializer) and is checked against the run's bag: the plant's latched vessel markers
(the lumen wall as one TRIANGLE_LIST of the expected triangle count, the 3-D centrelines), and the derived
``view/markers`` (the reference route, the robot, its estimate and the gradient arrow) with their real y.

Source of the scene: ``vesselbot run`` of a 3-D tree's scenario with its live view (``test_live.py``'s way):
the carotid bifurcation's, started in the external carotid, 0.55 mm off the plane y = 0 (the robot's y is
then real from the first tick); and a peer (``scene3d_peer.py``) that publishes the synthetic tree's scene on
the graph's topics to a recorder serving the live view, for the largest wall marker (22 958 triangles,
1.7 MB) through DDS, the bag and the WebSocket without a 5 s run.
"""

from __future__ import annotations

import math
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from _runs import free_port, last_json, node_client, run_cmd  # noqa: E402
from vesselbot_ros.bag.reader import iter_messages, open_bag  # noqa: E402
from vesselbot_ros.graph_spec import FRAME_ID, NETWORK_WALL_NS, topic  # noqa: E402
from vesselbot_ros.live_view import ARROW_AT_LIMIT_M  # noqa: E402
from vesselbot_ros.nodes.recorder_node import recorder_command  # noqa: E402
from vesselbot_ros.physics.params import BloodParams  # noqa: E402
from vesselbot_ros.testing import NodeProcess  # noqa: E402
from vesselbot_ros.vessels.network import load_network  # noqa: E402
from vesselbot_ros.vessels.tree_field import wall_mesh  # noqa: E402
from vesselbot_ros.vessels.tube_geometry import NetworkGeometry  # noqa: E402

PEER = Path(__file__).with_name("scene3d_peer.py")
#: The real run: the carotid scenario started 5 mm into the external carotid (y = -0.55 mm), routed to its end.
RUN_SCENARIO_3D = "config/carotid_bifurcation_3d_eca.yaml"
RUN_SETS_3D = ("initial.p0_m=[4.52e-3, -0.545e-3, -2.04e-3]",)
#: Its network (the expected wall's triangle count is computed from it).
RUN_NETWORK_3D = "carotid_bifurcation_3d"
#: The control tick (ns) of the peer (its ``DT_S``) and of the run's scenario (checked where each is used).
TICK_NS = 1_000_000
#: What view/markers must show in a network (no straight walls).
VIEW_NAMESPACES = ("robot", "estimate", "gradient", "reference_path")
TRIANGLE_LIST, LINE_STRIP, SPHERE, ARROW = 11, 4, 2, 0  # visualization_msgs/Marker types
DELETE = 2  # visualization_msgs/Marker action


def _peer_scene(ros: Any, tmp: Path, network: str) -> tuple[Any, Path]:
    """The peer publishes ``network``'s scene to a recorder serving the live view (and writing a bag)."""
    port, bag = free_port(), tmp / "bag"
    rec = NodeProcess(recorder_command(bag, {"scenario": f"scene3d_peer {network}"}, live_port=port, live_rate_Hz=0),
                      ros.env, tmp / "recorder.log")
    client = node_client("ws_live.mjs", str(port), "120", "60", "--until-scene", ",".join(VIEW_NAMESPACES))
    peer = NodeProcess(["python", str(PEER), network, "200"], ros.env, tmp / "peer.log")
    try:
        got = last_json(client, timeout=240)
    finally:
        if client.poll() is None:
            client.kill()
        peer.stop(timeout=20)
        code = rec.stop(timeout=30)
    assert code == 0, rec.output()[-3000:]
    assert "latched" in peer.output(), peer.output()[-3000:]
    return got, bag


def _run_scene(tmp: Path, scenario: str) -> tuple[Any, Path]:
    """``vesselbot run`` of a 3-D scenario with a live view, a Foxglove client connected before it starts."""
    port, bag = free_port(), tmp / "bag"
    client = node_client("ws_live.mjs", str(port), "120", "60", "--scene")
    try:
        sets = [a for kv in RUN_SETS_3D for a in ("--set", kv)]
        run = subprocess.run(run_cmd("--config", scenario, "--duration", "0.5", "--live-port", str(port),
                                     "--live-rate", "0", "--record-dir", str(bag), "--quiet", *sets),
                             cwd=tmp, capture_output=True, text=True, timeout=600)
        assert run.returncode == 0, run.stderr[-3000:]
        got = last_json(client, timeout=120)  # the server stops with the recorder: the client ends
    finally:
        if client.poll() is None:
            client.kill()
    return got, bag


def _recorded(bag: Path) -> dict[str, Any]:
    """From the bag: the vessel markers by namespace, the reference path's points, truth, reference, coil state by stamp."""
    out: dict[str, Any] = {"vessel": {}, "path": None, "truth": {}, "reference": {}, "coil": {}}
    for m in iter_messages(open_bag(bag)):
        if m.topic == topic("vessel_markers").name:
            out["vessel"] = {mk.ns: mk for mk in m.decode().markers}
        elif m.topic == topic("reference_path").name:
            out["path"] = [p.pose.position for p in m.decode().poses]
        elif m.topic in (topic("truth").name, topic("reference").name, topic("coil_state").name):
            msg = m.decode()
            key = {topic("truth").name: "truth", topic("reference").name: "reference",
                   topic("coil_state").name: "coil"}[m.topic]
            out[key][msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec] = msg
    return out


def _near(by_stamp: dict[int, Any], stamp: int, ticks: int = 2) -> list[Any]:
    """The messages within ``ticks`` ticks of ``stamp``, nearest first.

    The view pairs the truth and reference of one stamp, and takes the coil state of that tick or the newest
    before it (the recorder's subscriptions are one per topic, and the peer, stopped, may not have sent the
    truth's own).  The tick is the peer's and the run
    scenario's control period, not read off the stamps: the client may have its scene after a single tick.
    """
    return [by_stamp[s] for s in sorted(by_stamp, key=lambda s: abs(s - stamp)) if abs(s - stamp) <= ticks * TICK_NS]


def _xyz(p: Any) -> list[float]:
    return [p.x, p.y, p.z]


def _sums(points: list[Any]) -> list[float]:
    """Sum of x, of y and of z, in the points' order (what the client sums)."""
    sx = sy = sz = 0.0
    for p in points:
        sx += p.x
        sy += p.y
        sz += p.z
    return [sx, sy, sz]


def _check_scene(got: Any, bag: Path, network: str) -> None:
    assert got["decode_errors"] == {}, got["decode_errors"]
    scene, rec = got["scene"], _recorded(bag)
    net = load_network(network)
    assert net.is_3d
    # the plant's wall: one TRIANGLE_LIST of the expected triangles, translucent, every point as recorded
    wall, wall_rec = scene["vessel"][NETWORK_WALL_NS], rec["vessel"][NETWORK_WALL_NS]
    n_tris = len(wall_mesh(net, BloodParams())[1])  # the wall the 3-D plant computes with
    assert (wall["type"], wall["frame_id"], wall["n_colors"]) == (TRIANGLE_LIST, FRAME_ID, 0)
    assert wall["n_points"] == 3 * n_tris == len(wall_rec.points)
    assert wall["points_head"] == [_xyz(p) for p in wall_rec.points[:6]]
    assert wall["points_sum"] == _sums(wall_rec.points)
    assert 0 < wall["color"][3] < 1 and wall["scale"] == [1.0, 1.0, 1.0]
    # in 3-D: the wall and the centrelines of the branches that leave the plane have y
    lo, hi = NetworkGeometry(net, dims=3).bbox[2:4]
    assert wall["y_abs_max"] == pytest.approx(max(-lo, hi), rel=0.05)
    lines = {b.name: scene["vessel"][f"{b.name}/centreline"] for b in net.branches}
    assert all(c["type"] == LINE_STRIP and c["frame_id"] == FRAME_ID for c in lines.values())
    assert [c["y_abs_max"] > 0 for c in lines.values()] == [not b.is_planar for b in net.branches]
    # the view: no straight walls in a network (those drawn before the plant's markers came, deleted); the
    # route in 3-D, every point as recorded
    view = scene["view"]
    assert set(VIEW_NAMESPACES) <= set(view)
    assert all(view[ns]["action"] == DELETE for ns in {"upper_wall", "lower_wall"} & set(view))
    path = view["reference_path"]
    assert (path["type"], path["frame_id"], path["n_points"]) == (LINE_STRIP, FRAME_ID, len(rec["path"]))
    assert path["points_sum"] == _sums(rec["path"]) and (path["y_abs_max"] > 1e-4 or net.is_planar)
    # the robot: at the truth's position of its stamp, off the plane y = 0, inside the lumen
    assert len(scene["robot"]) >= 5
    for stamp, x, y, z in scene["robot"]:
        assert [x, y, z] == _xyz(rec["truth"][int(stamp)].position)
    off_plane = not net.is_planar  # a tree in the plane y = 0 (paper_iiic_artery_3d) keeps the robot there
    assert (max(abs(y) for _, _, y, _ in scene["robot"]) > 1e-4) == off_plane
    robot, stamp = view["robot"], int(view["robot"]["stamp"])
    truth = rec["truth"][stamp]
    assert robot["type"] == SPHERE and robot["position"] == _xyz(truth.position)
    assert (robot["position"][1] != 0.0) == off_plane
    assert NetworkGeometry(net, dims=3).query([robot["position"]])["sdist"][0] > 0
    r = 0.5 * (truth.vessel_diameter - truth.wall_gap_upper - truth.wall_gap_lower)
    assert robot["scale"] == pytest.approx([2 * r] * 3, rel=1e-12)
    # the estimate and the gradient arrow (from the robot along the applied 3-D gradient, 2 mm at the limit)
    assert view["estimate"]["type"] == SPHERE and len(view["estimate"]["position"]) == 3
    arrow = view["gradient"]
    stamp = int(arrow["stamp"])
    g = _xyz(rec["truth"][stamp].applied_gradient)
    a, b = arrow["points_head"]
    assert arrow["type"] == ARROW and a == _xyz(rec["truth"][stamp].position)
    assert any([bi - ai for ai, bi in zip(a, b)] == pytest.approx([ARROW_AT_LIMIT_M * gi / c.max_gradient for gi in g],
                                                                  rel=1e-9) for c in _near(rec["coil"], stamp))
    # the errors are 3-D norms (the reference's y counts)
    stamps = sorted(rec["truth"])
    assert all(abs(int(d) - TICK_NS) <= 1 for d in np.diff(stamps))  # every recorded tick, one tick apart (+-1 ns)
    errors = [e for e in got["views"]["errors"] if "tracking_error_m" in e]
    assert errors
    for e in errors:
        stamp = round(e["t_s"] * 1e9)
        p = _xyz(rec["truth"][stamp].position)
        # one tick's numbers: the truth's and the reference's of the same stamp (the view pairs them by stamp)
        assert e["tracking_error_m"] == pytest.approx(math.dist(p, _xyz(rec["reference"][stamp].position)), rel=1e-12)
        assert e["gradient_norm_T_per_m"] == pytest.approx(math.hypot(*_xyz(rec["truth"][stamp].applied_gradient)),
                                                           rel=1e-12)


@pytest.mark.parametrize("network", ["carotid_bifurcation_3d", "synthetic_tree_3d"])
def test_foxglove_client_sees_the_3d_wall_route_and_robot(ros, tmp_path, network):
    """A 3-D tree's scene, as Foxglove receives it (synthetic_tree_3d: the largest wall, 22 958 triangles, 1.7 MB)."""
    if network == RUN_NETWORK_3D:  # a real run
        got, bag = _run_scene(tmp_path, RUN_SCENARIO_3D)
    else:
        got, bag = _peer_scene(ros, tmp_path, network)
        assert got["reason"] == "scene", got["reason"]
    _check_scene(got, bag, network)
