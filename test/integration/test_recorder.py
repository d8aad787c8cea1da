"""The recorder node over real topics: counts, decoding, SIGINT, SIGKILL + repair, bad directories."""

from __future__ import annotations

import json
import signal
from pathlib import Path

import pytest

rclpy = pytest.importorskip("rclpy")
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from vesselbot_ros.bag.reader import iter_messages, open_bag  # noqa: E402
from vesselbot_ros.bag.repair import repair_bag  # noqa: E402
from vesselbot_ros.errors import BagError  # noqa: E402
from vesselbot_ros.nodes.recorder_node import FLUSH_SERVICE, recorder_command  # noqa: E402
from vesselbot_ros.testing import NodeProcess, call_service, spin_until  # noqa: E402

PEER = Path(__file__).with_name("graph_publisher_peer.py")
META = {"scenario": "synthetic", "seed": 3, "mode": "lockstep", "config": {"a": {"b": "it's quoted"}},
        "versions": {"vesselbot_ros": "test"}, "command": ["pytest"]}


def _probe(ros):
    node = rclpy.create_node("recorder_probe", context=ros.context)
    ex = SingleThreadedExecutor(context=ros.context)
    ex.add_node(node)
    return node, ex, node.create_client(Trigger, FLUSH_SERVICE)


def _flush(ex, client) -> dict[str, int]:
    resp = call_service(ex, client, Trigger.Request(), timeout=10)  # a flush again changes nothing
    assert resp is not None and resp.success, resp
    return json.loads(resp.message)


def _start(ros, tmp_path, out: Path, ticks: int, rate: float):
    rec = NodeProcess(recorder_command(out, META), ros.env, tmp_path / "recorder.log")
    node, ex, client = _probe(ros)
    assert spin_until(ex, client.service_is_ready, timeout=30), rec.output()
    pub = NodeProcess(["python", str(PEER), str(tmp_path / "counts.json"), str(ticks), str(rate)], ros.env,
                      tmp_path / "peer.log")
    return rec, pub, node, ex, client


def _published_truth(tmp_path: Path) -> int:
    """Truth messages the peer has published so far (it rewrites counts.json atomically every 50 ticks)."""
    path = tmp_path / "counts.json"
    return json.loads(path.read_text()).get("published:/vesselbot/truth", 0) if path.exists() else 0


def _contiguous_ticks(bag) -> list[int]:
    return [m.decode().tick for m in iter_messages(bag, topics=["/vesselbot/truth"])]


def test_recorded_counts_equal_published_counts_and_the_bag_decodes_everywhere(ros, tmp_path):
    out = tmp_path / "runs" / "r1"
    (out / "logs").mkdir(parents=True)  # the launcher's ROS log folder may already be there
    rec, pub, node, ex, client = _start(ros, tmp_path, out, ticks=600, rate=500.0)
    try:
        assert spin_until(ex, lambda: "done" in pub.output(), timeout=60), pub.output()
        published = json.loads((tmp_path / "counts.json").read_text())
        expect = {k.split(":", 1)[1]: v for k, v in published.items()}
        assert expect["/vesselbot/truth"] == 600 and expect["/vesselbot/vessel_markers"] == 1
        assert spin_until(ex, lambda: all(_flush(ex, client).get(t) == n for t, n in expect.items()
                                          if t != "/diagnostics"), timeout=30)
        assert rec.stop(timeout=20) == 0, rec.output()
    finally:
        pub.stop()
        rec.stop()
        node.destroy_node()
    info = open_bag(out)
    assert info.consistent, info.problems
    counts = {t.name: t.count for t in info.topics}
    for topic_name, n in expect.items():
        if topic_name == "/diagnostics":  # the recorder's own /diagnostics are recorded too
            assert counts[topic_name] >= n
        else:
            assert counts[topic_name] == n, topic_name
    assert info.run_metadata == META
    assert _contiguous_ticks(info) == list(range(600))
    # every custom type decodes with mcap + mcap_ros2 from the embedded schemas alone
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with info.mcap_paths[0].open("rb") as fh:
        seen = {}
        for schema, _, _, msg in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            seen[schema.name] = msg
    assert seen["vesselbot_msgs/msg/PlantState"].forces.total.x == pytest.approx(8e-9, rel=1e-12)
    assert seen["vesselbot_msgs/msg/CoilState"].max_gradient == 0.08
    assert seen["vesselbot_msgs/msg/ReferenceSample"].tick == 599
    from rosbags.highlevel import AnyReader

    with AnyReader([out]) as r:
        n = sum(1 for c, _, raw in r.messages() if r.deserialize(raw, c.msgtype) is not None)
    assert n == info.message_count


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_mid_run_leaves_a_finalised_complete_bag(ros, tmp_path, sig):
    out = tmp_path / "r2"
    rec, pub, node, ex, _client = _start(ros, tmp_path, out, ticks=0, rate=500.0)
    try:
        # a second of ticks published (a fixed sleep let a loaded machine publish fewer than the bound below)
        assert spin_until(ex, lambda: _published_truth(tmp_path) >= 500, timeout=60), pub.output()
        assert rec.stop(timeout=20, sig=sig) == 0, rec.output()
        assert "finalised" in rec.log_path.read_text()
    finally:
        pub.stop()
        rec.stop()
        node.destroy_node()
    info = open_bag(out)
    assert info.consistent, info.problems
    ticks = _contiguous_ticks(info)
    assert len(ticks) > 200 and ticks == list(range(len(ticks)))


