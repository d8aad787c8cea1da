"""The axes of the model's vectors, named once for every layer (the cores, the wire formats, the tables, reports).

A planar scenario (a straight vessel or a planar network) works on (2,) vectors ``(x, z)``: the plane y = 0, whose
messages carry y = 0; a 3-D tree on (3,) vectors ``(x, y, z)`` (``Scenario.dims``).  Frame ``vessel`` (W).
"""

from __future__ import annotations

__all__ = ["AXES", "AXIS_INDEX"]

#: The axis names of the core's vectors per axis count.
AXES: dict[int, tuple[str, ...]] = {2: ("x", "z"), 3: ("x", "y", "z")}
#: :data:`AXES` as indices into an ``(x, y, z)`` vector (a message's).
AXIS_INDEX: dict[int, tuple[int, ...]] = {d: tuple("xyz".index(a) for a in names) for d, names in AXES.items()}
