"""``vesselbot replay DIR [--rate R] [--topics ...] [--start S] [--loop] [--clock]``
and ``vesselbot replay DIR --into {observer,controller} [--node-cmd CMD] [--out OUT]``.

Plain replay publishes in the ROS domain of the environment
(``ROS_DOMAIN_ID``), with localhost-only discovery unless
``ROS_AUTOMATIC_DISCOVERY_RANGE`` is set.

``--into ROLE`` re-runs one node on the bag's inputs instead
(:mod:`vesselbot_ros.launch.reestimate`): a fresh node in a leased domain, fed
tick by tick, its outputs recorded next to the originals and compared, into a
new bag beside the recorded one (``DIR.reestimate_ROLE/``, or ``--out``).  Exit
codes: 0 every tick answered (and, with ``--tolerance``, every difference
within it); 1 the node died, a tick went unanswered, or a difference exceeds
``--tolerance``; 2 a bad bag or argument.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from vesselbot_ros.errors import BagError

if TYPE_CHECKING:  # annotations only: the replay imports the bag modules when it runs, not on --help
    from vesselbot_ros.bag.info import BagInfo

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
    parser.add_argument("--live", action="store_true",
                        help="also serve the replay live over the Foxglove WebSocket protocol (port 8765), on the "
                             "bag's sim time")
    parser.add_argument("--live-port", type=int, default=None, metavar="N",
                        help="port of the live view (0: any free port, printed once it listens); implies --live")
    parser.add_argument("--live-rate", type=float, default=None, metavar="HZ",
                        help="messages per topic and wall second sent to the live view, at most (default 50; 0: all)")
    parser.add_argument("--wait-subscribers", type=float, default=0.0, metavar="S",
                        help="first wait up to S seconds until every replayed topic has a subscriber")
    g = parser.add_argument_group("re-run one node on the bag's inputs (lockstep bags)")
    g.add_argument("--into", choices=("observer", "controller"), default=None,
                   help="feed the recorded inputs tick by tick into a fresh ROLE node and compare its outputs "
                        "with the recorded ones")
    g.add_argument("--node-cmd", default=None, metavar="CMD",
                   help="command of the node under test (default: ours); '{params}' is replaced by the "
                        "scenario's --params-file, else '--ros-args --params-file F' is appended")
    g.add_argument("--out", default=None, metavar="DIR",
                   help="result bag (default <bag>.reestimate_<ROLE>, beside the bag folder, which holds the bag only)")
    g.add_argument("--answer-timeout", type=float, default=10.0, metavar="S",
                   help="wall time to wait for the node's answer to each tick (default 10 s)")
    g.add_argument("--wait-timeout", type=float, default=60.0, metavar="S",
                   help="wall time to wait for the node to start and match (default 60 s)")
    g.add_argument("--tolerance", type=float, default=None, metavar="X",
                   help="exit 1 if any |new - recorded| exceeds X (SI units of each field)")
    g.add_argument("--domain-id", type=int, default=None, help="ROS domain for --into (default: lease a free one)")


def run(args: argparse.Namespace) -> int:
    """Replay the bag (or re-run one node on it, ``--into``); Ctrl-C stops cleanly."""
    # deferred: the bag reader pulls in numpy and yaml (~0.1 s); `vesselbot replay --help` imports this module
    from vesselbot_ros.bag.reader import open_bag

    info = open_bag(args.bag)  # fail on a broken bag before starting ROS
    if args.into is not None:
        return _run_into(args, info)
    if args.node_cmd is not None or args.out is not None or args.tolerance is not None:
        raise BagError("--node-cmd, --out and --tolerance need --into observer|controller")
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    # deferred: rclpy and the player load only when a bag is replayed, not for `vesselbot replay --help`
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from vesselbot_ros.bag.replay import replay

    live = _live_view(args, info)
    # rclpy's own signal handler would shut the context down from inside the signal, under a publication in
    # flight ("publisher's context is invalid": a traceback and exit 1 on Ctrl-C); without it, SIGINT and SIGTERM
    # raise KeyboardInterrupt between two Python steps, and the context is shut down below, after the loop (SIGINT
    # too is set here: a shell starts a background job with SIGINT ignored, which rclpy's handler overrode)
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("vesselbot_player")

    signalled = False

    def on_signal(signum: int, frame: Any) -> None:
        nonlocal signalled
        signalled = True
        raise KeyboardInterrupt

    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    stopped = False
    try:
        stats = replay(info, node, rate=args.rate, topics=args.topics, start_s=args.start, loop=args.loop,
                       clock=args.clock, wait_subscribers_s=args.wait_subscribers,
                       log=lambda s: print(f"vesselbot replay: {s}", file=sys.stderr, flush=True),
                       on_message=live.log if live is not None else None,
                       on_clock=live.set_time if live is not None else None)
    except Exception:  # after a signal, whatever it surfaced as
        # a signal's KeyboardInterrupt raised while a C extension had called back into Python comes out as that
        # call's error (rclpy's deserialisation of a /clock message: "TypeError: Unable to convert function return
        # value", from the KeyboardInterrupt; a clean-clone CI run): after a signal, it is the signal
        if not signalled:
            raise
        stopped = True
        print("vesselbot replay: stopped", file=sys.stderr)
    except KeyboardInterrupt:  # the signals above; nothing else shuts this context down during the replay
        stopped = True
        print("vesselbot replay: stopped", file=sys.stderr)
    finally:
        # once stopped by a signal, a second one changes nothing while the player cleans up
        for sig, handler in old.items():
            signal.signal(sig, signal.SIG_IGN if stopped else handler)
        node.destroy_node()
        rclpy.try_shutdown()
        if live is not None:
            live.close()
    if stopped:
        # the process ends here, as a node process does (nodes/process.py): after a signal, the interpreter's
        # own shutdown sometimes ended in an uncaught KeyboardInterrupt, so the process died of SIGINT (exit -2)
        # after it had said "stopped" (three clean-clone CI runs, with SIGINT and with SIGTERM; not reproduced
        # alone), whatever handler was set; the player has nothing left to do but flush its streams
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)
    print(f"vesselbot replay: published {sum(stats.published.values())} messages in {stats.wall_s:.2f} s "
          f"({stats.loops} pass(es)); max lateness {stats.max_lateness_s * 1e3:.2f} ms", flush=True)
    return 0


def _live_view(args: argparse.Namespace, info: Any) -> Any:
    """The live view of the replayed topics (``--live`` / ``--live-port``), or None."""
    # deferred: the live view's modules (~20 ms) are not needed by `vesselbot replay --help`
    from vesselbot_ros.live import DEFAULT_LIVE_PORT, DEFAULT_LIVE_RATE_HZ, LiveView

    port = args.live_port if args.live_port is not None else (DEFAULT_LIVE_PORT if args.live else None)
    if port is None:
        return None
    if not 0 <= port <= 65535:
        raise BagError(f"--live-port must be in [0, 65535], got {port}")
    from vesselbot_ros.bag.writer import make_typestore  # deferred: rosbags (~35 ms), only with a live view

    topics = [t for t in info.topics if args.topics is None or t.name in args.topics]
    ts = make_typestore([t.msgtype for t in topics])
    try:
        rate = DEFAULT_LIVE_RATE_HZ if args.live_rate is None else args.live_rate
        live = LiveView([(t.name, t.msgtype, t.latched) for t in topics], ts, port=port, max_rate_Hz=rate)
    except ValueError as exc:
        raise BagError(f"--live-rate: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - the SDK raises its own types for a busy port
        raise BagError(f"live view: cannot serve on port {port}: {exc}") from None
    print(f"vesselbot replay: live view on {live.url}", flush=True)
    return live


def _run_into(args: argparse.Namespace, info: BagInfo) -> int:
    # deferred: re-running a node pulls in the compiled core and rosbags; `vesselbot replay --help` imports this module
    from vesselbot_ros.launch.reestimate import ROLES, reestimate, reestimate_dir, replay_topic

    if args.tolerance is not None and not args.tolerance >= 0:
        raise BagError(f"--tolerance must be >= 0, got {args.tolerance}")
    _check_into_out(args, info, reestimate_dir(info.path, args.into))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    res = reestimate(info, args.into, out_dir=args.out, node_cmd=args.node_cmd,
                     answer_timeout_s=args.answer_timeout, wait_timeout_s=args.wait_timeout,
                     domain_id=args.domain_id,
                     log=lambda s: print(f"vesselbot replay: {s}", file=sys.stderr, flush=True))
    c = res.comparison
    rate = res.fed / res.wall_s if res.wall_s > 0 else float("inf")
    print(f"vesselbot replay --into {res.role}: fed {res.fed}/{res.planned} ticks, answered {res.answered}, "
          f"{res.wall_s:.2f} s wall ({rate:.0f} ticks/s)")
    print(f"  compared {c.compared} ticks with the recording: {c.identical} bit-identical"
          + (f", first difference at tick {c.first_difference_tick}" if c.first_difference_tick is not None else ""))
    for name in ROLES[res.role].fields:
        print(f"  max |new - recorded| {name:22s} {c.max_abs[name]:.6g}")
    print(f"  bag: {res.out_dir} (new output on {replay_topic(res.role)}; comparison.json)")
    if res.error:
        print(f"vesselbot replay: error: {res.error}", file=sys.stderr)
        return 1
    if args.tolerance is not None and c.max_abs_overall > args.tolerance:
        print(f"vesselbot replay: max difference {c.max_abs_overall:.6g} exceeds --tolerance {args.tolerance:g}",
              file=sys.stderr)
        return 1
    return 0


def _holds_bag(d: Path) -> bool:
    return (d / "metadata.yaml").exists() or any(d.glob("*.mcap"))


def _check_into_out(args: argparse.Namespace, info: Any, default: Path) -> None:
    """Refuse an --into result folder (``default``: beside the bag) that already holds a bag, suggesting a free ``--out``."""
    out = Path(args.out) if args.out is not None else default
    if not _holds_bag(out):
        return
    n = 2
    while _holds_bag(default.with_name(f"{default.name}_{n}")):
        n += 1
    free = default.with_name(f"{default.name}_{n}")
    existing = ", ".join(p.name for p in (out / "metadata.yaml", *sorted(out.glob("*.mcap"))) if p.exists())
    what = f" from an earlier `replay --into {args.into}`" if out.resolve() == default.resolve() else ""
    raise BagError(f"{out} already holds a bag ({existing}){what}; it is not overwritten: pass --out DIR for "
                   f"a new result (e.g. --out {free})")
