"""Rebuild a valid bag from the MCAP of a recorder that was killed hard.

A recorder killed with SIGKILL (or a power cut) leaves an MCAP with no
summary and no footer, possibly ending in a half-written chunk, and no
``metadata.yaml``.  :func:`repair_bag` streams the MCAP with ``mcap``'s
:class:`~mcap.stream_reader.StreamReader` (which needs no footer), keeps every
schema, channel and message up to the last complete chunk, and writes them
into a fresh, complete rosbag2 bag (same topics, types, embedded definitions,
offered QoS, log times; run metadata from ``run_metadata.json``) with rosbags.
The damaged file is kept next to it as ``<name>.mcap.damaged``.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

from vesselbot_ros.errors import BagError

__all__ = ["RepairResult", "repair_bag"]


@dataclass(frozen=True)
class RepairResult:
    """What :func:`repair_bag` did.

    Attributes:
        path: The bag directory.
        repaired: False if the bag was already valid (nothing was changed).
        message_count: Messages in the repaired bag.
        counts: Messages per topic.
        dropped_bytes: Bytes at the end of the damaged MCAP that could not be
            read (an incomplete chunk).
        damaged_path: Where the original MCAP was kept (None if not repaired).
    """

    path: Path
    repaired: bool
    message_count: int
    counts: dict[str, int]
    dropped_bytes: int
    damaged_path: Path | None


def _qos_list(metadata: dict[str, str]) -> list:
    from rosbags.rosbag2.metadata import parse_qos

    text = metadata.get("offered_qos_profiles", "")
    if not text:
        return []
    try:
        import yaml

        return parse_qos(yaml.safe_load(text) or [])
    except Exception:  # noqa: BLE001 - keep the data even if the QoS text is odd
        return []


def repair_bag(path: str | Path, force: bool = False) -> RepairResult:
    """Rebuild ``metadata.yaml`` (and a complete MCAP) of a bag directory.

    Args:
        path: The bag directory.
        force: Rebuild even if the bag already validates.

    Raises:
        BagError: if there is no MCAP, it is not an MCAP, or nothing in it
            can be recovered.
    """
    from mcap.records import Channel, Chunk, Message, Schema
    from mcap.stream_reader import StreamReader, breakup_chunk
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from vesselbot_ros.bag.reader import MCAP_MAGIC, open_bag
    from vesselbot_ros.bag.writer import RUN_METADATA_FILE, RUN_METADATA_KEY

    bag_dir = Path(path).expanduser().resolve()
    if not bag_dir.is_dir():
        raise BagError(f"bag directory {bag_dir} does not exist")
    if not force and (bag_dir / "metadata.yaml").exists():
        try:
            info = open_bag(bag_dir)
        except BagError:
            pass
        else:
            if info.consistent:
                counts = {t.name: t.count for t in info.topics}
                return RepairResult(bag_dir, False, info.message_count, counts, 0, None)
    mcaps = sorted(bag_dir.glob("*.mcap"))
    if not mcaps:
        raise BagError(f"bag {bag_dir}: no .mcap file to repair from")
    if len(mcaps) > 1:
        raise BagError(f"bag {bag_dir}: {len(mcaps)} .mcap files; repair handles one ({[m.name for m in mcaps]})")
    src = mcaps[0]
    with src.open("rb") as fh:
        if fh.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise BagError(f"bag {bag_dir}: {src.name} is not an MCAP file (bad magic); nothing can be recovered")

    run_json = None
    if (bag_dir / RUN_METADATA_FILE).is_file():
        run_json = (bag_dir / RUN_METADATA_FILE).read_text(encoding="utf-8").strip()

    work = bag_dir / ".repair"
    if work.exists():
        shutil.rmtree(work)
    tmp_bag = work / bag_dir.name
    size = src.stat().st_size
    good_end = len(MCAP_MAGIC)
    schemas: dict[int, Schema] = {}
    conns: dict[int, object] = {}
    counts: dict[str, int] = {}
    ts = get_typestore(Stores.ROS2_JAZZY)
    writer = Writer(tmp_bag, version=9, storage_plugin=StoragePlugin.MCAP)
    if run_json:
        writer.set_custom_data(RUN_METADATA_KEY, run_json)
    writer.open()
    last_t = -1

    def handle(rec: object) -> None:
        nonlocal last_t
        if isinstance(rec, Schema):
            schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            if rec.id in conns:
                return
            schema = schemas.get(rec.schema_id)
            if schema is None:
                raise BagError(f"channel {rec.topic} refers to unknown schema {rec.schema_id}")
            text = schema.data.decode("utf-8")
            if schema.name not in ts.fielddefs:
                ts.register(get_types_from_msg(text, schema.name))
            conns[rec.id] = writer.add_connection(
                rec.topic, schema.name, msgdef=text, rihs01=ts.hash_rihs01(schema.name),
                serialization_format=rec.message_encoding, offered_qos_profiles=_qos_list(dict(rec.metadata)),
            )
            counts.setdefault(rec.topic, 0)
        elif isinstance(rec, Message):
            conn = conns.get(rec.channel_id)
            if conn is None:
                return  # a message before its channel is invalid MCAP; nothing to attach it to
            writer.write(conn, rec.log_time, rec.data)  # type: ignore[arg-type]
            counts[conn.topic] += 1  # type: ignore[attr-defined]

    try:
        with src.open("rb") as fh:
            reader = StreamReader(fh, emit_chunks=True, record_size_limit=size)
            records = reader.records
            while True:
                try:
                    rec = next(records)
                except StopIteration:
                    break
                except Exception:  # noqa: BLE001 - EndOfFile, struct.error, ... on a cut record
                    break  # truncated or garbage: keep what was read so far
                if isinstance(rec, Chunk):
                    if rec.compression == "" and len(rec.data) != rec.uncompressed_size:
                        break  # a chunk cut short by the kill
                    try:
                        inner = breakup_chunk(rec, validate_crc=True)
                    except Exception:  # noqa: BLE001 - corrupt chunk: stop at the last good one
                        break
                    for r in inner:
                        handle(r)
                else:
                    handle(rec)
                good_end = reader._stream.count  # bytes consumed up to the end of this record
        total = sum(counts.values())
        if not conns:
            raise BagError(f"bag {bag_dir}: {src.name} holds no complete chunk; nothing can be recovered")
        writer.close()
    except BaseException:
        writer.abort()
        shutil.rmtree(work, ignore_errors=True)
        raise

    damaged = src.with_name(src.name + ".damaged")
    src.replace(damaged)
    new_mcap = tmp_bag / f"{bag_dir.name}.mcap"
    new_mcap.replace(src)
    (tmp_bag / "metadata.yaml").replace(bag_dir / "metadata.yaml")
    shutil.rmtree(work, ignore_errors=True)
    return RepairResult(bag_dir, True, total, counts, max(0, size - good_end), damaged)
