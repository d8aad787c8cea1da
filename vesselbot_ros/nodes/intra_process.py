"""The intra-process bus of a composed process: deliveries between co-located nodes without DDS.

:func:`use_intra_process` sets the process's bus before its nodes are
built; each :class:`~vesselbot_ros.nodes.base.VesselbotNode` takes the bus
that :func:`intra_process` returns when it is built, and
:func:`~vesselbot_ros.nodes.process.spin_nodes` attaches it to the executor.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Callable, Iterable
from typing import Any

from vesselbot_ros.graph_spec import topic

__all__ = ["IntraProcess", "intra_process", "use_intra_process"]


class IntraProcess:
    """Deliveries between nodes composed in one process, without DDS (``--single-process``).

    What rclcpp's intra-process communication does for composed nodes: a
    message published by a co-located node goes to its co-located subscribers
    as the same Python object (no serialization, no DDS, no copy), and over DDS
    only when a subscriber outside the process (the recorder, the launcher, a
    viewer, a user's node) is matched.  Nodes never mutate a message they
    published or received, which is what makes sharing it safe.

    Deliveries are queued first in, first out, and run as a task of the
    executor (:meth:`attach`), at most :attr:`BUDGET` per turn, so the executor still
    serves timers, services and DDS inputs between them; a message posted
    from another thread (the simulation_interfaces thread stepping the plant)
    is delivered on the executor's thread.  Only topics whose publishing role
    (graph spec) is composed here travel this way, latched ones excepted (they
    stay on DDS, for late joiners): their co-located subscribers create no DDS
    subscription, so nothing is delivered twice.
    """

    #: Deliveries per executor turn (a lockstep tick is nine).
    BUDGET = 256

    def __init__(self, roles: Iterable[str]) -> None:
        self.roles = frozenset(roles)
        self._subs: dict[str, list[Callable[[Any], None]]] = {}
        self._pubs: Counter[str] = Counter()
        self._queue: Any = deque()
        self._ex: Any = None
        self._pending = False

    def carries(self, key: str) -> bool:
        """True if topic ``key`` travels in process: published by a role composed here, and not latched."""
        spec = topic(key)
        return spec.publisher in self.roles and spec.qos != "reliable_latched"

    def add_publisher(self, key: str) -> None:
        """A co-located node publishes ``key``."""
        self._pubs[key] += 1

    def subscribe(self, key: str, callback: Callable[[Any], None]) -> None:
        """Deliver every message of ``key`` published here to ``callback`` (on the attached executor)."""
        self._subs.setdefault(key, []).append(callback)

    def attach(self, executor: Any) -> None:
        """Run deliveries on ``executor`` (the one spinning the composed nodes)."""
        self._ex = executor
        if self._queue:
            self._schedule()

    def _schedule(self) -> None:
        self._pending = True
        if self._ex is not None:
            self._ex.create_task(self._drain)

    def publishers(self, key: str) -> int:
        """Co-located publishers of ``key``."""
        return self._pubs[key]

    def subscribers(self, key: str) -> int:
        """Co-located subscribers of ``key``."""
        return len(self._subs.get(key, ()))

    def post(self, key: str, msg: Any) -> None:
        """Queue ``msg`` for every co-located subscriber of ``key`` (any thread)."""
        subs = self._subs.get(key)
        if not subs:
            return
        q = self._queue
        for cb in subs:
            q.append((cb, msg))
        if not self._pending:
            self._schedule()

    def _drain(self) -> None:
        q = self._queue
        try:
            for _ in range(self.BUDGET):
                if not q:
                    break
                cb, msg = q.popleft()
                cb(msg)
        finally:
            self._pending = False  # posts from here on schedule their own turn
            if q:
                self._schedule()



#: The process's intra-process bus (None: every message goes over DDS); set by :func:`use_intra_process`.
_INTRA: IntraProcess | None = None


def use_intra_process(roles: Iterable[str] | None) -> IntraProcess | None:
    """Compose the nodes of ``roles`` built from now on over one :class:`IntraProcess` bus (None: off)."""
    global _INTRA
    _INTRA = IntraProcess(roles) if roles is not None else None
    return _INTRA


def intra_process() -> IntraProcess | None:
    """The process's intra-process bus as :func:`use_intra_process` last set it (None: off)."""
    return _INTRA
