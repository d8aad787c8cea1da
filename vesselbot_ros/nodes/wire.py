"""Flat CDR codecs: the hot path's messages to and from the wire as flat tuples, without message objects.

rclpy turns a received message into Python by calling the generated
constructor of every nested message (a PlantState is 17 of them), and a
published one back field by field; between processes that cost more than the
delivery itself.  Building our own message objects cost about as much
(``bench/bench_graph.py``, docs/graph.md "Flat forms instead of message
objects": with message objects built and read on the hot path the graph took
1.24-1.38x the bare chain with one process per node, 1.04-1.09x with flat
forms).  So a per-tick message lives in the nodes
in its *flat form*: a named tuple (:attr:`FlatCodec.Flat`) of every value of
its CDR in wire order, fields named by their path (``header_stamp_sec``,
``vector_x``, ``pose_covariance_35``; a string as ``<path>_size`` and
``<path>_cdr``, its NUL-terminated bytes).  A :class:`FlatCodec` does:

* :meth:`FlatCodec.unpack`: CDR -> flat form, one ``struct`` call;
* :meth:`FlatCodec.pack`: flat form -> CDR, one ``struct`` call;
* :meth:`FlatCodec.maker`: a builder of the flat form from a few values (the
  others are the type's defaults and the graph's strings);
* :meth:`FlatCodec.flatten` and :meth:`FlatCodec.to_message`: rclpy message
  <-> flat form, for tools, tests and anything off the layout.

Its layout is derived from the message type's rosidl introspection
(``SLOT_TYPES``): XCDR1 little endian, as rmw_fastrtps writes it, each
primitive aligned to its size relative to the payload after the 4-byte
encapsulation header.  A type qualifies when every field is a primitive, a
fixed-size array of primitives, a nested message that qualifies, or a string
whose value the graph fixes (``header.frame_id`` is ``vessel``);
:func:`codec_for` returns None for the others.  A buffer off the layout
(another frame_id, an empty one, a big-endian sender, a truncated buffer)
goes through rclpy's own (de)serializer instead, so nothing is rejected here
that the node would not reject itself, and a flat form with another string
is packed by rclpy's serializer.

``test/unit/nodes/test_wire.py`` checks both directions against rclpy's
serializer for every hot-path type, with random values (hypothesis).
"""

from __future__ import annotations

import importlib
import struct
from collections import namedtuple
from collections.abc import Callable
from functools import cache
from typing import Any

import numpy as np

__all__ = ["FlatCodec", "codec_for", "message_builder", "ENCAPSULATION_LE"]

#: CDR_LE encapsulation header (representation identifier 0x0001, options 0).
ENCAPSULATION_LE = b"\x00\x01\x00\x00"

#: rosidl primitive -> (struct code, size in bytes).
_PRIMITIVES = {
    "double": ("d", 8), "float": ("f", 4), "int64": ("q", 8), "uint64": ("Q", 8), "int32": ("i", 4),
    "uint32": ("I", 4), "int16": ("h", 2), "uint16": ("H", 2), "int8": ("b", 1), "uint8": ("B", 1),
    "octet": ("B", 1), "boolean": ("?", 1), "char": ("B", 1),
}


def message_builder(cls: Any) -> Any:
    """A keyword-only constructor of message ``cls`` that stores every field directly.

    The generated constructors run one property setter per field, nested
    messages included; a lockstep tick builds eight messages, so the hot path
    uses these instead.  Every field must be given, with the type the setter
    would have stored (float, int, bool, str, a message, a float64 array for
    a fixed-size double array); the result equals the generated constructor's
    (``test/unit/nodes/test_conversions.py`` checks each builder below against it).
    """
    fields = [f for f in cls.__slots__ if f != "_check_fields"]
    args = ", ".join(f[1:] for f in fields)
    body = "".join(f"    m.{f} = {f[1:]}\n" for f in fields)
    src = f"def build(*, {args}):\n    m = new(cls)\n{body}    m._check_fields = False\n    return m\n"
    scope: dict[str, Any] = {"new": cls.__new__, "cls": cls}
    exec(src, scope)  # noqa: S102 - generated from the message's own slot names
    build = scope["build"]
    build.__doc__ = f"Build a {cls.__name__} from every field (keyword arguments)."
    return build


