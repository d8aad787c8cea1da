"""A hostile stand-in for the controller: answers every estimate with a bad command.

Used by the safety-invariant tests to show that the coil driver clamps whatever it
receives.  One command per estimate (so lockstep keeps ticking), cycling through:
random gradients up to 100x U_sat, huge values (1e6 T/m), sign-alternating full
scale steps, NaN, +Inf/-Inf, and a wrong frame_id.

usage: python hostile_controller.py [seed]
"""

from __future__ import annotations

import math
import sys

import numpy as np
import rclpy
from geometry_msgs.msg import Vector3Stamped
from nav_msgs.msg import Odometry

from vesselbot_ros.graph_spec import qos_profile, topic
from vesselbot_ros.testing import spin_node


def main() -> int:
    seed = int(sys.argv[1]) if len(sys.argv) > 1 else 0
    rng = np.random.default_rng(seed)
    rclpy.init()
    node = rclpy.create_node("vesselbot_controller")  # takes the controller's slot and name
    cmd_spec = topic("gradient_command")
    pub = node.create_publisher(Vector3Stamped, cmd_spec.name, qos_profile(cmd_spec))
    count = [0]

    def bad_value(k: int) -> tuple[float, float, str]:
        mode = k % 6
        if mode == 0:
            gx, gz = rng.uniform(-8.0, 8.0, size=2)  # up to 100x U_sat = 0.08 T/m
            return float(gx), float(gz), "vessel"
        if mode == 1:
            return 1e6, -1e6, "vessel"
        if mode == 2:
            s = 1.0 if (k // 6) % 2 == 0 else -1.0
            return 0.08 * s, -0.08 * s, "vessel"
        if mode == 3:
            return math.nan, 0.01, "vessel"
        if mode == 4:
            return math.inf, -math.inf, "vessel"
        return 0.05, 0.05, "not_the_vessel_frame"

    def on_estimate(est: Odometry) -> None:
        gx, gz, frame = bad_value(count[0])
        count[0] += 1
        msg = Vector3Stamped()
        msg.header.stamp = est.header.stamp
        msg.header.frame_id = frame
        msg.vector.x, msg.vector.z = gx, gz
        pub.publish(msg)

    est_spec = topic("estimate")
    node.create_subscription(Odometry, est_spec.name, on_estimate, qos_profile(est_spec))
    return spin_node(node)


if __name__ == "__main__":
    sys.exit(main())
