"""The process entry of the nodes: executor, spin loop, heap and logging warm-up, ``main()`` (:func:`run_node`)."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Sequence
from typing import Any

from vesselbot_ros.config import ConfigError
from vesselbot_ros.nodes.intra_process import intra_process

__all__ = ["make_executor", "freeze_heap", "warm_logging", "spin_nodes", "run_node"]


def _rclpy() -> Any:
    import rclpy

    return rclpy


def make_executor(context: Any = None) -> Any:
    """The executor used by every node process: rclpy's EventsExecutor."""
    from rclpy.experimental import EventsExecutor

    return EventsExecutor(context=context)


def freeze_heap() -> None:
    """Move every object built so far (modules, numba's and scipy's tables, the node) out of the collector's sight.

    A node process holds about 160,000 objects after its start, and a full
    collection, which the allocations of a long run trigger now and then,
    walks all of them (tens of ms at once: a late tick in real time).  They
    live as long as the process, so the collector need not look at them again.
    """
    import gc

    gc.freeze()


def warm_logging() -> None:
    """Pay the first log call's cost now, before the run, not in a real-time node's period.

    rclpy's logger finds its caller's module with :func:`inspect.getframeinfo`,
    which the first time resolves the file of every module loaded (``realpath``
    of each): 20-60 ms in a node process, measured as a 40-60 ms stall when the
    observer first warned of a lost measurement in the middle of a real-time run
    (every node then missed some 50 periods at once).  Later calls take about
    0.2 ms.  Builds a caller id as a log call does, without logging anything.
    """
    with contextlib.suppress(Exception):
        from rclpy.impl.rcutils_logger import CallerId

        CallerId()


def spin_nodes(nodes: Sequence[Any], context: Any = None, stop: Callable[[], bool] | None = None) -> None:
    """Spin ``nodes`` on one EventsExecutor until shutdown (or ``stop()``).

    The EventsExecutor's own ``spin()`` ignores SIGINT/SIGTERM, so we spin in
    short slices and let rclpy's signal handlers raise between them.
    """
    from rclpy.task import Future

    rclpy = _rclpy()
    ex = make_executor(context)
    for n in nodes:
        ex.add_node(n)
    bus = intra_process()
    if bus is not None:
        bus.attach(ex)
    never = Future()
    try:
        while rclpy.ok(context=context) and not (stop is not None and stop()):
            ex.spin_until_future_complete(never, timeout_sec=0.1)  # every event of a 0.1 s slice
    finally:
        for n in nodes:
            ex.remove_node(n)
        ex.shutdown()


def run_node(node_cls: Callable[..., Any], argv: Sequence[str] | None = None, *, exit_process: bool = False) -> int:
    """``main()`` of a node process: init, build, spin, clean up.

    Args:
        node_cls: The node class.
        argv: Command line (``sys.argv`` if None).
        exit_process: End the process right after the node's clean-up, with
            the code this would return (``python -m`` and the console
            scripts), instead of returning.  A runtime error still raises.

    Returns:
        0 on a clean stop (SIGINT, SIGTERM or end of run), 2 on an invalid
        parameter (one line on stderr naming it), 1 on a runtime error.
    """
    rclpy = _rclpy()
    from rclpy.executors import ExternalShutdownException

    args = list(sys.argv if argv is None else argv)
    role_name = getattr(node_cls, "ROLE", "node")
    exe = f"vesselbot_{role_name}"
    node = None
    code = 0
    rclpy.init(args=args)
    try:
        try:
            node = node_cls()
        except ConfigError as exc:
            print(f"{exe}: invalid parameter: {exc}", file=sys.stderr, flush=True)
            code = 2
            return code
        warm_logging()
        freeze_heap()
        spin_nodes([node], stop=lambda: node.done)
        return code
    except (KeyboardInterrupt, ExternalShutdownException):
        return code
    finally:
        if node is not None:
            try:
                node.destroy_node()
            except Exception:  # noqa: BLE001 - best effort during shutdown
                pass
        rclpy.try_shutdown()
        if exit_process and sys.exc_info()[0] in (None, KeyboardInterrupt, ExternalShutdownException):
            # Everything of the node is shut down and nothing is left to write: end the process here.  The
            # interpreter's own teardown (numba's and LLVM's objects, the DDS libraries' static destructors)
            # took 0.6 s per node, and 2 s for a graph's six nodes stopping together on two cores.
            # A signal shut the context down without closing rcl's log file (its last lines are written at the
            # interpreter's teardown, which this skips): close it here, as rclpy's own shutdown would have.
            ctx = rclpy.get_default_context()
            if getattr(ctx, "_logging_initialized", False):
                with contextlib.suppress(Exception), ctx._lock:
                    ctx._logging_fini()
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)

