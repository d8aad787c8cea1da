"""The process entry of the nodes: executor, spin loop, heap and logging warm-up, ``main()`` (:func:`run_node`)."""

from __future__ import annotations

import contextlib
import gc
import os
import signal
import sys
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.impl.rcutils_logger import CallerId
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from vesselbot_ros.config import ConfigError
from vesselbot_ros.nodes.intra_process import intra_process

__all__ = ["make_executor", "freeze_heap", "warm_logging", "spin_nodes", "run_node"]


def make_executor(context: Any = None) -> Any:
    """The executor used by every node process: rclpy's EventsExecutor."""
    return EventsExecutor(context=context)


def freeze_heap() -> None:
    """Move every object built so far (modules, numba's and scipy's tables, the node) out of the collector's sight.

    A node process holds about 160,000 objects after its start, and a full
    collection, which the allocations of a long run trigger now and then,
    walks all of them (tens of ms at once: a late tick in real time).  They
    live as long as the process, so the collector need not look at them again.
    """
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
        CallerId()


def spin_nodes(nodes: Sequence[Any], context: Any = None, stop: Callable[[], bool] | None = None) -> None:
    """Spin ``nodes`` on one EventsExecutor until shutdown (or ``stop()``).

    The EventsExecutor's own ``spin()`` ignores SIGINT/SIGTERM, so we spin in
    short slices and let the process's signal handlers (rclpy's, or those
    :func:`run_node` installs) raise between them.
    """
    ex = make_executor(context)
    for n in nodes:
        ex.add_node(n)
    bus = intra_process()
    if bus is not None:
        bus.attach(ex)
    never = Future()
    _SPINNING[0] = never
    try:
        while rclpy.ok(context=context) and not _SIGNALLED[0] and not (stop is not None and stop()):
            ex.spin_until_future_complete(never, timeout_sec=0.1)  # every event of a 0.1 s slice
    finally:
        _SPINNING[0] = None
        for n in nodes:
            ex.remove_node(n)
        ex.shutdown()


#: Set by :func:`_interrupt`: a signal has asked the node process to stop (reset by :func:`run_node`).
_SIGNALLED = [False]
#: While :func:`spin_nodes` spins, the future its executor spins on: a signal completes it, which ends the spin
#: after the callback in progress (a busy node's executor never ends a 0.1 s slice by itself).
_SPINNING: list[Any] = [None]


def _interrupt(signum: int, frame: Any) -> None:
    """SIGINT / SIGTERM of a node process: stop it.

    While the nodes spin, it completes the future the executor spins on, so the spin ends after the callback in
    progress: a KeyboardInterrupt raised inside a callback would reach rclpy's executor, which logs it as a FATAL
    "Exception in 'timers' callback" with a traceback, in every node log of a run that ended normally.  Before the
    spin (a node still building, which can take long), it stops the process as Ctrl-C does, between two Python steps.
    """
    _SIGNALLED[0] = True
    spinning = _SPINNING[0]
    if spinning is None:
        raise KeyboardInterrupt
    if not spinning.done():
        spinning.set_result(None)


def run_node(node_cls: Callable[..., Any], argv: Sequence[str] | None = None, *, exit_process: bool = False) -> int:
    """``main()`` of a node process: init, build, spin, clean up.

    SIGINT and SIGTERM end the spin, or raise :exc:`KeyboardInterrupt` before it (:func:`_interrupt`),
    instead of running rclpy's own signal handler, which shut the context down
    from inside the signal: a publication in flight then failed ("publisher's
    context is invalid", a traceback), and the context, shut down under rclpy's
    feet, kept its rcl logging open (rclpy closes it in ``Context.shutdown``
    only).  Here the signal ends the spin between two Python steps and the
    context is shut down once, by :func:`rclpy.try_shutdown`, which closes rcl
    logging too (rcl's log file gets its last lines).

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
    args = list(sys.argv if argv is None else argv)
    role_name = getattr(node_cls, "ROLE", "node")
    exe = f"vesselbot_{role_name}"
    node = None
    code = 0
    # SIGINT too is set here: a shell starts a background job with SIGINT ignored, which rclpy's handler overrode
    _SIGNALLED[0] = False
    old = {sig: signal.signal(sig, _interrupt) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
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
    except Exception:
        # a signal's KeyboardInterrupt raised while a C extension had called back into Python (rclpy deserialising
        # a message) comes out as that call's error: after a signal, it is the signal's stop
        if not _SIGNALLED[0]:
            raise
        return code
    finally:
        for sig in old:  # a second signal must not break the clean-up: it is on its way out already
            signal.signal(sig, signal.SIG_IGN)
        if node is not None:
            with contextlib.suppress(Exception):  # best effort during shutdown
                node.destroy_node()
        rclpy.try_shutdown()  # the whole public shutdown: the context, its shutdown callbacks, rcl logging
        if exit_process and sys.exc_info()[0] in (None, KeyboardInterrupt, ExternalShutdownException):
            # Everything of the node is shut down and rcl's log file is closed: end the process here, without the
            # interpreter's teardown (numba's and LLVM's objects, the DDS libraries' static destructors).  Measured
            # from the signal to the process's exit, one reference node process spinning alone, medians of 5:
            # SIGINT 32 ms with this exit, 170 ms without; SIGTERM 64 ms and 164 ms; rcl's log file held the
            # node's log line in all 20 runs (the old exit, which closed logging through rclpy's private
            # _logging_fini on a fresh default context, lost it in 6 of 6).  A graph's six nodes stop together on
            # two cores, so the teardown would add up.
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
        for sig, handler in old.items():
            signal.signal(sig, handler)
