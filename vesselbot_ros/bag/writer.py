"""Write rosbag2 bags (metadata.yaml version 9 + MCAP) with rosbags, never by hand.

:class:`BagWriter` wraps :class:`rosbags.rosbag2.Writer` as a context manager:

* the storage is MCAP with ``ros2msg`` schemas that embed the full message
  definitions (custom ``vesselbot_msgs`` types included, registered from the
  installed ``.msg`` files), ``cdr`` channels and the offered QoS per channel:
  this is what Foxglove and ``ros2 bag info/play`` read;
* the run's metadata (scenario, seed, mode, config, versions, command) goes
  into the rosbag2 ``custom_data`` under :data:`RUN_METADATA_KEY` (so it is in
  ``metadata.yaml`` and in the MCAP's ``rosbag2`` metadata record), and into
  the side file ``run_metadata.json`` written at open, so that ``bag repair``
  can restore it after a hard kill;
* the bag directory may already exist (the launcher puts its node logs beside it, in
  ``DIR.logs``), but an existing ``metadata.yaml`` or ``*.mcap`` is never
  overwritten;
* log times are integer ns and strictly increasing (ties are broken by +1 ns)
  so that every reader (rosbags, mcap, Foxglove) orders the messages exactly as
  they were received;
* :meth:`BagWriter.flush` closes the pending MCAP chunk and flushes it to the
  OS: after a hard kill the MCAP is readable up to the last closed chunk.
  rosbags closes a chunk by itself once it holds 1 MiB; the recorder also
  flushes on a wall-clock period;
* the bag is what ``ros2 bag record -s mcap`` writes on Jazzy (checked against
  rosbag2's ``mcap_storage.cpp``, ``qos.cpp`` and mcap's writer):
  ``ros_distro: jazzy``; infinite QoS durations as rmw's
  ``RMW_DURATION_INFINITE`` (9223372036 s, 854775807 ns); every MCAP channel
  carries ``offered_qos_profiles`` *and* ``topic_type_hash`` in its metadata,
  so a bag read from the MCAP alone keeps its type hashes; every chunk carries
  the CRC32 of its records and the footer the CRC32 of the summary section;
* chunk compression follows rosbag2's MCAP storage presets on Jazzy
  (``ros2 bag record --storage-preset-profile``, :data:`COMPRESSION_PRESETS`):
  ``zstd_fast`` (zstd at libzstd's fastest level, ZSTD_minCLevel, 768 KiB
  chunks, no chunk CRC) and ``zstd_small`` (zstd at ZSTD_maxCLevel, 4 MiB
  chunks, chunk CRC).  The bag stays indexed (chunk indexes, message
  indexes, statistics) and ``metadata.yaml`` says what rosbag2 says for a
  storage preset: ``compression_format`` and ``compression_mode`` empty (the
  compression is inside the MCAP chunks, which every MCAP reader undoes).

Example::

    truth = graph_spec.topic("truth")
    with BagWriter(out_dir, run_metadata={"scenario": "small_artery", "seed": 1}) as bag:
        conn = bag.add_topic(truth.name, truth.msgtype)
        bag.write(conn, cdr_bytes, t_ns)
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import struct
import sys
from binascii import crc32
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import Any

from rosbags.interfaces import Connection, Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.rosbag2 import storage_mcap as _mcap
from rosbags.rosbag2.storage_mcap import McapWriter
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from vesselbot_ros.atomic_io import failure_reason, probe_dir, write_text
from vesselbot_ros.errors import BagError

__all__ = [
    "BagWriter",
    "RUN_METADATA_KEY",
    "RUN_METADATA_FILE",
    "MIN_FREE_BYTES",
    "make_typestore",
    "check_output_dir",
    "qos_from_spec",
    "write_failed_message",
    "COMPRESSION_PRESETS",
    "McapPreset",
]

RUN_METADATA_KEY = "vesselbot.run"
RUN_METADATA_FILE = "run_metadata.json"
# A 60 s run at 1 kHz writes about 120 MB; refuse to start below this.
MIN_FREE_BYTES = 256 * 2**20
ROS_DISTRO = "jazzy"
# rmw's RMW_DURATION_INFINITE (INT64_MAX ns) as (sec, nsec): what Jazzy writes for "infinite"
RMW_DURATION_INFINITE = (9223372036, 854775807)

_CUSTOM_PACKAGE = "vesselbot_msgs"


@dataclass(frozen=True)
class McapPreset:
    """How MCAP chunks are written (rosbag2's ``SetOptionsForPreset`` in ``mcap_storage.cpp``, Jazzy).

    Attributes:
        compression: Chunk compression (``""`` or ``"zstd"``).
        level: ``"min"`` / ``"max"``: libzstd's ZSTD_minCLevel / ZSTD_maxCLevel
            (mcap's ``CompressionLevel::Fastest`` / ``Slowest``); None: no compression.
        chunk_bytes: A chunk is closed once its records exceed this size.
        chunk_crc: Whether chunks carry the CRC32 of their uncompressed records.
    """

    compression: str
    level: str | None
    chunk_bytes: int
    chunk_crc: bool


#: ``--compression`` presets: ``none`` is this project's uncompressed bag (rosbags' 1 MiB chunks, with CRCs);
#: the others are rosbag2's MCAP storage preset profiles on Jazzy (mcap's default chunk size is 768 KiB).
COMPRESSION_PRESETS: dict[str, McapPreset] = {
    "none": McapPreset("", None, 2**20, True),
    "zstd_fast": McapPreset("zstd", "min", 768 * 1024, False),
    "zstd_small": McapPreset("zstd", "max", 4 * 1024 * 1024, True),
}


def _zstd_compressor(level: str) -> Any:
    """``bytes -> bytes`` zstd at libzstd's minimum or maximum level (the library rosbags reads with)."""
    # deferred: an optional module (only the zstd presets need it), named differently before Python 3.14
    try:
        from compression import zstd  # type: ignore[import-not-found]  # Python >= 3.14
    except ImportError:
        from backports import zstd
    lo, hi = zstd.CompressionParameter.compression_level.bounds()
    lvl = lo if level == "min" else hi
    return lambda data: zstd.compress(data, level=lvl)


def compression_preset(name: str) -> McapPreset:
    """The preset called ``name``; BagError naming the valid ones otherwise."""
    try:
        return COMPRESSION_PRESETS[name]
    except KeyError:
        raise BagError(f"unknown compression {name!r}; valid: {', '.join(COMPRESSION_PRESETS)}") from None


def _msg_dirs(package: str) -> list[Path]:
    """Folders where ``package``'s ``.msg`` files may be installed (venv first)."""
    dirs = [Path(sys.prefix) / "share" / package / "msg"]
    for entry in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if entry:
            dirs.append(Path(entry) / "share" / package / "msg")
    if package == _CUSTOM_PACKAGE:
        dirs.append(Path(__file__).resolve().parents[2] / "msg_defs" / "msg")
    return [d for d in dirs if d.is_dir()]


def _register_package(ts: Typestore, package: str) -> bool:
    """Register every ``.msg`` of ``package`` found on disk; True if any was found."""
    for folder in _msg_dirs(package):
        types: dict[str, Any] = {}
        for f in sorted(folder.glob("*.msg")):
            types.update(get_types_from_msg(f.read_text(encoding="utf-8"), f"{package}/msg/{f.stem}"))
        if types:
            ts.register(types)
            return True
    return False


def make_typestore(extra_types: Sequence[str] = ()) -> Typestore:
    """A ROS 2 Jazzy typestore with ``vesselbot_msgs`` (and the packages of ``extra_types``).

    Args:
        extra_types: Message types (``pkg/msg/Name``) that must be known; the
            ``.msg`` files of their packages are registered when missing.

    Raises:
        BagError: if a type is neither standard nor installed as a ``.msg`` file.
    """
    ts = get_typestore(Stores.ROS2_JAZZY)
    if not _register_package(ts, _CUSTOM_PACKAGE):
        raise BagError(f"cannot find the {_CUSTOM_PACKAGE} .msg files under {sys.prefix}/share; run `make bootstrap`")
    for msgtype in extra_types:
        if msgtype not in ts.fielddefs:
            _register_package(ts, msgtype.split("/", 1)[0])
        if msgtype not in ts.fielddefs:
            raise BagError(f"unknown message type {msgtype!r}: not a ROS 2 Jazzy type and no .msg file installed")
    return ts


def qos_from_spec(durability_transient_local: bool, depth: int) -> Qos:
    """The offered QoS (reliable, keep last ``depth``) recorded with a channel.

    Args:
        durability_transient_local: True for latched topics.
        depth: History depth.
    """
    never = QosTime(*RMW_DURATION_INFINITE)  # as ros2 bag on Jazzy writes an infinite duration
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=depth,
        reliability=QosReliability.RELIABLE,
        durability=QosDurability.TRANSIENT_LOCAL if durability_transient_local else QosDurability.VOLATILE,
        deadline=never,
        lifespan=never,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=never,
        avoid_ros_namespace_conventions=False,
    )


def check_output_dir(path: str | os.PathLike[str], min_free_bytes: int = MIN_FREE_BYTES) -> Path:
    """Check that a bag can be written at ``path`` before anything is recorded.

    In this order: the free space of its file system (``min_free_bytes``;
    ``vesselbot run`` passes 0, its one rule being
    :func:`vesselbot_ros.sim.scenario.check_resources`), the directory is
    created if needed (it may exist, e.g. with a ``logs/`` folder), it must
    not already hold a bag, and a probe file must be writable there (the
    probe is removed, on failure too).  A refused check removes the folders
    it created.

    Returns:
        The resolved directory.

    Raises:
        BagError: naming the path and the problem.
    """
    out = Path(path).expanduser().resolve()
    base = out
    while not base.exists() and base != base.parent:
        base = base.parent
    if min_free_bytes > 0 and base.is_dir():
        free = shutil.disk_usage(base).free
        if free < min_free_bytes:
            raise BagError(f"only {free / 2**20:.0f} MiB free under {base}; recording to {out} needs at least "
                           f"{min_free_bytes / 2**20:.0f} MiB; nothing was created")
    created = [p for p in (out, *out.parents) if not p.exists()]

    def undo() -> None:
        for p in created:  # deepest first
            with contextlib.suppress(OSError):
                p.rmdir()

    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        undo()
        raise BagError(f"cannot create bag directory {out}: {exc.strerror or exc}") from None
    if not out.is_dir():
        raise BagError(f"bag path {out} exists and is not a directory")
    existing = [p.name for p in (out / "metadata.yaml", *out.glob("*.mcap")) if p.exists()]
    if existing:
        raise BagError(f"{out} already holds a bag ({', '.join(existing)}); not overwriting")
    try:
        probe_dir(out)
    except OSError as exc:
        undo()
        raise BagError(f"bag directory {out} is not writable: {exc.strerror or exc}") from None
    return out


def write_failed_message(bag_dir: str | os.PathLike[str], exc: OSError) -> str:
    """One line for a recording that cannot be written any more (a full disk, a quota, a file size limit)."""
    full = exc.errno in (28, 122, 27)  # ENOSPC, EDQUOT, EFBIG
    why = "the disk is full" if full else "a write failed"
    return (f"{why} ({exc.strerror or exc}) while recording {bag_dir}; recording stopped. Every message "
            f"flushed before is in its MCAP: free some space, then run `vesselbot bag repair {bag_dir}`")


class JazzyMcapWriter(McapWriter):
    """rosbags' MCAP storage, writing what rosbag2's MCAP plugin on Jazzy writes.

    Differences from rosbags (all in rosbag2 Jazzy's ``mcap_storage.cpp`` and
    mcap's ``McapWriter`` defaults): channel metadata holds ``topic_type_hash``
    next to ``offered_qos_profiles``; chunks carry the CRC32 of their
    uncompressed records; the footer carries the summary CRC; the rosbag2
    metadata record says ``ros_distro: jazzy``.  Chunk size, compression
    and chunk CRC follow a :class:`McapPreset`.
    """

    def __init__(self, path: Path, compression: Any, preset: McapPreset = COMPRESSION_PRESETS["none"]) -> None:
        super().__init__(path, compression)
        self.preset = preset
        if preset.compression:
            self.compression = preset.compression
            self.compressor = _zstd_compressor(preset.level or "min")

    def write(self, connection: Connection, timestamp: int, data: bytes | memoryview) -> None:
        # rosbags' write() with the preset's chunk size instead of its fixed 1 MiB
        self.message_start_time = min(timestamp, self.message_start_time)
        self.message_end_time = max(timestamp, self.message_end_time)
        self.channel_stats[connection.id] += 1
        chunk = self.chunk
        chunk.message_start_time = min(timestamp, chunk.message_start_time)
        chunk.message_end_time = max(timestamp, chunk.message_end_time)
        chunk.msgs[connection.id].append((timestamp, chunk.bio.tell()))
        rec = BytesIO()
        _mcap.write_uint16(rec, connection.id)
        _mcap.write_uint32(rec, 0)
        _mcap.write_uint64(rec, timestamp)
        _mcap.write_uint64(rec, timestamp)
        rec.write(data)
        _mcap.write_record(chunk.bio, 0x05, rec)
        if chunk.bio.tell() > self.preset.chunk_bytes:
            self.close_chunk()

    def add_connection(self, connection: Connection, offered_qos_profiles: str) -> None:
        super().add_connection(connection, offered_qos_profiles)
        meta = BytesIO()
        _mcap.write_string(meta, "offered_qos_profiles")
        _mcap.write_string(meta, offered_qos_profiles)
        _mcap.write_string(meta, "topic_type_hash")
        _mcap.write_string(meta, connection.digest)
        self.channels[-1] = self.channels[-1]._replace(metadata=meta.getvalue())
        # super() wrote the channel record into the chunk with the old metadata: rewrite it
        body = self.chunk.bio.getvalue()
        old = BytesIO()
        _mcap.write_channel(old, self.channels[-1]._replace(metadata=_qos_only(offered_qos_profiles)), self.schemas)
        assert body.endswith(old.getvalue())
        self.chunk.bio.seek(len(body) - len(old.getvalue()))
        self.chunk.bio.truncate()
        _mcap.write_channel(self.chunk.bio, self.channels[-1], self.schemas)

    def close_chunk(self) -> None:
        start = self.bio.tell()
        crc = crc32(self.chunk.bio.getvalue()) if self.preset.chunk_crc else 0
        super().close_chunk()
        # the Chunk record: opcode (1), length (8), start, end, uncompressed size (8 each), then the CRC
        end = self.bio.tell()
        self.bio.seek(start + 1 + 8 + 24)
        self.bio.write(struct.pack("<I", crc))
        self.bio.seek(end)

    def close(self, version: int, metadata: str) -> None:
        metadata = _DISTRO_LINE.sub(f"ros_distro: {ROS_DISTRO}", metadata)
        super().close(version, metadata)
        write_summary_crc(self.path)


def _qos_only(offered_qos_profiles: str) -> bytes:
    meta = BytesIO()
    _mcap.write_string(meta, "offered_qos_profiles")
    _mcap.write_string(meta, offered_qos_profiles)
    return meta.getvalue()


_DISTRO_LINE = re.compile(r"^ros_distro: rosbags$", re.M)
_FOOTER_LEN = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, summary_crc


def write_summary_crc(path: Path) -> None:
    """Fill in the footer's summary CRC of a complete MCAP file (0 = no summary)."""
    with path.open("r+b") as fh:
        fh.seek(0, os.SEEK_END)
        size = fh.tell()
        footer = size - 8 - _FOOTER_LEN
        fh.seek(footer)
        rec = fh.read(_FOOTER_LEN)
        if rec[0] != 0x02:
            raise BagError(f"{path}: no MCAP footer where one was just written")
        summary_start = struct.unpack_from("<Q", rec, 9)[0]
        if summary_start == 0:
            return
        fh.seek(summary_start)
        crc = crc32(fh.read(footer + _FOOTER_LEN - 4 - summary_start))
        fh.seek(footer + _FOOTER_LEN - 4)
        fh.write(struct.pack("<I", crc))


class _DirWriter(Writer):
    """rosbags' Writer, except that the bag directory may already exist (never the bag files)."""

    def __init__(self, path: Path, preset: McapPreset = COMPRESSION_PRESETS["none"]) -> None:
        # rosbags refuses existing directories in __init__ and open(); the check
        # for existing bag files is done here instead, and McapWriter opens 'xb'.
        super().__init__(path / f".unused-{os.getpid()}-{id(self)}", version=9, storage_plugin=StoragePlugin.MCAP)
        self.path = path
        self.preset = preset
        self.metapath = path / "metadata.yaml"

    def open(self) -> None:
        self.path.mkdir(mode=0o755, parents=True, exist_ok=True)
        if self.metapath.exists():
            raise WriterError(f"{self.metapath} exists already, not overwriting.")
        self.storage = JazzyMcapWriter(self.path, self.compression_mode, self.preset)

    def close(self) -> None:
        try:
            super().close()  # rosbags writes metadata.yaml.tmp, then renames it
        finally:
            with contextlib.suppress(OSError):
                self.metapath.with_suffix(".yaml.tmp").unlink(missing_ok=True)  # left by a write that failed
        text = self.metapath.read_text(encoding="utf-8")
        write_text(self.metapath, re.sub(r"^(\s+)ros_distro: rosbags$", rf"\1ros_distro: {ROS_DISTRO}", text, flags=re.M))


class BagWriter:
    """A rosbag2 (version 9, MCAP) bag being written; use as a context manager.

    Args:
        path: The bag directory (created; may exist but must not hold a bag).
        run_metadata: JSON-serialisable description of the run (scenario,
            seed, mode, config, versions, command); stored in ``custom_data``.
        typestore: Typestore used for the embedded definitions and type
            hashes (default: :func:`make_typestore`).
        compression: A key of :data:`COMPRESSION_PRESETS` (``none``,
            ``zstd_fast``, ``zstd_small``).

    Raises:
        BagError: if the directory cannot hold a new bag.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        run_metadata: Mapping[str, Any] | None = None,
        typestore: Typestore | None = None,
        compression: str = "none",
    ) -> None:
        self.path = Path(path)
        self.compression = compression
        self.preset = compression_preset(compression)
        self.run_metadata = dict(run_metadata or {})
        try:
            self._run_json = json.dumps(self.run_metadata, sort_keys=True)
        except (TypeError, ValueError) as exc:
            raise BagError(f"run metadata is not JSON-serialisable: {exc}") from None
        self.typestore = typestore if typestore is not None else make_typestore()
        self._writer: _DirWriter | None = None
        self._finished = False
        self._last_ns = -1
        self.connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}

    # -- lifecycle ---------------------------------------------------------
    def open(self) -> BagWriter:
        """Create the bag files (idempotent while open)."""
        if self._writer is not None:
            return self
        if self._finished:
            raise BagError(f"bag {self.path} is already finished")
        writer = _DirWriter(self.path, self.preset)
        writer.set_custom_data(RUN_METADATA_KEY, self._run_json)
        try:
            writer.open()
        except (WriterError, OSError) as exc:
            raise BagError(f"cannot open bag {self.path}: {exc}") from None
        try:
            write_text(self.path / RUN_METADATA_FILE, self._run_json + "\n")
        except OSError as exc:  # an OutputError (the file is not left half-written)
            with contextlib.suppress(OSError):
                writer.storage.abort()  # type: ignore[union-attr]  # set by writer.open()
            raise BagError(f"cannot open bag {self.path}: cannot write {RUN_METADATA_FILE} "
                           f"({failure_reason(exc)})") from None
        self._writer = writer
        return self

    def finish(self) -> None:
        """Write the MCAP summary and ``metadata.yaml``; safe to call twice."""
        writer, self._writer = self._writer, None
        if writer is None:
            return
        self._finished = True
        try:
            writer.close()
        except OSError as exc:
            raise BagError(f"could not finalise bag {self.path}: {exc}") from None

    def abort(self) -> None:
        """Stop writing without a summary (after a write failed, e.g. on a full disk).

        The MCAP is left as a hard kill leaves it: complete up to the last
        closed chunk, repairable with ``vesselbot bag repair``.  Safe to call
        twice and after :meth:`finish`.
        """
        writer, self._writer = self._writer, None
        self._finished = True
        if writer is None or writer.storage is None:
            return
        # OSError: the buffered tail cannot be written either; what is on disk stays
        with contextlib.suppress(OSError):
            writer.storage.abort()

    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.finish()

    @property
    def is_open(self) -> bool:
        """True between :meth:`open` and :meth:`finish`."""
        return self._writer is not None

    @property
    def mcap_path(self) -> Path:
        """The MCAP file of the bag."""
        return self.path / f"{self.path.name}.mcap"

    # -- writing -----------------------------------------------------------
    def add_topic(
        self, topic: str, msgtype: str, *, latched: bool = False, depth: int = 100
    ) -> Connection:
        """Declare a topic (channel) with its embedded definition and offered QoS.

        Args:
            topic: Absolute topic name.
            msgtype: ROS type ``pkg/msg/Name``.
            latched: Transient-local durability (``vessel_markers``, paths).
            depth: History depth of the offered QoS.

        Raises:
            BagError: if the type is unknown or the topic was already added.
        """
        writer = self._require_open()
        if topic in self.connections:
            raise BagError(f"topic {topic} was already added to bag {self.path}")
        if msgtype not in self.typestore.fielddefs:
            self.typestore = _extend(self.typestore, msgtype)
        conn = writer.add_connection(
            topic, msgtype, typestore=self.typestore, offered_qos_profiles=[qos_from_spec(latched, depth)]
        )
        self.connections[topic] = conn
        self.counts[topic] = 0
        return conn

    def write(self, conn: Connection, data: bytes | memoryview, t_ns: int) -> int:
        """Write one serialized (CDR) message; return the log time actually used (ns).

        Args:
            conn: A connection from :meth:`add_topic`.
            data: The CDR bytes exactly as published.
            t_ns: Receive time (ns); raised by 1 ns over the previous one if
                needed, so log times are strictly increasing.
        """
        writer = self._require_open()
        t = int(t_ns)
        if t <= self._last_ns:
            t = self._last_ns + 1
        self._last_ns = t
        writer.write(conn, t, data)
        self.counts[conn.topic] += 1
        return t

    def flush(self, fsync: bool = False) -> None:
        """Close the pending MCAP chunk (if it holds messages) and flush it to the OS.

        Args:
            fsync: Also ask the OS to put it on disk (survives a power cut).
        """
        writer = self._require_open()
        storage = writer.storage
        assert isinstance(storage, McapWriter)
        if storage.chunk.msgs:
            storage.close_chunk()
        storage.bio.flush()
        if fsync:
            os.fsync(storage.bio.fileno())

    def pending_bytes(self) -> int:
        """Bytes in the chunk not yet written to the file."""
        writer = self._require_open()
        storage = writer.storage
        assert isinstance(storage, McapWriter)
        return storage.chunk.bio.tell()

    def _require_open(self) -> _DirWriter:
        if self._writer is None:
            raise BagError(f"bag {self.path} is not open")
        return self._writer


def _extend(ts: Typestore, msgtype: str) -> Typestore:
    pkg = msgtype.split("/", 1)[0]
    if not _register_package(ts, pkg) or msgtype not in ts.fielddefs:
        raise BagError(f"unknown message type {msgtype!r}: not a ROS 2 Jazzy type and no .msg file installed")
    return ts
