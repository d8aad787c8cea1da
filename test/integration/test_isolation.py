"""Two graphs started at the same time on different leased domains never see each other."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

rclpy = pytest.importorskip("rclpy")
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from vesselbot_ros.ros_env import allocate_domain, allocate_domain_for_peers, ros_environment  # noqa: E402
from vesselbot_ros.testing import NodeProcess, spin_until  # noqa: E402

TALKER = Path(__file__).with_name("talker_peer.py")


def test_leased_domains_are_exclusive():
    with allocate_domain() as a:
        with pytest.raises(RuntimeError, match=f"domain id {a.domain_id} is in use"):
            allocate_domain(a.domain_id)
        with allocate_domain() as b:
            assert b.domain_id != a.domain_id
    # released: can be taken again
    with allocate_domain(a.domain_id) as again:
        assert again.domain_id == a.domain_id


def test_a_domain_held_for_peers_admits_a_chosen_run_and_no_leased_one():
    with allocate_domain_for_peers() as peers:
        dom = peers.domain_id
        # no automatically leased run takes it, nor an exclusive request for it
        taken = [allocate_domain() for _ in range(20)]
        try:
            assert dom not in {t.domain_id for t in taken}
        finally:
            for t in taken:
                t.release()
        with pytest.raises(RuntimeError, match=f"domain id {dom} is in use"):
            allocate_domain(dom)
        # a run given --domain-id joins it (shared, in its namespace), twice in two namespaces
        with allocate_domain(dom, "/vesselbot") as run, allocate_domain(dom, "/robot2") as other:
            assert run.domain_id == other.domain_id == dom
        with allocate_domain_for_peers() as more:
            assert more.domain_id != dom
    with allocate_domain(dom) as again:
        assert again.domain_id == dom


def test_two_concurrent_graphs_on_different_domains_do_not_cross_talk(ros, tmp_path):
    with allocate_domain() as other:
        other_env = ros_environment(other.domain_id, tmp_path / "other_log")
        assert other_env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
        with NodeProcess(["python", str(TALKER), "mine"], ros.env, tmp_path / "mine.log") as mine, \
             NodeProcess(["python", str(TALKER), "theirs"], other_env, tmp_path / "theirs.log") as theirs:
            node = rclpy.create_node("isolation_probe", context=ros.context)
            ex = SingleThreadedExecutor(context=ros.context)
            ex.add_node(node)
            got: list[str] = []
            node.create_subscription(String, "/vesselbot/isolation", lambda m: got.append(m.data), 10)
            assert spin_until(ex, lambda: got.count("mine") >= 10, timeout=20), mine.output()
            # keep listening a while: the other domain's talker is running all along
            end = time.monotonic() + 1.0
            spin_until(ex, lambda: time.monotonic() > end, timeout=2)
            assert theirs.alive(), theirs.output()
            assert set(got) == {"mine"}
            names = {n for n, _ns in node.get_node_names_and_namespaces()}
            assert "talker_mine" in names and "talker_theirs" not in names
            node.destroy_node()
