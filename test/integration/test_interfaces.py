"""Every custom message and service crosses a process boundary intact."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

rclpy = pytest.importorskip("rclpy")
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from vesselbot_msgs import msg as vm  # noqa: E402
from vesselbot_msgs import srv as vs  # noqa: E402

from vesselbot_ros.testing import NodeProcess, call_service, fill_message, spin_until  # noqa: E402

PEER = Path(__file__).with_name("echo_peer.py")
MESSAGES = ["PlantState", "ForceBreakdown", "ReferenceSample", "CoilState"]


def test_every_custom_message_and_service_round_trips_between_processes(ros, tmp_path):
    node = rclpy.create_node("interface_probe", context=ros.context)
    ex = SingleThreadedExecutor(context=ros.context)
    ex.add_node(node)
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
    received: dict[str, list] = {n: [] for n in MESSAGES}
    pubs = {}
    for name in MESSAGES:
        cls = getattr(vm, name)
        pubs[name] = node.create_publisher(cls, f"/echo_in/{name}", qos)
        node.create_subscription(cls, f"/echo_out/{name}", received[name].append, qos)
    inject = node.create_client(vs.InjectFault, "/echo/inject_fault")
    control = node.create_client(vs.RunControl, "/echo/run_control")

    with NodeProcess(["python", str(PEER)], ros.env, tmp_path / "peer.log") as peer:
        assert spin_until(ex, lambda: all(p.get_subscription_count() == 1 for p in pubs.values())
                          and inject.service_is_ready() and control.service_is_ready(), timeout=20), peer.output()
        sent = {}
        for i, name in enumerate(MESSAGES):
            msg = fill_message(getattr(vm, name)(), seed=100 * i)
            msg.header.frame_id = "vessel"
            sent[name] = msg
        # every field must differ from its default, or the comparison proves little
        assert sent["PlantState"].forces.steric.z != 0.0 and sent["CoilState"].slew_rate != 0.0
        # publish until each echo is back: this node can see the peer's echo publisher before that publisher has
        # matched this node's subscription (discovery is not symmetric), and an echo sent before then is lost
        # (VOLATILE: seen once in a clean-clone run on a loaded machine); the same message again changes nothing
        assert spin_until(ex, lambda: all(node.count_publishers(f"/echo_out/{n}") == 1 for n in MESSAGES), 20)
        resend = {"at": 0.0, "every": 0.25}

        def echoed() -> bool:
            missing = [n for n in MESSAGES if not received[n]]
            if missing and time.monotonic() >= resend["at"]:
                for name in missing:
                    pubs[name].publish(sent[name])
                resend["at"] = time.monotonic() + resend["every"]
                resend["every"] = min(2.0 * resend["every"], 2.0)
            return not missing

        assert spin_until(ex, echoed, timeout=20), peer.output()
        for name in MESSAGES:
            assert received[name][0] == sent[name], name

        req = vs.InjectFault.Request(kind=vs.InjectFault.Request.DROPOUT, start_time=0.5, duration=0.25, magnitude=1e-3)
        resp = call_service(ex, inject, req, timeout=20)  # the peer echoes: sending it again changes nothing
        assert resp.accepted is True
        assert resp.effective_start_time == pytest.approx(1.5)
        assert resp.message == "kind=1 duration=0.25 magnitude=0.001"

        resp = call_service(ex, control, vs.RunControl.Request(command=vs.RunControl.Request.STATUS), timeout=20)
        assert (resp.success, resp.tick, resp.finished, resp.sim_time) == (True, 1500, True, 1.5)
        assert resp.message == "command=4"
    node.destroy_node()