class _NotFlat(Exception):
    """The type has a field a flat layout cannot hold."""


def _message_class(t: Any) -> Any:
    return getattr(importlib.import_module(".".join(t.namespaces)), t.name)


class FlatCodec:
    """One message type's flat CDR layout (see module doc); build with :func:`codec_for`.

    Attributes:
        Flat: The type's flat form, a named tuple of every value of its CDR in
            wire order (see :meth:`unpack`).
        index: Field name -> its position in the flat form.
        size: Bytes of the type's CDR on the layout.
    """

    def __init__(self, cls: Any, strings: dict[str, str]) -> None:
        self.cls = cls
        self._fmt = ["<", "4s"]
        self._off = 0  # offset in the payload (after the encapsulation header)
        self._names = ["cdr_header"]  # the flat form's field names, in wire order
        self._flat = ["ENC"]  # expressions of the flat values of a message ``m``
        self._defaults: list[Any] = [ENCAPSULATION_LE]  # the flat values of a default message on the layout
        self._checks: list[tuple[int, bytes]] = []  # (offset in the buffer, bytes a string must equal)
        self._fixed: list[tuple[int, int, bytes]] = []  # (size index, bytes index, bytes) of each fixed string
        self._builders: dict[str, Any] = {}
        self._scope: dict[str, Any] = {"np": np, "ENC": ENCAPSULATION_LE}
        self._strings = strings
        build = self._walk(cls, "m", "", cls())
        self.size = 4 + self._off
        self._struct = struct.Struct("".join(self._fmt))
        self.Flat = namedtuple(f"Flat{cls.__name__}", self._names)  # type: ignore[misc]  # fields known at run time only
        self.index = {name: i for i, name in enumerate(self._names)}
        packable = " and ".join(f"v[{i}] == {len(b)} and v[{j}] == {b!r}" for i, j, b in self._fixed) or "True"
        src = (f"def flatten(m):\n    return new(Flat, ({', '.join(self._flat)},))\n"
               f"def to_message(v):\n    return {build}\n"
               f"def pack(v):\n    if {packable}:\n        return S.pack(*v)\n    return None\n"
               f"def on_layout(raw):\n    return len(raw) >= {self.size} and raw[:4] == ENC"
               + "".join(f" and raw[{o}:{o + len(b)}] == {b!r}" for o, b in self._checks) + "\n")
        self._scope.update(S=self._struct, Flat=self.Flat, new=tuple.__new__)
        exec(src, self._scope)  # noqa: S102 - generated from the message type's own introspection
        self.flatten: Callable[[Any], Any] = self._scope["flatten"]
        self.to_message: Callable[[Any], Any] = self._scope["to_message"]
        self._pack_fast = self._scope["pack"]
        self.on_layout: Callable[[bytes], bool] = self._scope["on_layout"]
        """True if a buffer is this type's CDR on the flat layout (little endian, the graph's strings, long enough)."""

    # ------------------------------------------------------------------ layout
    def _pad(self, align: int) -> None:
        pad = -self._off % align
        if pad:
            self._fmt.append(f"{pad}x")
            self._off += pad

    def _walk(self, cls: Any, expr: str, path: str, default: Any) -> str:
        """Lay out ``cls`` (a message ``expr``; ``default`` its default); return the expression rebuilding it from ``v``."""
        # deferred: ROS's IDL parser; the launcher's monitor imports this module ROS-free
        from rosidl_parser.definition import AbstractString, Array, BasicType, NamespacedType

        names = [s for s in cls.__slots__ if s != "_check_fields"]
        parts = []
        for slot, t in zip(names, cls.SLOT_TYPES, strict=True):
            name = slot[1:]
            p = f"{path}.{name}" if path else name
            e = f"{expr}.{slot}"  # the slot itself: the generated property costs a Python call per field
            flat = p.replace(".", "_")
            n = len(self._names)
            value = getattr(default, slot)
            if isinstance(t, BasicType):
                code, size = _PRIMITIVES[t.typename]
                self._pad(size)
                self._fmt.append(code)
                self._off += size
                self._names.append(flat)
                self._flat.append(e)
                self._defaults.append(value)
                parts.append(f"{name}=v[{n}]")
            elif isinstance(t, Array) and isinstance(t.value_type, BasicType) and t.value_type.typename == "double":
                self._pad(8)
                self._fmt.append(f"{t.size}d")
                self._off += 8 * t.size
                self._names += [f"{flat}_{i}" for i in range(t.size)]
                self._flat.append(f"*{e}")
                self._defaults += [float(x) for x in value]
                parts.append(f"{name}=np.array(v[{n}:{n + t.size}])")
            elif isinstance(t, AbstractString):
                if p not in self._strings:
                    raise _NotFlat(f"{cls.__name__}.{name}: a string the graph does not fix")
                raw = self._strings[p].encode() + b"\0"
                self._pad(4)
                self._fmt.append(f"I{len(raw)}s")
                self._checks.append((4 + self._off, struct.pack("<I", len(raw)) + raw))
                self._fixed.append((n, n + 1, raw))
                self._off += 4 + len(raw)
                self._names += [f"{flat}_size", f"{flat}_cdr"]
                self._flat += [f"len({e}.encode()) + 1", f"{e}.encode() + b'\\0'"]
                self._defaults += [len(raw), raw]
                parts.append(f"{name}=v[{n + 1}][:-1].decode()")
            elif isinstance(t, NamespacedType):
                parts.append(f"{name}={self._walk(_message_class(t), e, p, value)}")
            else:
                raise _NotFlat(f"{cls.__name__}.{name}: {type(t).__name__}")
        key = f"B{len(self._builders)}"
        self._builders[key] = self._scope[key] = message_builder(cls)
        return f"{key}({', '.join(parts)})"

    # ------------------------------------------------------------------ use
    def unpack(self, raw: bytes) -> Any:
        """The flat form of a received CDR buffer: one struct call on the layout, else rclpy's deserializer.

        Raises:
            Exception: rclpy's error for bytes that are not this type's CDR.
        """
        if self.on_layout(raw):
            return tuple.__new__(self.Flat, self._struct.unpack_from(raw))
        from rclpy.serialization import deserialize_message  # deferred: rclpy (the monitor imports this module ROS-free)

        return self.flatten(deserialize_message(raw, self.cls))

    def pack(self, flat: Any) -> bytes:
        """The CDR of a flat form, as rclpy's ``serialize_message`` writes it."""
        raw = self._pack_fast(flat)
        if raw is not None:
            return raw
        from rclpy.serialization import serialize_message  # deferred: rclpy (the monitor imports this module ROS-free)

        return serialize_message(self.to_message(flat))

    def maker(self, *paths: str) -> Callable[..., Any]:
        """A builder of the flat form from the values of ``paths`` (positional, in that order).

        Every other value is the type's default, and every string the graph's
        (e.g. ``maker("header.stamp.sec", "header.stamp.nanosec", "vector.x", "vector.z")``
        builds a Vector3Stamped in frame ``vessel`` with ``vector.y = 0``).  A
        path names a primitive field (dots between nested messages) or one
        element of an array (``pose.covariance_35``).

        Raises:
            KeyError: a path the type does not have, or a string.
        """
        idx = {}
        for i, p in enumerate(paths):
            flat = p.replace(".", "_")
            if flat not in self.index or flat.endswith(("_size", "_cdr")) or flat == "cdr_header":
                raise KeyError(f"{self.cls.__name__} has no primitive field {p!r}")
            idx[self.index[flat]] = f"a{i}"
        values = [idx.get(j, f"D[{j}]") for j in range(len(self._names))]
        args = ", ".join(f"a{i}" for i in range(len(paths)))
        scope: dict[str, Any] = {"new": tuple.__new__, "Flat": self.Flat, "D": tuple(self._defaults)}
        exec(f"def make({args}):\n    return new(Flat, ({', '.join(values)},))\n", scope)  # noqa: S102 - from the type's own fields
        return scope["make"]


@cache
def _codec(cls: Any, strings: tuple[tuple[str, str], ...]) -> FlatCodec | None:
    try:
        return FlatCodec(cls, dict(strings))
    except _NotFlat:
        return None


def codec_for(cls: Any, strings: dict[str, str]) -> FlatCodec | None:
    """The flat codec of message type ``cls``, its string fields fixed to ``strings`` (path -> value); None if it has none.

    ``strings`` may name paths the type does not have; a string field of the
    type that it does not name makes the type not flat.
    """
    return _codec(cls, tuple(sorted(strings.items())))
