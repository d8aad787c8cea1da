"""The bag of a real `vesselbot run`: complete (counts = publishers' counts), readable everywhere, reportable.

One short lockstep run of the paper scenario (0.3 s, seed 4, one process per
node, `--report`) is shared by the tests of this module.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

pytest.importorskip("rclpy")

from vesselbot_ros.bag.reader import final_diagnostics, iter_messages, open_bag
from vesselbot_ros.bag.report import FIGURES
from vesselbot_ros.graph_spec import NODE_NAMES, TOPICS, frame_topics, topic

CONFIG = "config/paper_small_artery.yaml"
N_TICKS = 300
PER_TICK = ("/clock", "/vesselbot/truth", "/vesselbot/measurement", "/vesselbot/estimate", "/vesselbot/reference",
            "/vesselbot/gradient_command", "/vesselbot/coil/applied", "/vesselbot/coil/state")
GRAPH_ROLES = ("plant", "imager", "observer", "controller", "coil_driver", "reference")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """(bag dir, metrics JSON of the launcher, stdout) of one recorded, reported run."""
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    tmp = tmp_path_factory.mktemp("run_bag")
    bag, metrics = tmp / "bag", tmp / "metrics.json"
    cmd = [sys.executable, "-m", "vesselbot_ros.cli", "run", "--config", CONFIG, "--duration", "0.3", "--seed", "4",
           "--quiet", "--record-dir", str(bag), "--metrics-json", str(metrics), "--report", "--all-metrics"]
    proc = subprocess.run(cmd, cwd=repo, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return bag, json.loads(metrics.read_text()), proc.stdout


def test_the_bag_folder_holds_the_bag_only_and_the_logs_and_report_go_beside_it(run):
    """`ros2 bag info` and Foxglove see a clean bag: no logs/, no report/ inside it."""
    bag, _, stdout = run
    assert sorted(p.name for p in bag.iterdir()) == ["bag.mcap", "metadata.yaml", "run_metadata.json"]
    logs = bag.with_name(f"{bag.name}.logs")
    assert (logs / "params.yaml").is_file() and any(logs.glob("*.log"))
    assert f"report: {bag.with_name(f'{bag.name}.report')}" in stdout
    # a run that ended normally leaves no alarm in any node's log (the stop signal ends the spin, not a callback)
    alarms = {p.name: p.read_text(errors="replace") for p in logs.glob("*.log")}
    assert not {n: t for n, t in alarms.items() if "FATAL" in t or "Traceback" in t}, alarms


def test_metadata_counts_equal_the_counts_the_publishers_reported(run):
    bag, _, _ = run
    info = open_bag(bag)
    assert info.consistent, info.problems  # metadata.yaml == MCAP statistics
    counts = {t.name: t.count for t in info.topics}
    assert set(counts) == {t.name for t in TOPICS}
    # every node's last /diagnostics (recorded in the bag) holds its final published:<topic> counts
    final = final_diagnostics(info)
    published: dict[str, int] = {}
    for role in GRAPH_ROLES:
        d = final[NODE_NAMES[role]]
        assert d["finished"] == "true", role
        for key, value in d.items():
            if key.startswith("published:"):
                name = key.split(":", 1)[1]
                published[name] = published.get(name, 0) + int(value)
    # /diagnostics is not counted by its publishers (every node and the recorder publish it); a run of positions
    # declares the MR frames' topics, with no message
    frames = {topic(k).name for k in frame_topics()}
    assert set(published) == set(counts) - {"/diagnostics"} - frames and all(counts[n] == 0 for n in frames)
    for name, n in published.items():
        assert counts[name] == n, name
    assert counts["/diagnostics"] >= len(GRAPH_ROLES)
    for name in PER_TICK:  # lockstep: exactly one per tick, nothing lost
        assert counts[name] == N_TICKS, name
    assert counts["/vesselbot/vessel_markers"] == 1 and counts["/vesselbot/reference/path"] == 1
    # and the recorder's own final count of what it received agrees
    rec = final[NODE_NAMES["recorder"]]
    for name in PER_TICK:
        assert int(rec[f"received:{name}"]) == N_TICKS, name


def test_the_bag_reads_back_with_rosbags_and_with_mcap(run):
    bag, _, _ = run
    info = open_bag(bag)
    from rosbags.highlevel import AnyReader

    per_topic: dict[str, int] = {}
    with AnyReader([bag]) as reader:
        assert reader.message_count == info.message_count
        for conn, _, raw in reader.messages():
            assert reader.deserialize(raw, conn.msgtype) is not None
            per_topic[conn.topic] = per_topic.get(conn.topic, 0) + 1
    assert per_topic == {t.name: t.count for t in info.topics if t.count}  # coil/stall: declared, no message

    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    mcap_topics: dict[str, int] = {}
    truth_ticks = []
    with info.mcap_paths[0].open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, _, msg in reader.iter_decoded_messages():
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            mcap_topics[channel.topic] = mcap_topics.get(channel.topic, 0) + 1
            if channel.topic == "/vesselbot/truth":
                truth_ticks.append(msg.tick)
    assert mcap_topics == per_topic
    assert truth_ticks == list(range(N_TICKS))
    # the bag is self-describing: the run's config and seed
    assert info.run_metadata["seed"] == 4 and info.run_metadata["mode"] == "lockstep"
    assert info.run_metadata["config"]["sim"]["duration_s"] == 0.3


def _same(a, b) -> bool:
    """JSON metric equality; the report writes NaN as null, the launcher as NaN."""
    if isinstance(a, float) and math.isnan(a):
        return b is None or (isinstance(b, float) and math.isnan(b))
    return a == b


def test_report_writes_every_figure_and_the_metrics_the_run_printed(run, tmp_path):
    bag, launcher, stdout = run
    report = bag.with_name(f"{bag.name}.report")  # written by `vesselbot run --report`, beside the bag
    assert f"report: {report}" in stdout
    for name in FIGURES:
        data = (report / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, name
    from_bag = json.loads((report / "metrics.json").read_text())
    ran = launcher["metrics"]
    for key, value in ran.items():  # every metric of the run, same compute_metrics, bit for bit
        assert key in from_bag, key
        assert _same(value, from_bag[key]), f"{key}: run {value!r}, report {from_bag[key]!r}"
    # what the run printed is what the bag says: its one-line result (as simulate's), and with --all-metrics each metric
    from vesselbot_ros.sim.metrics import headline

    assert f": {headline(from_bag)}" in stdout, stdout
    printed = {}
    for line in stdout.splitlines():
        parts = line.split()
        if line.startswith("  ") and len(parts) == 2 and parts[0] in ran:
            printed[parts[0]] = parts[1]
    assert set(printed) == set(ran)
    for key, text in printed.items():
        v = from_bag[key]
        if ran[key] is None:  # does not apply to this run (diverged_at_s when it did not diverge)
            want = "-"
        else:
            want = "nan" if v is None else (f"{v:.6g}" if isinstance(v, float) else str(v))
        assert text == want, key
    # `vesselbot report` on the same bag gives the same metrics
    out = tmp_path / "rep"
    proc = subprocess.run([sys.executable, "-m", "vesselbot_ros.cli", "report", str(bag), "--out", str(out)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    again = json.loads((out / "metrics.json").read_text())
    assert {k: v for k, v in again.items() if k != "bag"} == {k: v for k, v in from_bag.items() if k != "bag"}
    # per-tick topics decode to the ticks 0..n-1 in the estimate too
    stamps = [m.decode().header.stamp.nanosec for m in iter_messages(bag, topics=["/vesselbot/estimate"])]
    assert stamps == [k * 1_000_000 for k in range(N_TICKS)]
