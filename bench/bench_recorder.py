"""Recorder throughput: the graph's message mix at increasing tick rates, counting drops.

For each control rate (ticks/s; 8 messages per tick, the lockstep graph's mix
of vesselbot_ros.bag.synthetic, plus /diagnostics every 100 ticks) a fresh
recorder process records DURATION_S of traffic published by this process
(raw, pre-serialized CDR, reliable QoS as in topics.py).  Drops = published -
recorded, over the 8 per-tick topics (the recorder adds its own /diagnostics) (from the recorder's flush service,
then from the finalised bag's
metadata.yaml).  Prints one line per rate and the highest message rate
sustained with zero drops.  Target: 1 kHz control (about 8 k msg/s) without
drops.

Then the compression presets (``--compression``): the bag writer alone on the
same message mix as fast as it goes (msg/s, MB/s of CDR, bag size and ratio
against an uncompressed bag, side by side), and a recorder process per preset
at 1 kHz control (drops, bag size).

Usage: python bench/bench_recorder.py [DURATION_S] [RATE_HZ ...]
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import rclpy
from rclpy.serialization import serialize_message
from std_srvs.srv import Trigger

from vesselbot_ros.bag.reader import open_bag
from vesselbot_ros.bag.synthetic import tick_messages
from vesselbot_ros.graph_spec import TOPICS, qos_profile, topic
from vesselbot_ros.nodes.recorder_node import FLUSH_SERVICE, recorder_command
from vesselbot_ros.testing import NodeProcess, call_service, isolated_ros, spin_until

DIAGNOSTICS = topic("diagnostics").name


def bench_rate(ros, work: Path, rate_hz: float, duration_s: float, compression: str = "none"
               ) -> tuple[int, int, float, int]:
    """Return (published, recorded, achieved publish rate in msg/s, bag size in bytes)."""
    out = Path(tempfile.mkdtemp(dir=work)) / f"bag_{int(rate_hz)}"
    rec = NodeProcess(recorder_command(out, {"scenario": "bench", "rate_hz": rate_hz}, compression=compression),
                      ros.env, work / f"rec_{int(rate_hz)}_{compression}.log")
    node = rclpy.create_node(f"bench_{int(rate_hz)}", context=ros.context)
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=ros.context)
    ex.add_node(node)
    client = node.create_client(Trigger, FLUSH_SERVICE)
    specs = {s.name: s for s in TOPICS}
    sample = [tick_messages(k) for k in range(100)]
    pubs = {name: node.create_publisher(type(msg), name, qos_profile(specs[name])) for name, msg in sample[0]}
    raw = [[(pubs[n], serialize_message(m)) for n, m in tick] for tick in sample]
    try:
        assert spin_until(ex, lambda: client.service_is_ready() and all(
            p.get_subscription_count() > 0 for p in pubs.values()), 30), rec.output()
        time.sleep(0.5)
        n_ticks = int(rate_hz * duration_s)
        published = 0
        t0 = time.monotonic()
        for k in range(n_ticks):
            delay = t0 + k / rate_hz - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            for pub, data in raw[k % 100]:
                pub.publish(data)
                published += pub.topic_name != DIAGNOSTICS  # the recorder publishes there too
        elapsed = time.monotonic() - t0
        for p in pubs.values():
            from rclpy.duration import Duration

            p.wait_for_all_acked(Duration(seconds=10))
        recorded = -1
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            answer = call_service(ex, client, Trigger.Request(), 10)  # a flush again changes nothing
            counts = json.loads(answer.message) if answer is not None else {}
            recorded = sum(v for k, v in counts.items() if k in pubs and k != DIAGNOSTICS)
            if recorded >= published:
                break
            time.sleep(0.2)
        rec.stop(timeout=30)
        info = open_bag(out)
        in_bag = sum(t.count for t in info.topics if t.name in pubs and t.name != DIAGNOSTICS)
        size = sum(p.stat().st_size for p in info.mcap_paths)
        return published, in_bag, published / elapsed, size
    finally:
        rec.stop()
        node.destroy_node()


def main() -> int:
    duration = float(sys.argv[1]) if len(sys.argv) > 1 else 3.0
    rates = [float(r) for r in sys.argv[2:]] or [250.0, 500.0, 1000.0, 2000.0, 4000.0]
    best = 0.0
    with tempfile.TemporaryDirectory() as tmp, isolated_ros(tmp) as ros:
        print(f"recorder throughput, {duration:.0f} s per rate, 8 msgs/tick (+ /diagnostics)")
        for rate in rates:
            pub, got, achieved, _ = bench_rate(ros, Path(tmp), rate, duration)
            drops = pub - got
            print(f"  control {rate:6.0f} Hz: published {pub:7d} at {achieved:8.0f} msg/s, "
                  f"recorded {got:7d}, drops {drops}")
            if drops == 0:
                best = max(best, achieved)
    print(f"highest rate sustained with zero drops: {best:.0f} msg/s "
          f"({best / 8:.0f} Hz control; target 1000 Hz = 8000 msg/s)")
    bench_compression(duration)
    return 0


def writer_throughput(out: Path, compression: str, n_ticks: int) -> tuple[float, float, int]:
    """The bag writer alone on n_ticks of the graph's mix: (msg/s, MB/s of CDR, bag bytes)."""
    from vesselbot_ros.bag.writer import BagWriter

    specs = {s.name: s for s in TOPICS}
    sample = [[(n, serialize_message(m)) for n, m in tick_messages(k)] for k in range(n_ticks)]
    n_msgs = sum(len(t) for t in sample)
    n_bytes = sum(len(d) for t in sample for _, d in t)
    bag = BagWriter(out, run_metadata={"scenario": "bench"}, compression=compression).open()
    conns = {name: bag.add_topic(name, specs[name].msgtype) for name, _ in sample[0]}
    t0 = time.perf_counter()
    t_ns = 1_700_000_000_000_000_000
    for k, tick in enumerate(sample):
        for name, data in tick:
            bag.write(conns[name], data, t_ns + k * 1_000_000)
    bag.finish()
    wall = time.perf_counter() - t0
    size = sum(p.stat().st_size for p in open_bag(out).mcap_paths)
    return n_msgs / wall, n_bytes / wall / 1e6, size


