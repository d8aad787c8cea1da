"""Recorder throughput: the graph's message mix at increasing tick rates, counting drops.

For each control rate (ticks/s; 8 messages per tick, the lockstep graph's mix
of vesselbot_ros.bag.synthetic, plus /diagnostics every 100 ticks) a fresh
recorder process records DURATION_S of traffic published by this process
(raw, pre-serialized CDR, reliable QoS as in topics.py).  Drops = published -
recorded, over the 8 per-tick topics (the recorder adds its own /diagnostics) (from the recorder's flush service, then from the finalised bag's
metadata.yaml).  Prints one line per rate and the highest message rate
sustained with zero drops.  Target: 1 kHz control (about 8 k msg/s) without
drops.

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
from vesselbot_ros.nodes.recorder_node import FLUSH_SERVICE, recorder_command
from vesselbot_ros.testing import NodeProcess, isolated_ros, spin_until
from vesselbot_ros.graph_spec import TOPICS, qos_profile, topic

DIAGNOSTICS = topic("diagnostics").name


def bench_rate(ros, work: Path, rate_hz: float, duration_s: float) -> tuple[int, int, float]:
    """Return (published, recorded, achieved publish rate in msg/s)."""
    out = Path(tempfile.mkdtemp(dir=work)) / f"bag_{int(rate_hz)}"
    rec = NodeProcess(recorder_command(out, {"scenario": "bench", "rate_hz": rate_hz}), ros.env,
                      work / f"rec_{int(rate_hz)}.log")
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
            fut = client.call_async(Trigger.Request())
            spin_until(ex, fut.done, 10)
            counts = json.loads(fut.result().message)
            recorded = sum(v for k, v in counts.items() if k in pubs and k != DIAGNOSTICS)
            if recorded >= published:
                break
            time.sleep(0.2)
        rec.stop(timeout=30)
        info = open_bag(out)
        in_bag = sum(t.count for t in info.topics if t.name in pubs and t.name != DIAGNOSTICS)
        return published, in_bag, published / elapsed
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
            pub, got, achieved = bench_rate(ros, Path(tmp), rate, duration)
            drops = pub - got
            print(f"  control {rate:6.0f} Hz: published {pub:7d} at {achieved:8.0f} msg/s, "
                  f"recorded {got:7d}, drops {drops}")
            if drops == 0:
                best = max(best, achieved)
    print(f"highest rate sustained with zero drops: {best:.0f} msg/s "
          f"({best / 8:.0f} Hz control; target 1000 Hz = 8000 msg/s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
