"""The lockstep input join of every node (:class:`TickJoin`): inputs keyed by the tick they serve."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from vesselbot_ros.graph_spec import tick_of_ns

if TYPE_CHECKING:
    from vesselbot_ros.nodes.base import VesselbotNode

__all__ = ["TickJoin"]


class TickJoin:
    """The lockstep input join of every node: inputs keyed by the tick they serve.

    Tick k is *ready* once every input it needs is in: an input with lag L
    serves tick ``k = its own tick + L`` (the observer's ``coil/applied`` k-1
    serves tick k), and ticks ``k < L`` need no such input (None).  An input
    for a tick already handled (or a second one for a waiting tick) is
    rejected as ``stale_tick``, one more than ``window`` ticks ahead as
    ``future_tick``: the message is dropped and no state moves.  Times are
    rebuilt as ``k * dt`` from the tick (:func:`~vesselbot_ros.nodes.conversions.tick_of_ns`),
    never taken from a stamp.

    Args:
        node: The owning node (its :meth:`VesselbotNode.reject` reports rejections).
        inputs: Topic key -> lag (ticks).
        window: How far ahead of the current tick an input may arrive (per key
            with ``windows``; None: unbounded, for inputs keyed by arrival order).
    """

    def __init__(self, node: VesselbotNode, inputs: dict[str, int], window: int = 2,
                 windows: dict[str, int | None] | None = None) -> None:
        self.node = node
        self.lags = dict(inputs)
        self.windows: dict[str, int | None] = dict.fromkeys(inputs, window)
        self.windows.update(windows or {})
        self.k = 0  # the next tick to handle
        self._slots: dict[str, dict[int, Any]] = {key: {} for key in inputs}

    def tick_of(self, key: str, stamp_ns: int, tick_field: int | None = None) -> int | None:
        """The tick a stamp lies on (and matches ``tick_field`` if given), else None (rejected ``off_tick_stamp``)."""
        k, on_grid = tick_of_ns(stamp_ns, self.node.dt)
        if not on_grid or (tick_field is not None and tick_field != k):
            self.node.reject(key, "off_tick_stamp", f"stamp {stamp_ns} ns, tick field {tick_field}")
            return None
        return k

    def put(self, key: str, k: int, value: Any) -> bool:
        """Store input ``key`` of tick ``k``; False (and rejected) if stale, duplicate or too far ahead."""
        kk = k + self.lags[key]
        slot = self._slots[key]
        if kk < self.k or kk in slot:
            self.node.reject(key, "stale_tick", f"tick {k}, node at {self.k}")
            return False
        w = self.windows[key]
        if w is not None and kk > self.k + w:
            self.node.reject(key, "future_tick", f"tick {k}, node at {self.k}")
            return False
        slot[kk] = value
        return True

    def fits(self, key: str, k: int) -> bool:
        """True if :meth:`put` would store input ``key`` of tick ``k`` (nothing is stored nor rejected)."""
        kk = k + self.lags[key]
        w = self.windows[key]
        return kk >= self.k and kk not in self._slots[key] and (w is None or kk <= self.k + w)

    def pop_ready(self) -> dict[str, Any] | None:
        """The inputs of the current tick if all are in (and advance to the next tick), else None."""
        k = self.k
        for key, lag in self.lags.items():
            if k >= lag and k not in self._slots[key]:
                return None
        self.k = k + 1
        return {key: (self._slots[key].pop(k) if k >= lag else None) for key, lag in self.lags.items()}

    def expect(self, key: str, k: int, running: bool = True) -> bool:
        """Single-input nodes: accept tick ``k`` only if it is the current one (else reject stale / future)."""
        if running and k == self.k:
            return True
        self.node.reject(key, "stale_tick" if k < self.k or not running else "future_tick",
                         f"tick {k}, node at tick {self.k}")
        return False

