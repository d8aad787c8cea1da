"""Several graph nodes in one process, on one EventsExecutor (``vesselbot run --single-process``).

Usage::

    python -m vesselbot_ros.launch.composed --roles plant,imager,observer,controller,coil_driver,reference \\
        --ros-args --params-file params.yaml

Every node gets the same ROS arguments (so the same parameters) and its own
name.  The nodes hand each other's messages over in process
(:class:`vesselbot_ros.nodes.intra_process.IntraProcess`, as rclcpp's intra-process
communication does for composed nodes); DDS carries a message only to
readers outside the process (recorder, launcher, viewers, a user's node).
``--no-intra-process``: every message over DDS.
An invalid parameter exits with code 2 and one line naming it.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import sys
from collections.abc import Sequence
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException

from vesselbot_ros.config import ConfigError
from vesselbot_ros.graph_spec import LOOP_ROLES, role
from vesselbot_ros.nodes.intra_process import use_intra_process
from vesselbot_ros.nodes.process import freeze_heap, spin_nodes, warm_logging

__all__ = ["node_class", "main"]


def node_class(name: str) -> Any:
    """Import and return the node class of role ``name`` (from the graph spec)."""
    module, _, cls = role(name).node_class.partition(":")
    return getattr(importlib.import_module(module), cls)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point (see module docstring)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args: list[str] = []
    if "--ros-args" in argv:
        i = argv.index("--ros-args")
        argv, ros_args = argv[:i], argv[i:]
    parser = argparse.ArgumentParser(prog="vesselbot-composed")
    parser.add_argument("--roles", required=True, help="comma-separated node roles")
    parser.add_argument("--no-intra-process", dest="intra_process", action="store_false",
                        help="every message over DDS (default: lockstep deliveries between these nodes in process)")
    ns = parser.parse_args(argv)
    roles = [r for r in ns.roles.split(",") if r]
    for r in roles:
        if r not in LOOP_ROLES:
            print(f"vesselbot-composed: unknown role {r!r}; known: {', '.join(LOOP_ROLES)}", file=sys.stderr)
            return 2
    nodes: list[Any] = []
    rclpy.init(args=["vesselbot_composed", *ros_args])
    use_intra_process(roles if ns.intra_process else None)
    try:
        for r in roles:
            try:
                nodes.append(node_class(r)())
            except ConfigError as exc:
                print(f"vesselbot_{r}: invalid parameter: {exc}", file=sys.stderr, flush=True)
                return 2
        warm_logging()
        freeze_heap()
        spin_nodes(nodes)
        return 0
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:
        for n in nodes:
            with contextlib.suppress(Exception):  # best effort at shutdown
                n.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
