"""The run's time series, kept by the node that publishes them and served once at the end of a run.

A per-tick topic whose :class:`~vesselbot_ros.graph_spec.TopicSpec` names
``series`` (truth, estimate, reference, coil state) carries some of the run's
series: its publisher copies the floats of every message it publishes into one
row per tick (:class:`SeriesLog`, a few microseconds per tick) and answers
``<role>/series`` (``vesselbot_msgs/srv/GetSeries``) with them after the run.
The launcher reads a run's series this way instead of subscribing to four
per-tick topics, which cost the loop four deliveries per tick; it subscribes
only to the topics a user's node publishes (``--without``), and reads those
messages with the same :data:`READERS`.  The values are the floats of the
published messages, so they equal what the bag holds bit for bit.
"""

from __future__ import annotations

import functools
import operator
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from vesselbot_ros.graph_spec import tick_of_ns, topic
from vesselbot_ros.physics.axes import AXES

__all__ = ["SERIES_COLUMNS", "READERS", "SeriesLog", "series_columns", "columns_of", "readers", "series_from_response",
           "split_series", "empty_series"]

#: series name -> its columns: a vector's per axis (``{}`` takes the axis name, :data:`~vesselbot_ros.physics.axes.AXES`)
#: or one flag
_SERIES: dict[str, str] = {
    "p_true": "p_true_{}_m",
    "v_true": "v_true_{}_m_per_s",
    "in_contact": "in_contact",
    "x_hat": "x_hat_{}_m",
    "z_hat": "z_hat_{}_m_per_s",
    "p_ref": "p_ref_{}_m",
    "g_applied": "g_applied_{}_T_per_m",
    "saturated": "saturated",
    "slew_limited": "slew_limited_{}",
    # the coil rejected the tick's command (non-finite, malformed): what the metrics' rejected_commands count
    "cmd_rejected": "cmd_rejected",
}

#: Flags (stored as 0.0 / 1.0, returned as bool).
FLAGS = frozenset({"in_contact", "saturated", "slew_limited", "cmd_rejected"})

#: topic key -> the fields of its flat form (nodes/wire.py) the series read, in the order of its spec's ``series``
#: columns (``{}`` per axis, as in :data:`_SERIES`)
_FIELDS: dict[str, tuple[str, ...]] = {
    "truth": ("position_{}", "velocity_{}", "in_contact"),
    "estimate": ("pose_pose_position_{}", "twist_twist_linear_{}"),
    "reference": ("position_{}",),
    "coil_state": ("applied_{}", "saturated", "slew_limited_{}", "command_rejected"),
}

#: topic key -> its messages carry the tick (else: their stamp on the tick grid gives it)
_HAS_TICK: dict[str, bool] = {"truth": True, "estimate": False, "reference": True, "coil_state": True}


def _per_axis(pattern: str, dims: int) -> tuple[str, ...]:
    return tuple(pattern.format(a) for a in AXES[dims]) if "{}" in pattern else (pattern,)


@functools.cache
def series_columns(dims: int = 2) -> dict[str, tuple[str, ...]]:
    """Series name -> its columns, for a scenario of ``dims`` axes (``Scenario.dims``)."""
    return {name: _per_axis(pattern, dims) for name, pattern in _SERIES.items()}


def _reader(fields: tuple[str, ...]) -> Callable[[Any], tuple[float, ...]]:
    get = operator.attrgetter(*fields)
    return lambda m: tuple(map(float, get(m)))


@functools.cache
def readers(dims: int = 2) -> dict[str, Callable[[Any], tuple[float, ...]]]:
    """Topic key -> one message's series floats (flags as 0.0 / 1.0), for a scenario of ``dims`` axes."""
    return {key: _reader(tuple(f for pattern in fields for f in _per_axis(pattern, dims)))
            for key, fields in _FIELDS.items()}


#: The planar scenario's :func:`series_columns`.
SERIES_COLUMNS = series_columns(2)
#: The planar scenario's :func:`readers`.
READERS = readers(2)


def columns_of(key: str, dims: int = 2) -> tuple[str, ...]:
    """The columns topic ``key`` carries (empty: none), for a scenario of ``dims`` axes."""
    cols = series_columns(dims)
    return tuple(c for name in topic(key).series for c in cols[name])


