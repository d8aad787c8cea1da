"""Republish a recorded bag with its original timing (scaled), like ``ros2 bag play``.

:func:`replay` publishes the recorded CDR bytes unchanged (raw publish: no
decoding) on publishers with the recorded topic's QoS (the graph's QoS from
:mod:`vesselbot_ros.graph_spec` for its own topics, transient local for latched
ones).  Message *i* is published at wall time
``t0 + (log_time_i - log_time_first) / rate``.

Clock: a lockstep bag holds the plant's ``/clock``, which is republished like
any topic, so sim-time nodes follow the recorded sim time.  With
``clock=True``, ``/clock`` is published by the player before every message
whose time differs from the last one published: the *sim time* of that
message, i.e. the last recorded ``/clock`` at or before its log time (the
stamps in the messages are sim time too, so ``/clock`` and the stamps agree).
A bag without a recorded ``/clock`` gets the bag time (log time since the
bag's first message, from 0).  The recorded ``/clock`` is then read, not
republished (one clock source only).  The wall-clock receive time of the
recording is never published as ``/clock``.

``on_clock`` receives that same sim time (whether or not ``/clock`` is
published: ``replay --live`` broadcasts it as the live view's time), and
``on_message`` each message with its original log time.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vesselbot_ros.bag.reader import BagInfo, iter_messages, open_bag
from vesselbot_ros.errors import BagError
from vesselbot_ros.graph_spec import TOPICS, qos_profile, topic

__all__ = ["ReplayStats", "replay", "make_publishers"]

CLOCK_TOPIC = topic("clock").name


@dataclass(frozen=True)
class ReplayStats:
    """What a replay published.

    Attributes:
        published: Messages published per topic (all loops).
        loops: Completed passes over the bag.
        wall_s: Wall time spent publishing (s).
        max_lateness_s: Largest delay of a publication behind its schedule (s), measured once it was published.
    """

    published: dict[str, int]
    loops: int
    wall_s: float
    max_lateness_s: float


def _import_type(msgtype: str) -> Any:
    pkg, kind, name = msgtype.split("/")
    try:
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ImportError, AttributeError):
        raise BagError(f"cannot replay {msgtype}: its Python package {pkg} is not installed") from None


def make_publishers(node: Any, info: BagInfo, topics: Sequence[str]) -> dict[str, Any]:
    """Publishers for ``topics`` of a bag, with the graph's QoS where known."""
    # deferred: rclpy and the message packages; this module is imported ROS-free (launch.reestimate's planning, tests)
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    specs = {s.name: s for s in TOPICS}
    pubs = {}
    for name in topics:
        t = info.topic(name)
        assert t is not None
        if name in specs:
            qos = qos_profile(specs[name])
        else:
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1 if t.latched else 100,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL if t.latched else DurabilityPolicy.VOLATILE)
        pubs[name] = node.create_publisher(_import_type(t.msgtype), name, qos)
    return pubs


