"""``vesselbot run --live``: Foxglove's own client (@foxglove/ws-protocol, run by node) on the live view."""

from __future__ import annotations

import subprocess

from _runs import free_port, last_json, node_client, run_cmd
from vesselbot_ros.bag.reader import iter_messages, open_bag
import math

from vesselbot_ros.graph_spec import TOPICS, VIEW_CHANNELS, ns_of_time, topic


def test_foxglove_client_decodes_every_channel_and_sees_the_recorded_positions(tmp_path):
    port = free_port()
    client = node_client("ws_live.mjs", str(port), "120", "60")
    bag = tmp_path / "bag"
    try:
        run = subprocess.run(run_cmd("--config", "sound_small_artery", "--duration", "0.3", "--live-port", str(port),
                                     "--live-rate", "0", "--record-dir", str(bag), "--quiet"),
                             cwd=tmp_path, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr[-3000:]
        assert f"live view: ws://127.0.0.1:{port}" in run.stdout
        got = last_json(client, timeout=120)  # the server stops with the recorder: the client ends
    finally:
        if client.poll() is None:
            client.kill()
    assert got["reason"] == "server closed"
    # every topic of the graph spec is advertised, as cdr with its ros2msg schema, and the derived view channels
    adv = {a["topic"]: a for a in got["advertised"]}
    assert set(adv) == {t.name for t in TOPICS} | {v.name for v in VIEW_CHANNELS}
    for v in VIEW_CHANNELS:
        assert adv[v.name]["encoding"] == ("json" if v.msgtype == "json" else "cdr")
    for t in TOPICS:
        assert (adv[t.name]["encoding"], adv[t.name]["schemaEncoding"], adv[t.name]["schemaName"]) == \
            ("cdr", "ros2msg", t.msgtype)
    # messages on every channel, each decoded by Foxglove's deserializer from the advertised schema
    assert got["decode_errors"] == {}
    # (a topic the bag holds no message of, coil/stall in a run without a stall, has none here either)
    in_bag = {t.name: t.count for t in open_bag(bag).topics}
    assert in_bag[topic("coil_stall").name] == 0
    assert all(got["counts"].get(name, 0) >= 1 for name in adv if in_bag.get(name, 1)), got["counts"]
    # the view: walls, robot, estimate, gradient arrow and path; errors and |G| within the coil's per-axis limit
    assert set(got["views"]["marker_namespaces"]) == {"upper_wall", "lower_wall", "robot", "estimate", "gradient",
                                                      "reference_path"}
    errors = got["views"]["errors"]
    assert errors and set(errors[-1]) == {"t_s", "tracking_error_m", "estimation_error_m", "gradient_norm_T_per_m",
                                          "gradient_limit_T_per_m"}
    for e in errors:  # the first ones may precede the first estimate or coil state
        assert 0 <= e.get("tracking_error_m", 0) < 5e-3 and 0 <= e.get("estimation_error_m", 0) < 5e-3
        assert 0 <= e["gradient_norm_T_per_m"] <= math.sqrt(2) * e.get("gradient_limit_T_per_m", math.inf)
    assert [e["t_s"] for e in errors] == sorted(e["t_s"] for e in errors)
    # the robot positions received equal the bag's at the same stamps
    recorded = {}
    for m in iter_messages(open_bag(bag), topics=["/vesselbot/truth"]):
        msg = m.decode()
        recorded[msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec] = (msg.position.x, msg.position.z)
    assert len(recorded) == 300
    live = {int(t): (x, z) for t, x, z in got["positions"]}
    assert len(live) >= 1 and set(live) <= set(recorded)
    assert all(live[t] == recorded[t] for t in live)
    # the client connected while the recorder waited for the nodes: it saw the run from tick 0
    assert ns_of_time(0.0) in live and len(live) == 300


def test_the_live_view_sends_each_topic_at_most_at_the_live_rate(tmp_path):
    """Default --live-rate (50 per topic and wall second): a subset of the ticks, each equal to the bag's."""
    import json

    port = free_port()
    client = node_client("ws_live.mjs", str(port), "120", "60")
    bag = tmp_path / "bag"
    try:
        run = subprocess.run(run_cmd("--duration", "1.0", "--live-port", str(port), "--record-dir", str(bag),
                                     "--metrics-json", str(tmp_path / "m.json"), "--quiet"),
                             cwd=tmp_path, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr[-3000:]
        got = last_json(client, timeout=120)
    finally:
        if client.poll() is None:
            client.kill()
    wall = json.loads((tmp_path / "m.json").read_text())["wall_s"]
    recorded = {}
    for m in iter_messages(open_bag(bag), topics=["/vesselbot/truth"]):
        msg = m.decode()
        recorded[msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec] = (msg.position.x, msg.position.z)
    live = {int(t): (x, z) for t, x, z in got["positions"]}
    assert 1 <= len(live) <= 50 * (wall + 1.0) and len(live) < len(recorded) == 1000
    assert all(live[t] == recorded[t] for t in live)
