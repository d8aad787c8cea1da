"""A peer that, in a real-time run, sends one far-future gradient command and one garbage /clock.

Once the plant's /clock passes ``--at`` seconds of sim time, and both of its writers have matched every
reader of their topic that it sees in the graph (a volatile sample published before its writer matched a
reader never reaches that reader: under load the writer's side of discovery can lag the reader's), it
publishes a gradient command stamped 1e6 s and a /clock of 1e9 s (once each), prints
``injected <sim time>`` and keeps spinning.

usage: python realtime_hostile_peer.py --at 0.2
"""

from __future__ import annotations

import argparse
import sys

import rclpy
from geometry_msgs.msg import Vector3Stamped
from rosgraph_msgs.msg import Clock

from vesselbot_ros.graph_spec import FRAME_ID, loop_roles, qos_profile, topic
from vesselbot_ros.nodes.conversions import ns_of_stamp, stamp_of_ns
from vesselbot_ros.testing import spin_node


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--at", type=float, default=0.2)
    a = ap.parse_args()
    rclpy.init()
    node = rclpy.create_node("realtime_hostile_peer")
    cmd, clk = topic("gradient_command"), topic("clock")
    cmd_pub = node.create_publisher(Vector3Stamped, cmd.name, qos_profile(cmd))
    clock_pub = node.create_publisher(Clock, clk.name, qos_profile(clk))
    done = [False]
    # real time: every loop node but the plant reads /clock, and the recorder and this peer; the driver and the
    # recorder read gradient commands
    least = {clock_pub: len(loop_roles(False)) + 1, cmd_pub: 2}  # a graph of positions: no tracker

    def matched() -> bool:
        return all(p.get_subscription_count() >= max(n, node.count_subscribers(p.topic_name)) for p, n in least.items())

    def on_clock(msg: Clock) -> None:
        t = ns_of_stamp(msg.clock) * 1e-9
        if done[0] or t < a.at or t > 1e5 or not matched():
            return
        done[0] = True
        bad = Vector3Stamped()
        bad.header.stamp = stamp_of_ns(int(1e6 * 1e9))
        bad.header.frame_id = FRAME_ID
        bad.vector.x = 0.05
        cmd_pub.publish(bad)
        clock_pub.publish(Clock(clock=stamp_of_ns(int(1e9 * 1e9))))
        print(f"injected {t}", flush=True)

    node.create_subscription(Clock, clk.name, on_clock, qos_profile(clk))
    return spin_node(node)


if __name__ == "__main__":
    sys.exit(main())
