"""``vesselbot replay DIR [--rate R] [--topics ...] [--start S] [--loop] [--clock]``.

Publishes in the ROS domain of the environment (``ROS_DOMAIN_ID``), with
localhost-only discovery unless ``ROS_AUTOMATIC_DISCOVERY_RANGE`` is set.
"""

from __future__ import annotations

import argparse
import os
import sys

__all__ = ["register", "run"]


def register(parser: argparse.ArgumentParser) -> None:
    """Add the replay arguments."""
    parser.add_argument("bag", help="bag directory")
    parser.add_argument("--rate", type=float, default=1.0, help="speed factor (2 = twice as fast); default 1")
    parser.add_argument("--topics", nargs="+", metavar="TOPIC", help="replay only these topics")
    parser.add_argument("--start", type=float, default=0.0, metavar="S", help="skip the first S seconds of the bag")
    parser.add_argument("--loop", action="store_true", help="replay again and again until Ctrl-C")
    parser.add_argument("--clock", action="store_true",
                        help="publish /clock from the bag's log time (and do not replay a recorded /clock)")
    parser.add_argument("--wait-subscribers", type=float, default=0.0, metavar="S",
                        help="first wait up to S seconds until every replayed topic has a subscriber")


def run(args: argparse.Namespace) -> int:
    """Replay the bag; exit 0 when done (Ctrl-C stops it cleanly)."""
    from vesselbot_ros.bag.reader import open_bag

    info = open_bag(args.bag)  # fail on a broken bag before starting ROS
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    import rclpy
    from rclpy.executors import ExternalShutdownException

    from vesselbot_ros.bag.replay import replay

    rclpy.init()
    node = rclpy.create_node("vesselbot_player")
    try:
        stats = replay(info, node, rate=args.rate, topics=args.topics, start_s=args.start, loop=args.loop,
                       clock=args.clock, wait_subscribers_s=args.wait_subscribers,
                       should_stop=lambda: not rclpy.ok(),
                       log=lambda s: print(f"vesselbot replay: {s}", file=sys.stderr, flush=True))
    except (KeyboardInterrupt, ExternalShutdownException):
        print("vesselbot replay: stopped", file=sys.stderr)
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    print(f"vesselbot replay: published {sum(stats.published.values())} messages in {stats.wall_s:.2f} s "
          f"({stats.loops} pass(es)); max lateness {stats.max_lateness_s * 1e3:.1f} ms", flush=True)
    return 0
