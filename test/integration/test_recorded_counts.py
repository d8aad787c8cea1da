"""Nothing recorded is lost: at the end of every recorded run the bag holds exactly what was published.

The 2000th command of a user's controller could miss the bag: the launcher waited for the recorder
to catch up with the counts our nodes report in their diagnostics, and a user's node reports none,
so the recorder could be stopped before the user's last message reached it.  Now the launcher counts
what a user's node publishes itself, waits for the recorder to have it, and compares every topic of
the finalised bag with the published counts (exit 1 naming topic and counts on any difference).
"""

from __future__ import annotations

import contextlib
import re
import signal
import subprocess
import sys
from collections.abc import Iterator

import pytest

pytest.importorskip("rclpy")

from _runs import REPO, hostile_env, run_cmd

EXTRA_PUBLISHER = """
import sys, time, rclpy
from vesselbot_msgs.msg import CoilState
from vesselbot_ros.graph_spec import qos_profile, topic
rclpy.init()
node = rclpy.create_node("foreign_publisher")
spec = topic("coil_state")
pub = node.create_publisher(CoilState, spec.name, qos_profile(spec))
print("ready", flush=True)
try:
    while rclpy.ok():
        if pub.get_subscription_count() > 0:
            pub.publish(CoilState(tick=10**6))  # out of every run's range: only the bag sees it
        time.sleep(0.05)
except KeyboardInterrupt:
    pass
"""


# a controller whose subscriptions the graph learns of after its publisher (DDS announces them on separate
# built-in writers, so any node can look like this for a moment; here it is 0.3 s, once the rest of the graph is
# up, so that the launcher waits for this node alone): it answers every tick
LATE_SUBSCRIBER = """
import sys, time, rclpy
from geometry_msgs.msg import Vector3Stamped
from nav_msgs.msg import Odometry
from vesselbot_ros.graph_spec import DEFAULT_NAMESPACE, qos_profile, topic
rclpy.init(args=sys.argv)
node = rclpy.create_node("late_subscriber", namespace=DEFAULT_NAMESPACE)
cmd, est = topic("gradient_command"), topic("estimate")
while node.count_publishers(est.rel) == 0:  # the graph is up: the launcher waits for this slot's node alone
    time.sleep(0.05)
time.sleep(1.0)
pub = node.create_publisher(Vector3Stamped, cmd.rel, qos_profile(cmd))
time.sleep(0.3)
def answer(msg):
    out = Vector3Stamped()
    out.header.stamp = msg.header.stamp
    out.header.frame_id = "vessel"
    pub.publish(out)
node.create_subscription(Odometry, est.rel, answer, qos_profile(est))
try:
    rclpy.spin(node)
except BaseException:
    pass
"""


@contextlib.contextmanager
def _peers_domain() -> Iterator[int]:
    """A domain id for the test's own nodes and the run that joins them, held until the block ends (a lease
    released before the run would let another test's run take the id first)."""
    from vesselbot_ros.ros_env import allocate_domain_for_peers

    with allocate_domain_for_peers() as lease:
        yield lease.domain_id


def _run_with_users_controller(tmp_path, user_args: list[str], duration: str, bag) -> None:
    """``vesselbot run --without controller`` recorded to ``bag``, the controller slot taken by ``python
    user_args`` (started first, stopped after the run); the run must succeed."""
    with _peers_domain() as dom:
        env = hostile_env(dom, tmp_path / "ros_log")
        user = subprocess.Popen([sys.executable, *user_args, "--ros-args", "-p", "use_sim_time:=true"], env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            p = subprocess.run(run_cmd("--duration", duration, "--without", "controller", "--domain-id", str(dom),
                                       "--record-dir", str(bag), "--quiet"),
                               cwd=REPO, capture_output=True, text=True, timeout=240)
        finally:
            user.send_signal(signal.SIGINT)
            try:
                user.wait(timeout=20)
            except subprocess.TimeoutExpired:  # the user's own node, not the launcher's: stop it, say so, judge the bag
                user.kill()
                out, _ = user.communicate(timeout=20)
                print(f"the user's node did not exit 20 s after SIGINT; killed. Its output:\n{out[-3000:]}")
    assert p.returncode == 0, p.stdout + p.stderr


@pytest.mark.timeout(300)
def test_users_controller_every_command_is_in_the_bag(tmp_path):
    from vesselbot_ros.bag.reader import final_diagnostics, open_bag

    bag = tmp_path / "bag"
    _run_with_users_controller(tmp_path, [str(REPO / "examples" / "my_controller.py")], "0.3", bag)
    info = open_bag(bag)
    assert info.consistent, info.problems
    n = 300
    # one command per tick from the user's node, every one of them in the bag
    assert info.topic("/vesselbot/gradient_command").count == n
    final = final_diagnostics(info)
    for node, d in final.items():
        for key, value in d.items():
            if key.startswith("published:") and not key.endswith("/diagnostics"):
                name = key.split(":", 1)[1]
                assert info.topic(name).count == int(value), (node, name, value)


@pytest.mark.timeout(300)
def test_a_slots_node_whose_subscription_the_graph_learns_of_late_still_gets_tick_0(tmp_path):
    """The run starts once what the graph shows of the slot's node (its publishers, then its subscriptions) has
    stayed the same for a moment, and our publishers matched its subscriptions: tick 0's estimate is not sent
    before the user's subscription exists (it was lost, and the coil's watchdog answered tick 0 after 2 s)."""
    from vesselbot_ros.bag.reader import open_bag

    bag = tmp_path / "bag"
    _run_with_users_controller(tmp_path, ["-c", LATE_SUBSCRIBER], "0.1", bag)
    info = open_bag(bag)
    assert info.topic("/vesselbot/gradient_command").count == 100


@pytest.mark.timeout(300)
def test_a_message_the_publishers_did_not_count_fails_the_run_naming_topic_and_counts(tmp_path):
    with _peers_domain() as dom:
        env = hostile_env(dom, tmp_path / "ros_log")
        foreign = subprocess.Popen([sys.executable, "-c", EXTRA_PUBLISHER], env=env, stdout=subprocess.PIPE,
                                   stderr=subprocess.STDOUT, text=True)
        try:
            assert foreign.stdout.readline().strip() == "ready"
            p = subprocess.run(run_cmd("--duration", "0.3", "--domain-id", str(dom), "--record-dir",
                                       str(tmp_path / "bag"), "--quiet"), cwd=REPO, capture_output=True, text=True,
                               timeout=240)
        finally:
            foreign.send_signal(signal.SIGINT)
            foreign.wait(timeout=20)
    assert p.returncode == 1, p.stdout + p.stderr
    line = [ln for ln in p.stderr.splitlines() if "does not hold what was published" in ln]
    assert line, p.stderr
    m = re.search(r"/vesselbot/coil/state: published 300, recorded (\d+)", line[0])
    assert m and int(m.group(1)) > 300, line[0]  # 300 + the foreign ones
