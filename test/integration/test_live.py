"""``vesselbot run --live`` and ``replay --live``: Foxglove's own client (@foxglove/ws-protocol, run by node) on the live view.

The client offers exactly one WebSocket subprotocol per test: ``foxglove.sdk.v1`` (the
SDK's name) or ``foxglove.websocket.v1`` (the protocol specification's, ws-protocol's
default, older Foxglove releases and Lichtblick).  Both must connect; both must see the
``time`` capability broadcast the simulation's time (the recorded ``/clock``), never the
wall clock.
"""

from __future__ import annotations

import math
import queue
import re
import signal
import subprocess
import sys
import threading
import time

import pytest

from _runs import free_port, last_json, node_client, run_cmd
from vesselbot_ros.bag.reader import iter_messages, open_bag
from vesselbot_ros.graph_spec import TOPICS, VIEW_CHANNELS, ns_of_time, topic
from vesselbot_ros.live import clock_ns
from vesselbot_ros.live_view import ERRORS_SCHEMA_NAME

LINE_TIMEOUT_S = 120.0


def _lines(proc: subprocess.Popen[str]) -> queue.Queue[str | None]:
    """Every stdout line of ``proc`` as it comes (None at its end), read by a thread."""
    q: queue.Queue[str | None] = queue.Queue()

    def pump() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            q.put(line)
        q.put(None)

    threading.Thread(target=pump, daemon=True).start()
    return q


def _wait_line(q: queue.Queue[str | None], pattern: str, seen: list[str]) -> re.Match[str]:
    """The first line matching ``pattern`` (bounded by LINE_TIMEOUT_S); every line read goes to ``seen``."""
    deadline = time.monotonic() + LINE_TIMEOUT_S
    while True:
        left = deadline - time.monotonic()
        assert left > 0, f"no line matching {pattern!r} in {LINE_TIMEOUT_S} s: {''.join(seen)[-2000:]}"
        try:
            line = q.get(timeout=left)
        except queue.Empty:
            continue
        assert line is not None, f"the process ended without a line matching {pattern!r}: {''.join(seen)[-2000:]}"
        seen.append(line)
        m = re.search(pattern, line)
        if m:
            return m


def _recorded(bag):
    """From the bag: truth by stamp -> (x, z, log time), log times per topic, and the /clock sim times in order."""
    truth, log_times, clock = {}, {}, []
    for m in iter_messages(open_bag(bag)):
        log_times.setdefault(m.topic, set()).add(m.log_time_ns)
        if m.topic == topic("truth").name:
            msg = m.decode()
            truth[msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec] = (
                msg.position.x, msg.position.z, m.log_time_ns)
        elif m.topic == topic("clock").name:
            clock.append(clock_ns(m.data))
    return truth, log_times, clock


def _check_sim_time(got, clock, *, monotonic=True, final=True):
    """The ``time`` capability is advertised and its broadcasts are the run's sim times, not the wall clock."""
    assert "time" in got["capabilities"]
    times = [int(t) for t in got["times"]]
    assert len(set(times)) >= 2, times
    assert set(times) <= set(clock)
    assert max(times) < 10**11  # sim ns of a short run; a wall-clock time would be ~1.8e18
    if monotonic:
        assert times == sorted(times)
    if final:  # the last sim time reaches the client (the rate limit holds back at most until a flush)
        assert max(times) == clock[-1]
    return times


def _check_log_times(got, truth, log_times):
    """Every message the client got carries its original log time (the bag's): live, latched and re-sent alike."""
    for name, stamps in got["log_times"].items():
        if name in log_times:
            assert {int(t) for t in stamps} <= log_times[name], name
    path = got["log_times"][topic("reference_path").name]
    assert path and {int(t) for t in path} <= log_times[topic("reference_path").name]
    live = {int(t): (x, z, int(lt)) for t, x, z, lt in got["positions"]}
    assert live and set(live) <= set(truth)
    assert all(live[t] == truth[t] for t in live)  # positions and log times equal the bag's at the same stamps
    return live


