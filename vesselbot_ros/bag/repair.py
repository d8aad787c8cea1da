"""Rebuild a valid bag from the MCAP of a recorder that was killed hard, without ever losing the original.

A recorder killed with SIGKILL (or a power cut, or a full disk) leaves an MCAP
with no summary and no footer, possibly ending in a half-written chunk, and no
``metadata.yaml``.  :func:`repair_bag` streams the MCAP with ``mcap``'s
:class:`~mcap.stream_reader.StreamReader` (which needs no footer), keeps every
schema, channel and message up to the last complete chunk, and writes them
into a fresh, complete rosbag2 bag (same topics, types, embedded definitions,
offered QoS, log times) in the Jazzy format of :mod:`vesselbot_ros.bag.writer`.

What is never lost:

* the original MCAP: when it had to be rewritten it is kept beside the new
  one as ``<name>.mcap.damaged`` (``.damaged.2``, ``.damaged.3``, ... if that
  name is taken: an earlier repair's original is never overwritten); when
  it is complete and intact it is not touched at all and only
  ``metadata.yaml`` is rebuilt;
* a replaced ``metadata.yaml`` is kept as ``metadata.yaml.orig`` (same
  numbering);
* the run's metadata (scenario, seed, config): from ``run_metadata.json``, or
  from the ``rosbag2`` metadata record of the MCAP, or from the old
  ``metadata.yaml`` if it can still be read.

The new ``metadata.yaml`` names the MCAP file as it is on disk, so a bag whose
folder was renamed or copied stays readable.  Nothing is changed until the new
bag is complete: on any error (a full disk included) the work folder is
removed and the bag is left as it was.
"""

from __future__ import annotations