def replay(
    bag: str | Path | BagInfo,
    node: Any,
    *,
    rate: float = 1.0,
    topics: Sequence[str] | None = None,
    start_s: float = 0.0,
    loop: bool = False,
    clock: bool = False,
    wait_subscribers_s: float = 0.0,
    should_stop: Callable[[], bool] = lambda: False,
    log: Callable[[str], None] = lambda s: None,
    on_message: Callable[[str, bytes, int], None] | None = None,
    on_clock: Callable[[int], None] | None = None,
) -> ReplayStats:
    """Publish a bag's messages on ``node`` with their recorded timing divided by ``rate``.

    Args:
        bag: Bag directory or validated :class:`BagInfo`.
        node: An rclpy node to create the publishers on.
        rate: Speed factor (> 0): 2 plays twice as fast.
        topics: Only these topics (default: all recorded topics).
        start_s: Skip the first ``start_s`` seconds of the bag (log time).
        loop: Replay again from ``start_s`` until ``should_stop()``.
        clock: Publish ``/clock`` from the bag's log time (see module doc).
        wait_subscribers_s: First wait up to this long until every replayed
            topic with a message has a subscriber (0: do not wait).
        should_stop: Polled between messages; True ends the replay.
        log: Receives progress lines.
        on_message: Also called with (topic, CDR bytes, log time ns as recorded) for every
            message published (``replay --live`` hands them to the live view).
        on_clock: Called with the sim time (ns) that ``clock`` publishes, before every message
            whose sim time differs from the last one (also without ``clock``).

    Raises:
        BagError: for an invalid bag, an unknown topic or a bad argument.
    """
    if not rate > 0:
        raise BagError(f"--rate must be > 0, got {rate}")
    if not (start_s >= 0 and start_s < float("inf")):
        raise BagError(f"--start must be a finite time >= 0 s, got {start_s}")
    info = bag if isinstance(bag, BagInfo) else open_bag(bag)
    names = [t.name for t in info.topics] if topics is None else list(dict.fromkeys(topics))
    unknown = sorted(set(names) - {t.name for t in info.topics})
    if unknown:
        raise BagError(f"bag {info.path} has no topic {', '.join(unknown)}; it has {[t.name for t in info.topics]}")
    if clock:
        names = [n for n in names if n != CLOCK_TOPIC]
    # the sim time comes from the recorded /clock, read (and republished only if among the names)
    recorded_clock = (clock or on_clock is not None) and info.topic(CLOCK_TOPIC) is not None
    read = names + [CLOCK_TOPIC] if recorded_clock and CLOCK_TOPIC not in names else names
    pubs = make_publishers(node, info, names)
    clock_pub = None
    if clock:
        from rosgraph_msgs.msg import Clock  # deferred: a message package (see make_publishers)

        clock_pub = node.create_publisher(Clock, CLOCK_TOPIC, qos_profile(topic("clock")))

    if wait_subscribers_s > 0:
        deadline = time.monotonic() + wait_subscribers_s
        # a topic the bag declares with no message (coil/stall of a run without a stall) has nothing to wait for
        awaited = {n: p for n, p in pubs.items() if info.topic(n).count}  # type: ignore[union-attr]  # pubs: the bag's own topics
        while time.monotonic() < deadline and not should_stop():
            if all(p.get_subscription_count() > 0 for p in awaited.values()):
                # our side has matched; give the subscribers' side of DDS discovery time to
                # match too, or the first reliable samples arrive late through repairs
                time.sleep(0.5)
                break
            time.sleep(0.02)
        else:
            missing = [n for n, p in awaited.items() if p.get_subscription_count() == 0]
            if missing:
                log(f"no subscriber after {wait_subscribers_s} s on {missing}; publishing anyway")

    start_ns = info.start_ns + int(round(start_s * 1e9))
    sim_at_start = _sim_time_before(info, start_ns) if recorded_clock else None
    published = dict.fromkeys(names, 0)
    loops = 0
    max_late = 0.0
    t_begin = time.monotonic()
    sleep = time.sleep
    while True:
        t0_wall = time.monotonic()
        first_ns: int | None = None
        sim_ns = sim_at_start
        last_clock_ns: int | None = None
        for m in iter_messages(info, topics=read, start_ns=start_ns):
            if recorded_clock and m.topic == CLOCK_TOPIC:
                sim_ns = _clock_ns(m.data)
                if m.topic not in pubs:
                    continue
            if should_stop():
                return ReplayStats(published, loops, time.monotonic() - t_begin, max_late)
            if first_ns is None:  # the schedule starts at the first message, after the reader opened
                first_ns = m.log_time_ns
                t0_wall = time.monotonic()
            due = t0_wall + (m.log_time_ns - first_ns) * 1e-9 / rate
            delay = due - time.monotonic()
            if delay > 0:
                sleep(delay)
            if clock_pub is not None or on_clock is not None:
                now_ns = sim_ns if recorded_clock else m.log_time_ns - info.start_ns
                if now_ns is not None and now_ns != last_clock_ns:
                    if clock_pub is not None:
                        from rosgraph_msgs.msg import Clock  # deferred: a message package (see make_publishers)

                        c = Clock()
                        c.clock.sec, c.clock.nanosec = divmod(now_ns, 1_000_000_000)
                        clock_pub.publish(c)
                    if on_clock is not None:
                        on_clock(now_ns)
                    last_clock_ns = now_ns
            pubs[m.topic].publish(m.data)
            # how late it went out, measured once it did: an oversleep and the publication itself included (the
            # oversleep was left out, so a loaded machine's late publications were reported as on time)
            max_late = max(max_late, time.monotonic() - due)
            published[m.topic] += 1
            if on_message is not None:
                on_message(m.topic, m.data, m.log_time_ns)
        loops += 1
        log(f"pass {loops} done: {sum(published.values())} messages published")
        if not loop or should_stop() or first_ns is None:
            break
    from rclpy.duration import Duration  # deferred: rclpy (see make_publishers)

    for p in pubs.values():  # reliable delivery of the tail before the caller exits
        p.wait_for_all_acked(Duration(seconds=2))
    return ReplayStats(published, loops, time.monotonic() - t_begin, max_late)


def _clock_ns(data: bytes) -> int:
    """Sim time (ns) of a serialized ``rosgraph_msgs/Clock``."""
    # deferred: rclpy and a message package (see make_publishers)
    from rclpy.serialization import deserialize_message
    from rosgraph_msgs.msg import Clock

    c = deserialize_message(bytes(data), Clock)
    return int(c.clock.sec) * 1_000_000_000 + int(c.clock.nanosec)


def _sim_time_before(info: BagInfo, start_ns: int) -> int | None:
    """The last recorded ``/clock`` before log time ``start_ns`` (None if there is none)."""
    last = None
    for m in iter_messages(info, topics=[CLOCK_TOPIC]):
        if m.log_time_ns >= start_ns:
            break
        last = _clock_ns(m.data)
    return last