def test_foxglove_client_decodes_every_channel_and_sees_the_recorded_positions(tmp_path):
    """Client offering only ``foxglove.sdk.v1``, connected before the run: every channel, every tick, on sim time."""
    port = free_port()
    client = node_client("ws_live.mjs", str(port), "120", "60", "--subprotocol", "foxglove.sdk.v1")
    bag = tmp_path / "bag"
    try:
        run = subprocess.run(run_cmd("--config", "sound_small_artery", "--duration", "0.3", "--live-port", str(port),
                                     "--live-rate", "0", "--record-dir", str(bag), "--quiet"),
                             cwd=tmp_path, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr[-3000:]
        assert f"live view: ws://127.0.0.1:{port} " in run.stdout
        got = last_json(client, timeout=120)  # the server stops with the recorder: the client ends
    finally:
        if client.poll() is None:
            client.kill()
    assert got["reason"] == "server closed" and got["subprotocol"] == "foxglove.sdk.v1"
    # every topic of the graph spec is advertised, as cdr with its ros2msg schema, and the derived view channels
    adv = {a["topic"]: a for a in got["advertised"]}
    assert set(adv) == {t.name for t in TOPICS} | {v.name for v in VIEW_CHANNELS}
    for v in VIEW_CHANNELS:
        assert adv[v.name]["encoding"] == ("json" if v.msgtype == "json" else "cdr")
        assert adv[v.name]["schemaName"] == (ERRORS_SCHEMA_NAME if v.msgtype == "json" else v.msgtype)
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
    # the robot positions received equal the bag's at the same stamps, with the bag's log times
    truth, log_times, clock = _recorded(bag)
    assert len(truth) == 300
    live = _check_log_times(got, truth, log_times)
    # the client connected while the recorder waited for the nodes: it saw the run from tick 0
    assert ns_of_time(0.0) in live and len(live) == 300
    # Foxglove's timeline: sim time from /clock, covering the run, and every view update within it
    times = _check_sim_time(got, clock)
    assert max(times) >= max(live) and all(min(times) <= round(e["t_s"] * 1e9) <= max(times) for e in errors)


@pytest.fixture(scope="module")
def port0_run(tmp_path_factory):
    """``vesselbot run --live-port 0`` (default live rate); a client offering only ``foxglove.websocket.v1``
    connects, without retries, to the port the run printed."""
    tmp = tmp_path_factory.mktemp("live0")
    bag = tmp / "bag"
    err = open(tmp / "run.stderr", "w")  # noqa: SIM115 - a file (a pipe nobody reads could fill and block the run) the fixture closes
    run = subprocess.Popen(run_cmd("--duration", "1.0", "--live-port", "0", "--record-dir", str(bag),
                                   "--metrics-json", str(tmp / "m.json"), "--quiet"),
                           cwd=tmp, stdout=subprocess.PIPE, stderr=err, text=True)
    client = None
    try:
        lines, seen = _lines(run), []
        port = int(_wait_line(lines, r"^live view: ws://127\.0\.0\.1:(\d+) ", seen).group(1))
        client = node_client("ws_live.mjs", str(port), "0", "60", "--subprotocol", "foxglove.websocket.v1",
                             "--no-retry")
        assert run.wait(timeout=300) == 0, (tmp / "run.stderr").read_text()[-3000:]
        got = last_json(client, timeout=120)
    finally:
        for p in (run, client):
            if p is not None and p.poll() is None:
                p.kill()
        err.close()
    yield port, got, bag, tmp


def test_live_port_0_prints_the_bound_port_once_it_accepts_and_the_spec_subprotocol_connects(port0_run):
    port, got, bag, _ = port0_run
    assert port > 0
    assert got["reason"] == "server closed" and got["subprotocol"] == "foxglove.websocket.v1"
    assert got["decode_errors"] == {} and got["positions"]
    truth, log_times, clock = _recorded(bag)
    _check_log_times(got, truth, log_times)
    _check_sim_time(got, clock)


def test_the_live_view_sends_each_topic_at_most_at_the_live_rate(port0_run):
    """Default --live-rate (50 per topic and wall second): a subset of the ticks, each equal to the bag's."""
    import json

    _, got, bag, tmp = port0_run
    wall = json.loads((tmp / "m.json").read_text())["wall_s"]
    truth, _, _ = _recorded(bag)
    live = {int(t): (x, z) for t, x, z, _ in got["positions"]}
    assert 1 <= len(live) <= 50 * (wall + 1.0) and len(live) < len(truth) == 1000
    assert all(live[t] == truth[t][:2] for t in live)


def test_replay_live_serves_the_bag_on_its_sim_time_to_a_spec_subprotocol_client(ros, port0_run, tmp_path):
    """``replay --live-port 0 --loop``: the printed port accepts at once; the bag's messages with their log
    times, and its /clock as the time (going back to the start at each pass, which Foxglove takes as a seek)."""
    _, _, bag, _ = port0_run
    err_path = tmp_path / "replay.stderr"
    err = open(err_path, "w")  # noqa: SIM115 - a file, closed below: one line per pass, and nobody reads a pipe while it runs
    replay = subprocess.Popen([sys.executable, "-m", "vesselbot_ros.cli", "replay", str(bag), "--loop",
                               "--live-port", "0"], env=ros.env, stdout=subprocess.PIPE, stderr=err, text=True)
    client = None
    try:
        lines, seen = _lines(replay), []
        port = int(_wait_line(lines, r"live view on ws://127\.0\.0\.1:(\d+)$", seen).group(1))
        client = node_client("ws_live.mjs", str(port), "0", "60", "--subprotocol", "foxglove.websocket.v1",
                             "--no-retry", "--max-messages", "300")
        got = last_json(client, timeout=120)
        replay.send_signal(signal.SIGINT)
        assert replay.wait(timeout=60) == 0, err_path.read_text()[-3000:]
    finally:
        for p in (replay, client):
            if p is not None and p.poll() is None:
                p.kill()
        err.close()
    assert got["reason"] == "max messages" and got["subprotocol"] == "foxglove.websocket.v1"
    assert got["decode_errors"] == {}
    assert {a["topic"] for a in got["advertised"]} == {t.name for t in open_bag(bag).topics} | \
        {v.name for v in VIEW_CHANNELS}
    truth, log_times, clock = _recorded(bag)
    _check_log_times(got, truth, log_times)
    _check_sim_time(got, clock, monotonic=False, final=False)  # a loop starts its time again
