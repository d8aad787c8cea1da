"""Publishes std_msgs/String ``argv[1]`` on /vesselbot/isolation at 50 Hz until stopped."""

import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from std_msgs.msg import String


def main() -> int:
    rclpy.init()
    node = rclpy.create_node(f"talker_{sys.argv[1]}")
    pub = node.create_publisher(String, "/vesselbot/isolation", 10)
    node.create_timer(0.02, lambda: pub.publish(String(data=sys.argv[1])))
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