class SeriesLog:
    """One row per tick of the series a node's published topics carry.

    Args:
        keys: Topic keys the node publishes (those without series are ignored).
        n: Ticks of the run.
        dt: Control period (s).
        dims: Axes of the scenario's vectors (``Scenario.dims``: 2 planar, 3 a 3-D tree).
    """

    def __init__(self, keys: Iterable[str], n: int, dt: float, dims: int = 2) -> None:
        self.keys = tuple(k for k in keys if topic(k).series)
        self.columns = tuple(c for k in self.keys for c in columns_of(k, dims))
        self.n = int(n)
        self.dt = float(dt)
        # per topic: (tick or stamp ns, floats) as published; the table is built when asked for (:attr:`values`)
        self._rows: dict[str, list[tuple[int, tuple[float, ...]]]] = {k: [] for k in self.keys}
        self._slot: dict[str, tuple[int, int, Callable[[Any], tuple[float, ...]], bool]] = {}
        col = 0
        read = readers(dims)
        for k in self.keys:
            w = len(columns_of(k, dims))
            self._slot[k] = (col, col + w, read[k], _HAS_TICK[k])
            col += w

    def add(self, key: str, msg: Any) -> None:
        """Keep the floats of one published message of topic ``key``, in its flat form (others: ignored); about 1 us."""
        slot = self._slot.get(key)
        if slot is None:
            return
        if slot[3]:
            self._rows[key].append((msg.tick, slot[2](msg)))
        else:
            self._rows[key].append((msg.header_stamp_sec * 1_000_000_000 + msg.header_stamp_nanosec, slot[2](msg)))

    @property
    def values(self) -> np.ndarray:
        """(n, columns) table: row k holds the floats of the message of tick k (NaN: none; the last one wins)."""
        table = np.full((self.n, len(self.columns)), np.nan)
        for key, rows in self._rows.items():
            a, b, _read, has_tick = self._slot[key]
            for t, vals in rows:
                if has_tick:
                    k: int | None = int(t)
                else:
                    k, on_grid = tick_of_ns(int(t), self.dt)
                    k = k if on_grid else None
                if k is not None and 0 <= k < self.n:
                    table[k, a:b] = vals
        return table

    def reset(self) -> None:
        """Forget every row (ResetSimulation: the run starts again at tick 0)."""
        for rows in self._rows.values():
            rows.clear()

    def as_dict(self) -> dict[str, np.ndarray]:
        """``{series name: array}`` of the rows so far (as :func:`series_from_response` returns them)."""
        return split_series(list(self.columns), self.values)

    def fill(self, response: Any) -> Any:
        """Fill a ``GetSeries`` response with every row."""
        response.rows = self.n
        response.columns = list(self.columns)
        response.values = self.values.ravel().tolist()
        return response


def series_from_response(response: Any) -> dict[str, np.ndarray]:
    """A ``GetSeries`` response -> ``{series name: (rows, width) array}`` (flags as bool, width-1 series 1-D).

    Raises:
        ValueError: the response's shape does not add up, or a column is unknown.
    """
    cols = list(response.columns)
    rows = int(response.rows)
    values = np.asarray(response.values, dtype=float)
    if values.size != rows * len(cols):
        raise ValueError(f"series response holds {values.size} values, not {rows} rows x {len(cols)} columns")
    return split_series(cols, values.reshape(rows, len(cols)))


def split_series(cols: list[str], table: np.ndarray) -> dict[str, np.ndarray]:
    """Columns of a (rows, columns) table -> ``{series name: array}`` (flags as bool, width-1 series 1-D).

    A vector is (rows, 3) when its y column is there (a 3-D tree), else (rows, 2).

    Raises:
        ValueError: a column is unknown, or a vector has its y column without its x and z.
    """
    out: dict[str, np.ndarray] = {}
    planar, space = series_columns(2), series_columns(3)
    for name, names in planar.items():
        if names[0] not in cols:
            continue
        if len(space[name]) == 3 and space[name][1] in cols:
            names = space[name]
        idx = [cols.index(c) for c in names]
        block = table[:, idx]
        if name in FLAGS:
            block = np.nan_to_num(block) != 0.0
        out[name] = block[:, 0] if len(names) == 1 else block
    known = {c for d in AXES for names in series_columns(d).values() for c in names}
    unknown = set(cols) - known
    if unknown:
        raise ValueError(f"unknown series columns {sorted(unknown)}")
    lone = [c for names in space.values() if len(names) == 3 and names[1] in cols
            for c in (names[0], names[2]) if c not in cols]
    if lone:
        raise ValueError(f"series columns {sorted(lone)} missing next to their y column")
    return out


def empty_series(n: int, dims: int = 2) -> dict[str, np.ndarray]:
    """Every series of a run of ``n`` ticks (vectors over ``dims`` axes), unknown (NaN; flags False)."""
    out: dict[str, np.ndarray] = {}
    for name, names in series_columns(dims).items():
        shape = (n,) if len(names) == 1 else (n, len(names))
        out[name] = np.zeros(shape, dtype=bool) if name in FLAGS else np.full(shape, np.nan)
    return out
