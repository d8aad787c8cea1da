"""Synthetic graph publisher: the graph's topics and message mix, counted (no node graph needed).

Usage: graph_publisher_peer.py COUNTS_JSON TICKS RATE_HZ
  Waits until every topic has a subscriber (the recorder), publishes the two
  latched topics once and TICKS ticks of vesselbot_ros.bag.synthetic at
  RATE_HZ (TICKS = 0: until SIGINT), then writes {"published:<topic>": n}
  into COUNTS_JSON and keeps spinning until SIGINT/SIGTERM.
"""

import json
import os
import sys
import time

import rclpy
from rclpy.executors import ExternalShutdownException

from vesselbot_ros.bag.synthetic import latched_messages, tick_messages
from vesselbot_ros.graph_spec import TOPICS, qos_profile


def write_counts(path: str, counts: dict[str, int]) -> None:
    """Write the published counts atomically (a reader never sees a half-written file)."""
    tmp = f"{path}.tmp"
    with open(tmp, "w") as fh:
        json.dump({f"published:{n}": c for n, c in counts.items()}, fh)
    os.replace(tmp, path)


def main() -> int:
    counts_path, ticks, rate = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    rclpy.init()
    node = rclpy.create_node("synthetic_graph")
    specs = {s.name: s for s in TOPICS}
    pubs = {}
    for name, msg in latched_messages() + tick_messages(0):
        pubs[name] = node.create_publisher(type(msg), name, qos_profile(specs[name]))
    counts = dict.fromkeys(pubs, 0)
    try:
        deadline = time.monotonic() + 30
        while not all(p.get_subscription_count() > 0 for p in pubs.values()):
            if time.monotonic() > deadline:
                print("no subscriber", flush=True)
                return 1
            rclpy.spin_once(node, timeout_sec=0.02)
        for name, msg in latched_messages():
            pubs[name].publish(msg)
            counts[name] += 1
        t0 = time.monotonic()
        k = 0
        while ticks == 0 or k < ticks:
            due = t0 + k / rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            for name, msg in tick_messages(k):
                pubs[name].publish(msg)
                counts[name] += 1
            k += 1
            if ticks == 0 and k % 50 == 0:
                write_counts(counts_path, counts)
        write_counts(counts_path, counts)
        print("done", flush=True)
        while rclpy.ok():
            rclpy.spin_once(node, timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        write_counts(counts_path, counts)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