def test_sigkill_leaves_an_mcap_that_repair_turns_into_a_valid_bag(ros, tmp_path):
    out = tmp_path / "r3"
    rec, pub, node, ex, _client = _start(ros, tmp_path, out, ticks=0, rate=500.0)
    try:
        assert spin_until(ex, lambda: _published_truth(tmp_path) >= 1000, timeout=60), pub.output()
        rec.stop(timeout=5, sig=signal.SIGKILL)
        killed_at = json.loads((tmp_path / "counts.json").read_text())["published:/vesselbot/truth"]
    finally:
        pub.stop()
        rec.stop()
        node.destroy_node()
    assert not (out / "metadata.yaml").exists()
    with pytest.raises(BagError, match="no metadata.yaml; run `vesselbot bag repair"):
        open_bag(out)
    res = repair_bag(out)
    assert res.repaired
    info = open_bag(out)
    assert info.consistent and info.run_metadata == META
    ticks = _contiguous_ticks(info)
    # a 0.5 s flush period at 500 ticks/s loses at most ~250 ticks (+ scheduling slack)
    assert ticks == list(range(len(ticks))) and len(ticks) >= killed_at - 500 > 0


def test_unwritable_directory_or_existing_bag_fails_at_start_with_a_clear_error(ros, tmp_path):
    afile = tmp_path / "file"
    afile.write_text("x")
    rec = NodeProcess(recorder_command(afile / "run", META), ros.env, tmp_path / "rec_bad.log")
    assert rec.wait(timeout=30) == 1
    rec.stop()
    assert "cannot create bag directory" in rec.log_path.read_text()
    out = tmp_path / "full"
    out.mkdir()
    (out / "metadata.yaml").write_text("x")
    rec = NodeProcess(recorder_command(out, META), ros.env, tmp_path / "rec_exists.log")
    assert rec.wait(timeout=30) == 1
    rec.stop()
    assert "already holds a bag (metadata.yaml)" in rec.log_path.read_text()


def test_full_disk_stops_the_recorder_with_one_line_and_a_repairable_bag(ros, tmp_path):
    """The MCAP may not grow past 600 kB (RLIMIT_FSIZE: writes fail as on a full disk)."""
    out = tmp_path / "r5"
    limit = 600_000
    argv = ["python", "-c", "import os, resource, sys; "
            f"resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit})); os.execvp(sys.argv[1], sys.argv[1:])",
            *recorder_command(out, META)]
    rec = NodeProcess(argv, ros.env, tmp_path / "recorder.log")
    node, ex, client = _probe(ros)
    pub = None
    try:
        assert spin_until(ex, client.service_is_ready, timeout=30), rec.output()
        # 100 ticks/s (~0.2 MB/s): several 0.5 s chunks (~0.1 MB each) are written before the 600 kB cap;
        # at 500 ticks/s one chunk was about the cap, and whether any tick survived was a matter of timing
        pub = NodeProcess(["python", str(PEER), str(tmp_path / "counts.json"), "0", "100"], ros.env,
                          tmp_path / "peer.log")
        assert spin_until(ex, lambda: not rec.alive(), timeout=90), rec.output()
        assert rec.wait(5) == 1
    finally:
        if pub is not None:
            pub.stop()
        rec.stop()
        node.destroy_node()
    log = rec.log_path.read_text()
    assert "Traceback" not in log and "Error occurred at" not in log and "FATAL" not in log, log
    errors = [ln for ln in log.splitlines() if ln.startswith("vesselbot recorder: error:")]
    assert len(errors) == 1, log
    assert "while recording" in errors[0] and f"vesselbot bag repair {out}" in errors[0]
    assert (out / f"{out.name}.mcap").stat().st_size <= limit
    res = repair_bag(out)
    info = open_bag(out)
    assert res.repaired and info.consistent and info.run_metadata == META
    ticks = _contiguous_ticks(info)
    assert len(ticks) > 50 and ticks == list(range(len(ticks)))
