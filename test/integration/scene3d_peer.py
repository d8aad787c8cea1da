"""A 3-D vessel tree's scene on the graph's topics: what the plant, reference, observer and coil publish, with y.

Usage: scene3d_peer.py NETWORK RATE_HZ
  Waits until every topic it publishes has a subscriber (the recorder), then publishes the
  plant's latched vessel markers of NETWORK (the wall mesh and 3-D centrelines, built by the
  plant's own function) and a reference path along the centreline from the inlet to the first
  outlet (x, y, z), prints "latched", and then ticks at RATE_HZ until SIGINT/SIGTERM: /clock,
  truth, reference, estimate and coil state, the robot on that route where it leaves the plane
  y = 0 (|y| > 0.5 mm), each tick the next point.  Stands in for the 3-D closed loop
  until ``vesselbot run`` of a 3-D scenario exists.
"""

import sys
import time

import numpy as np
import rclpy
from geometry_msgs.msg import Vector3
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rclpy.executors import ExternalShutdownException
from rosgraph_msgs.msg import Clock
from vesselbot_msgs.msg import CoilState, PlantState, ReferenceSample
from visualization_msgs.msg import MarkerArray

from vesselbot_ros.graph_spec import CHILD_FRAME_ID, qos_profile, topic
from vesselbot_ros.nodes import conversions as cv
from vesselbot_ros.nodes.plant_node import network_scene_markers
from vesselbot_ros.physics.params import BloodParams
from vesselbot_ros.vessels.network import load_network, route_to_outlet
from vesselbot_ros.vessels.tube_geometry import NetworkGeometry

ROBOT_RADIUS_M = 250e-6
DT_S = 1e-3
#: The applied gradient (T/m), its limit, and the estimate's and reference's offsets from the robot (m).
GRADIENT = (0.03, -0.04, 0.02)
LIMIT = 0.08
EST_OFFSET = (5e-6, -3e-6, 2e-6)
REF_OFFSET = (1e-5, 2e-5, -1e-5)


def _set(v: Vector3, xyz) -> None:
    v.x, v.y, v.z = (float(c) for c in xyz)


def main() -> int:
    network, rate = sys.argv[1], float(sys.argv[2])
    net = load_network(network)
    markers = network_scene_markers(net, BloodParams(), ROBOT_RADIUS_M)
    geom = NetworkGeometry(net, dims=3)
    route = geom.centreline_path(route_to_outlet(net, net.outlets[0]))
    path_pts = route[:: max(1, len(route) // 300)]
    radius = geom.query(route)["radius"]
    off_plane = np.flatnonzero(np.abs(route[:, 1]) > 0.5e-3)[::5]
    rclpy.init()
    node = rclpy.create_node("scene3d_peer")
    pubs = {k: node.create_publisher(cls, topic(k).name, qos_profile(topic(k)))
            for k, cls in (("vessel_markers", MarkerArray), ("reference_path", PathMsg), ("clock", Clock),
                           ("truth", PlantState), ("reference", ReferenceSample), ("estimate", Odometry),
                           ("coil_state", CoilState))}
    try:
        deadline = time.monotonic() + 30
        while not all(p.get_subscription_count() > 0 for p in pubs.values()):
            if time.monotonic() > deadline:
                print("no subscriber", flush=True)
                return 1
            rclpy.spin_once(node, timeout_sec=0.02)
        pubs["vessel_markers"].publish(markers)
        pubs["reference_path"].publish(cv.path_msg(path_pts))
        print("latched", flush=True)
        t0, k = time.monotonic(), 0
        while rclpy.ok():
            delay = t0 + k / rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            i = off_plane[k % len(off_plane)]
            p, r_lumen, t = route[i], float(radius[i]), k * DT_S
            stamp = cv.header(t)
            clock = Clock()
            clock.clock = stamp.stamp
            truth = PlantState(header=stamp, tick=k, vessel_diameter=2 * r_lumen,
                               wall_gap_upper=r_lumen - ROBOT_RADIUS_M, wall_gap_lower=r_lumen - ROBOT_RADIUS_M,
                               signed_wall_distance=ROBOT_RADIUS_M - r_lumen)
            _set(truth.position, p)
            _set(truth.applied_gradient, GRADIENT)
            truth.forces.header = stamp
            ref = ReferenceSample(header=stamp, tick=k)
            _set(ref.position, p + REF_OFFSET)
            est = Odometry(header=stamp, child_frame_id=CHILD_FRAME_ID)
            _set(est.pose.pose.position, p + EST_OFFSET)
            est.pose.pose.orientation.w = 1.0
            coil = CoilState(header=stamp, tick=k, max_gradient=LIMIT, saturation_scale=1.0)
            _set(coil.commanded, GRADIENT)
            _set(coil.applied, GRADIENT)
            for key, msg in (("clock", clock), ("truth", truth), ("reference", ref), ("estimate", est),
                             ("coil_state", coil)):  # the lockstep order: the coil state closes the tick
                pubs[key].publish(msg)
            k += 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
