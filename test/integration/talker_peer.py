"""Publishes std_msgs/String ``argv[1]`` on /vesselbot/isolation at 50 Hz until stopped."""

import sys

import rclpy
from std_msgs.msg import String

from vesselbot_ros.testing import spin_node


def main() -> int:
    rclpy.init()
    node = rclpy.create_node(f"talker_{sys.argv[1]}")
    pub = node.create_publisher(String, "/vesselbot/isolation", 10)
    node.create_timer(0.02, lambda: pub.publish(String(data=sys.argv[1])))
    return spin_node(node)


if __name__ == "__main__":
    sys.exit(main())
