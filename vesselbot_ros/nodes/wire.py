"""Flat CDR codecs: the hot path's messages to and from the wire without rclpy's per-field conversions.

rclpy turns a received message into Python by calling the generated
constructor of every nested message (a PlantState is 17 of them), and a
published one back field by field; between processes that cost more than the
delivery itself (``bench/bench_graph.py``: the graph's own topology with no
code per message took 1.2-1.4x the bare chain, 0.6x when the same bytes travel
raw).  A :class:`FlatCodec` does the same job with one ``struct`` call:

* its layout is derived from the message type's rosidl introspection
  (``SLOT_TYPES``): XCDR1 little endian, as rmw_fastrtps writes it, each
  primitive aligned to its size relative to the payload after the 4-byte
  encapsulation header;
* a type qualifies when every field is a primitive, a fixed-size array of
  primitives, a nested message that qualifies, or a string whose value the
  graph fixes (``header.frame_id`` is ``vessel``); :func:`codec_for` returns
  None for the others, which keep rclpy's path;
* :meth:`FlatCodec.decode` returns the same message object rclpy's
  deserializer would (built slot by slot), and :meth:`FlatCodec.encode` the
  same CDR rclpy's serializer would; a message off the layout (another
  frame_id, an empty one, a big-endian sender, a truncated buffer) goes
  through rclpy's own (de)serializer instead, so nothing is rejected here
  that the node would not reject itself.

``test/unit/nodes/test_wire.py`` checks both directions against rclpy's
serializer for every hot-path type, with random values (hypothesis).
"""

from __future__ import annotations

import struct
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
    import importlib

    return getattr(importlib.import_module(".".join(t.namespaces)), t.name)


class FlatCodec:
    """One message type's flat CDR layout (see module doc); build with :func:`codec_for`."""

    def __init__(self, cls: Any, strings: dict[str, str]) -> None:
        self.cls = cls
        self._fmt = ["<"]
        self._off = 0  # offset in the payload (after the encapsulation header)
        self._args: list[str] = []  # pack arguments: accessor expressions or string constants
        self._checks: list[tuple[int, bytes]] = []  # (offset in the buffer, bytes a string must equal)
        self._builders: dict[str, Any] = {}
        self._scope: dict[str, Any] = {"np": np}
        self._n = 0  # unpacked values so far
        self._strings = strings
        self._paths: list[str] = []  # the string fields, fixed to their values
        self._fmt.append("4s")
        self._args.append("ENC")
        self._scope["ENC"] = ENCAPSULATION_LE
        self._n = 1
        build = self._walk(cls, "m", "")
        self.size = 4 + self._off
        self._struct = struct.Struct("".join(self._fmt))
        guard = " and ".join(f"m.{p} == {strings[p]!r}" for p in self._paths) or "True"
        src = (f"def encode(m):\n    if {guard}:\n        return S.pack({', '.join(self._args)})\n    return None\n"
               f"def decode(v):\n    return {build}\n")
        self._scope["S"] = self._struct
        exec(src, self._scope)  # noqa: S102 - generated from the message type's own introspection
        self._encode_fast = self._scope["encode"]
        self._decode_fast = self._scope["decode"]

    # ------------------------------------------------------------------ layout
    def _pad(self, align: int) -> None:
        pad = -self._off % align
        if pad:
            self._fmt.append(f"{pad}x")
            self._off += pad

    def _walk(self, cls: Any, expr: str, path: str) -> str:
        """Lay out ``cls`` (accessed as ``expr`` when encoding); return the expression that rebuilds it."""
        from rosidl_parser.definition import AbstractString, Array, BasicType, NamespacedType

        names = [s for s in cls.__slots__ if s != "_check_fields"]
        parts = []
        for slot, t in zip(names, cls.SLOT_TYPES, strict=True):
            name = slot[1:]
            p = f"{path}.{name}" if path else name
            e = f"{expr}.{name}"
            if isinstance(t, BasicType):
                code, size = _PRIMITIVES[t.typename]
                self._pad(size)
                self._fmt.append(code)
                self._off += size
                self._args.append(e)
                parts.append(f"{name}=v[{self._n}]")
                self._n += 1
            elif isinstance(t, Array) and isinstance(t.value_type, BasicType) and t.value_type.typename == "double":
                self._pad(8)
                self._fmt.append(f"{t.size}d")
                self._off += 8 * t.size
                self._args.append(f"*{e}")
                parts.append(f"{name}=np.array(v[{self._n}:{self._n + t.size}])")
                self._n += t.size
            elif isinstance(t, AbstractString):
                if p not in self._strings:
                    raise _NotFlat(f"{cls.__name__}.{name}: a string the graph does not fix")
                raw = self._strings[p].encode() + b"\0"
                self._pad(4)
                self._fmt.append(f"I{len(raw)}s")
                self._checks.append((4 + self._off, struct.pack("<I", len(raw)) + raw))
                self._off += 4 + len(raw)
                self._args += [str(len(raw)), repr(raw)]
                parts.append(f"{name}={self._strings[p]!r}")
                self._paths.append(p)
                self._n += 2
            elif isinstance(t, NamespacedType):
                parts.append(f"{name}={self._walk(_message_class(t), e, p)}")
            else:
                raise _NotFlat(f"{cls.__name__}.{name}: {type(t).__name__}")
        key = f"B{len(self._builders)}"
        self._builders[key] = self._scope[key] = message_builder(cls)
        return f"{key}({', '.join(parts)})"

    # ------------------------------------------------------------------ use
    def encode(self, msg: Any) -> bytes:
        """The message's CDR, as rclpy's ``serialize_message`` writes it."""
        raw = self._encode_fast(msg)
        if raw is not None:
            return raw  # type: ignore[no-any-return]
        from rclpy.serialization import serialize_message

        return serialize_message(msg)  # type: ignore[no-any-return]

    def decode(self, raw: bytes) -> Any:
        """The message of a received CDR buffer, equal to rclpy's ``deserialize_message``."""
        if len(raw) >= self.size and raw[:4] == ENCAPSULATION_LE and all(
                raw[o:o + len(b)] == b for o, b in self._checks):
            return self._decode_fast(self._struct.unpack_from(raw))
        from rclpy.serialization import deserialize_message

        return deserialize_message(raw, self.cls)


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
