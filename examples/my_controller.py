"""A user's own controller for the vesselbot graph (run with ``vesselbot run --without controller``).

It follows the topic contract of the controller slot (``vesselbot run --without controller``
prints it; names, types and QoS come from :mod:`vesselbot_ros.graph_spec`):

* subscribe ``/vesselbot/estimate`` (nav_msgs/Odometry: x_hat in pose.position,
  z_hat in twist.linear, frame ``vessel``) and ``/vesselbot/reference``
  (vesselbot_msgs/ReferenceSample);
* publish ``/vesselbot/gradient_command`` (geometry_msgs/Vector3Stamped, T/m)
  stamped with the tick time t_k of the estimate it answers.

The law here is a plain PD on the position error, mapped to a gradient with a
fixed gain: deliberately simple, to show the plumbing.  The coil driver clamps
whatever we send (saturation, slew), so a bad gain cannot hurt the coils.

    python examples/my_controller.py --ros-args -p use_sim_time:=true
"""

from __future__ import annotations

import sys

import rclpy
from geometry_msgs.msg import Vector3Stamped
from nav_msgs.msg import Odometry
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from vesselbot_msgs.msg import ReferenceSample

from vesselbot_ros.graph_spec import DEFAULT_NAMESPACE, qos_profile, topic


class MyController(Node):
    """PD position controller: gradient = kp * (p_ref - x_hat) + kd * (v_ref - z_hat)."""

    def __init__(self) -> None:
        # in the graph's namespace, so the relative names below resolve like ours (and --namespace remaps them)
        super().__init__("my_controller", namespace=DEFAULT_NAMESPACE)
        self.kp = self.declare_parameter("kp_T_per_m2", 20.0).value  # T/m per m of error
        self.kd = self.declare_parameter("kd_T_s_per_m2", 0.5).value  # T/m per m/s of error
        self.refs: dict[tuple[int, int], ReferenceSample] = {}
        self.estimates: dict[tuple[int, int], Odometry] = {}
        cmd, est, ref = topic("gradient_command"), topic("estimate"), topic("reference")
        # the subscriptions first, the publisher last: the run starts once it sees a node publish in its slot, and
        # an input of tick 0 sent before its subscription matched would be lost (lockstep waits for its answer)
        self.create_subscription(Odometry, est.rel, self.on_estimate, qos_profile(est))
        self.create_subscription(ReferenceSample, ref.rel, self.on_reference, qos_profile(ref))
        self.pub = self.create_publisher(Vector3Stamped, cmd.rel, qos_profile(cmd))

    @staticmethod
    def key(stamp) -> tuple[int, int]:
        return (stamp.sec, stamp.nanosec)

    def on_reference(self, msg: ReferenceSample) -> None:
        self.refs[self.key(msg.header.stamp)] = msg
        self.try_answer(self.key(msg.header.stamp))

    def on_estimate(self, msg: Odometry) -> None:
        self.estimates[self.key(msg.header.stamp)] = msg
        self.try_answer(self.key(msg.header.stamp))

    def try_answer(self, k: tuple[int, int]) -> None:
        # lockstep: answer tick k once both its estimate and its reference are in
        if k not in self.refs or k not in self.estimates:
            return
        ref, est = self.refs.pop(k), self.estimates.pop(k)
        p, v = est.pose.pose.position, est.twist.twist.linear
        cmd = Vector3Stamped()
        cmd.header.stamp = est.header.stamp  # t_k: the tick we answer
        cmd.header.frame_id = "vessel"
        cmd.vector.x = self.kp * (ref.position.x - p.x) + self.kd * (ref.velocity.x - v.x)
        cmd.vector.z = self.kp * (ref.position.z - p.z) + self.kd * (ref.velocity.z - v.z)
        self.pub.publish(cmd)


def main() -> int:
    rclpy.init(args=sys.argv)
    node = MyController()
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
