"""live_view: the derived scene and errors, and the Foxglove layout only names channels the live view serves."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from vesselbot_ros.graph_spec import TOPICS, VIEW_CHANNELS
from vesselbot_ros.live_view import ARROW_AT_LIMIT_M, scene_numbers

REPO = Path(__file__).resolve().parents[2]


def test_scene_numbers_take_the_radius_from_the_gap_and_errors_as_norms():
    d, z, r = 3e-3, 2e-4, 2.5e-4
    gap = 0.5 * d - z - r
    sn = scene_numbers(0.5, (1e-3, z), d, gap, (0.03, -0.04), 0.08, (1e-3 + 3e-6, z + 4e-6), (1e-3 - 6e-5, z + 8e-5))
    assert sn.robot_radius_m == pytest.approx(r, abs=1e-18)
    assert sn.wall_z_m == 0.5 * d
    assert sn.estimation_error_m == pytest.approx(5e-6, rel=1e-9)
    assert sn.tracking_error_m == pytest.approx(1e-4, rel=1e-9)
    none = scene_numbers(0.0, (0.0, 0.0), d, 0.5 * d - r, (0.0, 0.0), 0.08, None, None)
    assert none.tracking_error_m is None and none.estimation_error_m is None


def test_markers_draw_pulsing_walls_robot_estimate_gradient_arrow_and_path():
    pytest.importorskip("rclpy")
    from geometry_msgs.msg import Point
    from std_msgs.msg import Header
    from visualization_msgs.msg import Marker

    from vesselbot_ros.live_view import DerivedView

    view = DerivedView(lambda *a: None)
    view._path_points = [Point(x=0.0, z=0.0), Point(x=0.01, z=1e-4)]
    sn = scene_numbers(0.1, (2e-3, 1e-4), 3.1e-3, 0.5 * 3.1e-3 - 1e-4 - 2.5e-4, (0.08, 0.0), 0.08,
                       (2e-3, 1e-4), None)
    ms = {m.ns: m for m in view.markers(sn, Header()).markers}
    assert set(ms) == {"upper_wall", "lower_wall", "robot", "estimate", "gradient", "reference_path"}
    assert ms["upper_wall"].pose.position.z > 0.5 * 3.1e-3 > -ms["lower_wall"].pose.position.z - 1e-3
    assert ms["upper_wall"].pose.position.z - ms["upper_wall"].scale.z / 2 == pytest.approx(0.5 * 3.1e-3)
    assert ms["robot"].type == Marker.SPHERE and ms["robot"].scale.x == pytest.approx(5e-4)
    a, b = ms["gradient"].points
    assert math.hypot(b.x - a.x, b.z - a.z) == pytest.approx(ARROW_AT_LIMIT_M)  # |G| at the limit: 2 mm
    assert all(m.header.frame_id == "vessel" for m in ms.values())


def test_layout_names_only_channels_the_live_view_serves():
    layout = json.loads((REPO / "config" / "foxglove" / "vesselbot.json").read_text())
    served = {t.name for t in TOPICS} | {v.name for v in VIEW_CHANNELS}
    named = set()
    for cfg in layout["configById"].values():
        named |= set(cfg.get("topics", {}))
        named |= {p["value"].split(".", 1)[0] for p in cfg.get("paths", [])}
        if "topicPath" in cfg:
            named.add(cfg["topicPath"].split(".", 1)[0])
    assert named and named <= served, named - served
    assert {v.name for v in VIEW_CHANNELS} <= named  # every derived channel has a panel