def bench_compression(duration: float) -> None:
    from vesselbot_ros.bag.writer import COMPRESSION_PRESETS

    n_ticks = 10_000  # 10 s of the 1 kHz graph, 80 k messages
    with tempfile.TemporaryDirectory() as tmp:
        rows = {c: writer_throughput(Path(tmp) / c, c, n_ticks) for c in COMPRESSION_PRESETS}
    base = rows["none"]
    print(f"\nbag writer alone, {n_ticks} ticks of the graph's mix ({n_ticks * 8} messages):")
    print(f"  {'compression':12s} {'msg/s':>10s} {'MB/s':>8s} {'bag MB':>8s} {'size / none':>12s} {'speed / none':>13s}")
    for c, (rate, mbs, size) in rows.items():
        print(f"  {c:12s} {rate:10.0f} {mbs:8.2f} {size / 1e6:8.2f} {size / base[2]:12.3f} {rate / base[0]:13.3f}")
    with tempfile.TemporaryDirectory() as tmp, isolated_ros(tmp) as ros:
        print(f"\nrecorder process at 1000 Hz control, {duration:.0f} s:")
        sizes = {}
        for c in COMPRESSION_PRESETS:
            pub, got, achieved, size = bench_rate(ros, Path(tmp), 1000.0, duration, compression=c)
            sizes[c] = size
            print(f"  {c:12s} published {pub:7d} at {achieved:8.0f} msg/s, recorded {got:7d}, drops {pub - got}, "
                  f"bag {size / 1e6:6.2f} MB ({size / sizes['none']:.3f} of none)")


if __name__ == "__main__":
    sys.exit(main())