import errno
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from mcap.records import Channel, Chunk, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from rosbags.rosbag2.metadata import parse_qos
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from vesselbot_ros.bag.reader import MCAP_MAGIC, open_bag
from vesselbot_ros.bag.writer import RUN_METADATA_FILE, RUN_METADATA_KEY, _DirWriter
from vesselbot_ros.config import ConfigError, parse_yaml_text
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
            read (an incomplete chunk); 0 for an intact MCAP.
        damaged_path: Where the original MCAP was kept (None if it was not
            rewritten).
        mcap_rewritten: False if the MCAP was intact and only
            ``metadata.yaml`` was rebuilt.
        kept: Every original file kept under a new name.
        run_metadata_from: Where the run metadata came from
            (``run_metadata.json``, ``mcap``, ``metadata.yaml``) or None.
    """

    path: Path
    repaired: bool
    message_count: int
    counts: dict[str, int]
    dropped_bytes: int
    damaged_path: Path | None
    mcap_rewritten: bool = False
    kept: tuple[Path, ...] = field(default_factory=tuple)
    run_metadata_from: str | None = None


def _unused(path: Path, suffix: str = ".damaged") -> Path:
    """``path + suffix``, or ``.damaged.2``, ``.damaged.3``, ... : a name that holds nothing yet."""
    cand = path.with_name(path.name + suffix)
    n = 2
    while cand.exists() or cand.is_symlink():
        cand = path.with_name(f"{path.name}{suffix}.{n}")
        n += 1
    return cand


def _run_json_from_metadata_text(text: str) -> str | None:
    """The run metadata in a rosbag2 metadata YAML text (``custom_data``), or None."""
    try:
        doc = parse_yaml_text(text, source="metadata")
    except ConfigError:
        return None
    if isinstance(doc, dict) and "rosbag2_bagfile_information" in doc:
        doc = doc["rosbag2_bagfile_information"]
    custom = doc.get("custom_data") if isinstance(doc, dict) else None
    raw = custom.get(RUN_METADATA_KEY) if isinstance(custom, dict) else None
    return raw if isinstance(raw, str) and raw.strip() else None


def _qos_list(metadata: dict[str, str]) -> list:
    text = metadata.get("offered_qos_profiles", "")
    if not text:
        return []
    try:
        return parse_qos(yaml.safe_load(text) or [])
    except Exception:  # noqa: BLE001 - keep the data even if the QoS text is odd
        return []


def repair_bag(path: str | Path, force: bool = False) -> RepairResult:
    """Rebuild ``metadata.yaml`` (and, if damaged, a complete MCAP) of a bag directory.

    Args:
        path: The bag directory.
        force: Rebuild even if the bag already validates.

    Raises:
        BagError: if there is no MCAP, it is not an MCAP, nothing in it can be
            recovered, or the disk is full (the bag is then left as it was).
    """
    bag_dir = Path(path).expanduser().resolve()
    if not bag_dir.is_dir():
        raise BagError(f"bag directory {bag_dir} does not exist")
    meta_path = bag_dir / "metadata.yaml"
    if not force and meta_path.exists():
        try:
            info = open_bag(bag_dir)
        except BagError:
            pass
        else:
            if info.consistent:
                counts: dict[str, int] = {t.name: t.count for t in info.topics}
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
    size = src.stat().st_size
    free = shutil.disk_usage(bag_dir).free
    if free < size + 2**20:
        raise BagError(f"bag {bag_dir}: repair needs about {(size + 2**20) / 2**20:.0f} MiB free, only "
                       f"{free / 2**20:.0f} MiB left; nothing was changed: free some space and run "
                       f"`vesselbot bag repair {bag_dir}` again")

    run_json: str | None = None
    run_from: str | None = None
    if (bag_dir / RUN_METADATA_FILE).is_file():
        run_json = (bag_dir / RUN_METADATA_FILE).read_text(encoding="utf-8").strip() or None
        run_from = RUN_METADATA_FILE if run_json else None

    kept: list[Path] = []
    damaged: Path | None = None
    work = bag_dir / f".repair-{os.getpid()}"
    shutil.rmtree(work, ignore_errors=True)
    tmp_bag = work / src.stem  # the new MCAP gets the original's file name
    good_end = len(MCAP_MAGIC)
    complete = False
    schemas: dict[int, Schema] = {}
    conns: dict[int, object] = {}
    counts = {}
    mcap_run_json: list[str] = []
    ts = get_typestore(Stores.ROS2_JAZZY)
    writer = _DirWriter(tmp_bag)

    def handle(rec: object) -> None:
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
            rihs01 = dict(rec.metadata).get("topic_type_hash") or ts.hash_rihs01(schema.name)
            conns[rec.id] = writer.add_connection(
                rec.topic, schema.name, msgdef=text, rihs01=rihs01,
                serialization_format=rec.message_encoding, offered_qos_profiles=_qos_list(dict(rec.metadata)),
            )
            counts.setdefault(rec.topic, 0)
        elif isinstance(rec, Message):
            conn = conns.get(rec.channel_id)
            if conn is None:
                return  # a message before its channel is invalid MCAP; nothing to attach it to
            writer.write(conn, rec.log_time, rec.data)  # type: ignore[arg-type]  # conns holds rosbags Connections
            counts[conn.topic] += 1  # type: ignore[attr-defined]  # (typed object: rosbags has no stubs)
        elif isinstance(rec, Metadata) and rec.name == "rosbag2":
            found = _run_json_from_metadata_text(rec.metadata.get("serialized_metadata", ""))
            if found:
                mcap_run_json.append(found)

    try:
        try:
            writer.open()
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
                    good_end = fh.tell()  # bytes consumed up to the end of this record (the reader reads exactly)
                    if isinstance(rec, Footer):
                        fh.seek(size - len(MCAP_MAGIC))
                        complete = good_end + len(MCAP_MAGIC) == size and fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC
                        if complete:
                            good_end = size
                        break
            if not conns:
                raise BagError(f"bag {bag_dir}: {src.name} holds no complete chunk; nothing can be recovered")
            if run_json is None and mcap_run_json:
                run_json, run_from = mcap_run_json[-1], "mcap"
            if run_json is None and meta_path.is_file():
                try:
                    run_json = _run_json_from_metadata_text(meta_path.read_text(encoding="utf-8"))
                except (OSError, UnicodeDecodeError):
                    run_json = None
                run_from = "metadata.yaml" if run_json else None
            if run_json:
                writer.set_custom_data(RUN_METADATA_KEY, run_json)
            writer.close()
        except BaseException:
            try:
                if writer.storage is not None:
                    writer.storage.abort()
            except OSError:
                pass
            raise
        total = sum(counts.values())

        # Install: renames only (no space needed); every original is kept under a new name.
        if not complete:
            damaged = _unused(src)
            src.replace(damaged)
            kept.append(damaged)
            (tmp_bag / src.name).replace(src)
        if meta_path.exists():
            old_meta = _unused(meta_path, ".orig")
            meta_path.replace(old_meta)
            kept.append(old_meta)
        (tmp_bag / "metadata.yaml").replace(meta_path)
    except OSError as exc:
        state = ("nothing was changed" if not kept
                 else "the originals are kept as " + ", ".join(k.name for k in kept))
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            raise BagError(f"bag {bag_dir}: the disk filled up while repairing ({exc.strerror}); {state}: free "
                           f"some space and run `vesselbot bag repair {bag_dir}` again") from None
        raise BagError(f"bag {bag_dir}: repair failed ({exc.strerror or exc}); {state}") from None
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return RepairResult(bag_dir, True, total, counts, max(0, size - good_end), damaged, not complete, tuple(kept),
                        run_from)
