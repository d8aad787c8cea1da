"""A user's own tracker node for the vesselbot graph (run with ``vesselbot run --without tracker``).

With ``imager.kind: mr_images`` the imager publishes MR frames and a tracker turns each into the measurement.
This node takes the tracker's slot; it follows the slot's contract (``vesselbot run --without tracker`` prints
it; names, types and QoS come from :mod:`vesselbot_ros.graph_spec`):

* subscribe ``/vesselbot/imager/frame`` (sensor_msgs/Image, encoding 64FC2: the frame's complex samples; stamp =
  acquisition time; lockstep: one message per tick, an empty image when no frame is delivered);
* publish ``/vesselbot/measurement`` (geometry_msgs/PointStamped, m, frame ``vessel``), one per frame message in
  lockstep: the frame's position stamped with its acquisition time, or the last one again (before the first: an
  empty ``frame_id`` and stamp 0, "no frame yet").

The frames' geometry (field of view, pixel, noise level) is the scenario's imager section: the node reads the
same scenario as the run (parameters ``config`` and ``set``, as ``vesselbot run --config ... --set ...``).  Inside,
it calls any tracker kind by name (``tracker_kind``: the default ``dipole_fit``, or ``module:Class`` of your own):
replace :meth:`MyTracker.position` with your pipeline.  With the default kind its numbers are the graph's own
tracker's, bit for bit.

    python examples/my_tracker_node.py --ros-args -p config:=config/plans/clinical_3t.yaml \\
        -p "set:=['imager.kind=mr_images', 'imager.fov_centre_m=[4.0e-3, 0.0, 0.0]']"
"""

from __future__ import annotations

import sys
from typing import Any

import rclpy
from geometry_msgs.msg import PointStamped
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from sensor_msgs.msg import Image

from vesselbot_ros.graph_spec import DEFAULT_NAMESPACE, qos_profile, topic
from vesselbot_ros.imaging.frames import frame_of
from vesselbot_ros.nodes import conversions as cv
from vesselbot_ros.sim.closed_loop import build_stage
from vesselbot_ros.sim.scenario import load_scenario, scenario_with


class MyTracker(Node):
    """Answers every ``imager/frame`` message with a measurement (lockstep)."""

    def __init__(self) -> None:
        super().__init__("my_tracker", namespace=DEFAULT_NAMESPACE)
        config = self.declare_parameter("config", "").value
        sets = [s for s in self.declare_parameter("set", [""]).value if s]
        kind = self.declare_parameter("tracker_kind", "dipole_fit").value
        self.scenario = scenario_with(load_scenario(config or "sound_small_artery", sets=sets), {"tracker.kind": kind})
        self.tracker = build_stage(self.scenario, "tracker")  # any tracker kind, by name
        self.frames = 0
        self.last: PointStamped | None = None
        out, frames = topic("measurement"), topic("mr_frame")
        # the subscription first, the publisher last (examples/my_controller.py says why)
        self.create_subscription(Image, frames.rel, self.on_frame, qos_profile(frames))
        self.pub = self.create_publisher(PointStamped, out.rel, qos_profile(out))

    def position(self, msg: Any) -> PointStamped | None:
        """The frame's measurement, or None (no frame, or rejected by the tracker)."""
        samples = cv.frame_samples(msg)
        if samples is None:
            return None
        t_acq = cv.ns_of_stamp(msg.header.stamp) * 1e-9
        meas = self.tracker.track(t_acq, frame_of(self.scenario.imager, samples, t_acq, self.frames))
        self.frames += 1
        return None if meas is None else cv.measurement_msg(meas.t_acq_s, meas.p, self.scenario.dims)

    def on_frame(self, msg: Any) -> None:
        meas = self.position(msg)
        if meas is not None:
            self.last = meas
        self.pub.publish(self.last if self.last is not None else PointStamped())  # "no frame yet": stamp 0


def main() -> int:
    rclpy.init(args=sys.argv)
    node = MyTracker()
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
