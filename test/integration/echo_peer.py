"""A second process for the interface round-trip test.

Republishes every vesselbot_msgs message it receives on /echo_in/<Name> to
/echo_out/<Name>, and serves both services with responses derived from the
request, so that the test can compare deserialized content both ways.
"""

import sys

import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from vesselbot_msgs import msg as vm
from vesselbot_msgs import srv as vs

from vesselbot_ros.testing import spin_node

MESSAGES = ["PlantState", "ForceBreakdown", "ReferenceSample", "CoilState"]


def main() -> int:
    rclpy.init()
    node = rclpy.create_node("echo_peer")
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
    pubs = {}
    for name in MESSAGES:
        cls = getattr(vm, name)
        pubs[name] = node.create_publisher(cls, f"/echo_out/{name}", qos)
        node.create_subscription(cls, f"/echo_in/{name}", lambda m, n=name: pubs[n].publish(m), qos)

    def inject(req, resp):
        resp.accepted = req.kind in (req.OUTLIER_BURST, req.DROPOUT)
        resp.message = f"kind={req.kind} duration={req.duration!r} magnitude={req.magnitude!r}"
        resp.effective_start_time = req.start_time + 1.0
        return resp

    def run_control(req, resp):
        resp.success = req.command == req.STATUS
        resp.message = f"command={req.command}"
        resp.sim_time = 1.5
        resp.tick = 1500
        resp.finished = True
        return resp

    node.create_service(vs.InjectFault, "/echo/inject_fault", inject)
    node.create_service(vs.RunControl, "/echo/run_control", run_control)
    print("echo_peer ready", flush=True)
    return spin_node(node)


if __name__ == "__main__":
    sys.exit(main())
