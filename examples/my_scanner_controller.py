"""A user's controller that knows the MRI scanner's sequence (run with ``vesselbot run --without controller``).

It follows the controller slot's contract (``vesselbot run --without controller`` prints it; names,
types and QoS come from :mod:`vesselbot_ros.graph_spec`), and uses the optional sequence-phase port:

* subscribe ``estimate`` (nav_msgs/Odometry) and ``reference`` (vesselbot_msgs/ReferenceSample);
* subscribe ``scanner/phase`` (vesselbot_msgs/SequencePhase, latched): the coil driver publishes the
  phase window ``[window_start, window_end)`` of tick k+1 before it answers tick k, so the latest
  message holds the phase of every tick up to its ``window_end``;
* publish ``gradient_command`` (geometry_msgs/Vector3Stamped, T/m) stamped t_k, one per tick.

The law is a PD on the position error (as ``examples/my_controller.py``) that uses the phase:

* in a PROPULSION window it commands the PD gradient divided by the sequence's duty cycle, so the
  gradient averaged over a sequence period is the PD's (the coil is off the rest of the time);
* in TRACKING and DEAD windows it commands exactly zero (the coil would not apply anything there,
  and a zero command keeps the slew budget for the next propulsion window);
* CONTINUOUS (the paper's loop): the plain PD.

A tick whose phase window has not arrived yet waits for it (lockstep answers must not guess).

The estimate it reads already accounts for the imaging latency when the observer is the EKF
(``observer.kind: ekf``: frames fused at their acquisition stamp, then re-predicted); with the
paper's observer (25) the estimate lags by the latency.

    python examples/my_scanner_controller.py --ros-args -p use_sim_time:=true
"""

from __future__ import annotations

import sys

import rclpy
from geometry_msgs.msg import Vector3Stamped
from nav_msgs.msg import Odometry
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from vesselbot_msgs.msg import ReferenceSample, SequencePhase

from vesselbot_ros.graph_spec import DEFAULT_NAMESPACE, FRAME_ID, qos_profile, topic


def stamp_s(stamp) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


class MyScannerController(Node):
    """PD position controller gated and scaled by the scanner's sequence phase."""

    def __init__(self) -> None:
        super().__init__("my_scanner_controller", namespace=DEFAULT_NAMESPACE)
        self.kp = self.declare_parameter("kp_T_per_m2", 20.0).value  # T/m per m of error
        self.kd = self.declare_parameter("kd_T_s_per_m2", 0.5).value  # T/m per m/s of error
        self.refs: dict[tuple[int, int], ReferenceSample] = {}
        self.estimates: dict[tuple[int, int], Odometry] = {}
        self.windows: list[SequencePhase] = []  # phase windows received, oldest first (a few kept)
        cmd, est, ref, phase = topic("gradient_command"), topic("estimate"), topic("reference"), topic("sequence_phase")
        # the subscriptions first, the publisher last (examples/my_controller.py says why)
        self.create_subscription(Odometry, est.rel, self.on_estimate, qos_profile(est))
        self.create_subscription(ReferenceSample, ref.rel, self.on_reference, qos_profile(ref))
        self.create_subscription(SequencePhase, phase.rel, self.on_phase, qos_profile(phase))
        self.pub = self.create_publisher(Vector3Stamped, cmd.rel, qos_profile(cmd))

    @staticmethod
    def key(stamp) -> tuple[int, int]:
        return (stamp.sec, stamp.nanosec)

    def on_phase(self, msg: SequencePhase) -> None:
        self.windows = [*self.windows[-7:], msg]
        for k in sorted(self.estimates):  # ticks that waited for this window
            self.try_answer(k)

    def phase_at(self, t_s: float) -> SequencePhase | None:
        """The received window holding ``t_s`` (newest first), or None."""
        for w in reversed(self.windows):
            if w.window_start - 1e-9 <= t_s < w.window_end - 1e-9:
                return w
        return None

    def on_reference(self, msg: ReferenceSample) -> None:
        self.refs[self.key(msg.header.stamp)] = msg
        self.try_answer(self.key(msg.header.stamp))

    def on_estimate(self, msg: Odometry) -> None:
        self.estimates[self.key(msg.header.stamp)] = msg
        self.try_answer(self.key(msg.header.stamp))

    def try_answer(self, k: tuple[int, int]) -> None:
        # lockstep: answer tick k once both its estimate and its reference are in
        # and the phase window holding t_k (published before the coil answered tick k-1; wait if it is late)
        if k not in self.refs or k not in self.estimates:
            return
        w = self.phase_at(stamp_s(self.estimates[k].header.stamp))
        if w is None:
            return
        ref, est = self.refs.pop(k), self.estimates.pop(k)
        p, v = est.pose.pose.position, est.twist.twist.linear
        gain = 1.0  # CONTINUOUS: the plain PD
        if w.phase in (SequencePhase.TRACKING, SequencePhase.DEAD):
            gain = 0.0
        elif w.phase == SequencePhase.PROPULSION and w.duty_cycle > 0.0:
            gain = 1.0 / w.duty_cycle
        cmd = Vector3Stamped()
        cmd.header.stamp = est.header.stamp  # t_k: the tick we answer
        cmd.header.frame_id = FRAME_ID
        cmd.vector.x = gain * (self.kp * (ref.position.x - p.x) + self.kd * (ref.velocity.x - v.x))
        cmd.vector.z = gain * (self.kp * (ref.position.z - p.z) + self.kd * (ref.velocity.z - v.z))
        self.pub.publish(cmd)


def main() -> int:
    rclpy.init(args=sys.argv)
    node = MyScannerController()
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
