"""Open, validate and read rosbag2 MCAP bags, with clear errors for broken ones.

* :func:`open_bag` checks a bag directory and returns a :class:`BagInfo`:
  ``metadata.yaml`` present and parseable, the MCAP files present, each with
  its magic at both ends and a readable summary (a file cut short by a hard
  kill has no footer: the error says to run ``vesselbot bag repair``), and
  whether the per-topic counts of ``metadata.yaml`` match the MCAP's
  statistics.  Every failure is a :class:`~vesselbot_ros.errors.BagError`
  naming the path and the problem.
* :func:`iter_messages` yields :class:`BagMessage` (topic, type, log time,
  CDR bytes) in log-time order via rosbags' ``AnyReader``; decoding uses only
  the definitions embedded in the bag.
* :func:`read_timeseries` turns the graph's topics into numpy arrays (the
  input of the report and of ``sim.metrics.compute_metrics``).
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from vesselbot_ros.bag.writer import RUN_METADATA_FILE, RUN_METADATA_KEY
from vesselbot_ros.config import ConfigError, parse_yaml_text
from vesselbot_ros.errors import BagError
from vesselbot_ros.graph_spec import topic
from vesselbot_ros.resources import require_fits

__all__ = [
    "TopicInfo",
    "BagInfo",
    "BagMessage",
    "open_bag",
    "iter_messages",
    "read_timeseries",
    "final_diagnostics",
    "MCAP_MAGIC",
]

MCAP_MAGIC = b"\x89MCAP0\r\n"
_REPAIR_HINT = "run `vesselbot bag repair {path}` to rebuild it from the MCAP"


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag.

    Attributes:
        name: Topic name.
        msgtype: ROS type ``pkg/msg/Name``.
        count: Messages in ``metadata.yaml``.
        mcap_count: Messages in the MCAP's statistics (None if not available).
        latched: True if the offered QoS is transient local.
    """

    name: str
    msgtype: str
    count: int
    mcap_count: int | None
    latched: bool


@dataclass(frozen=True)
class BagInfo:
    """A validated bag directory.

    Attributes:
        path: The bag directory.
        mcap_paths: Its MCAP files.
        topics: Per-topic information, in ``metadata.yaml`` order.
        message_count: Total messages in ``metadata.yaml``.
        start_ns: Log time of the first message (ns).
        end_ns: Log time of the last message (ns).
        run_metadata: The run's description (scenario, seed, config, ...), or {}.
        problems: Inconsistencies between ``metadata.yaml`` and the MCAP (empty if none).
        chunk_compression: The MCAP chunks' compression, as their index records say
            (``none``, ``zstd``, ``lz4``; several joined by ``+``; ``-`` without a summary).
        chunks: Number of MCAP chunks (from the summary's chunk indexes).
    """

    path: Path
    mcap_paths: tuple[Path, ...]
    topics: tuple[TopicInfo, ...]
    message_count: int
    start_ns: int
    end_ns: int
    run_metadata: dict[str, Any] = field(default_factory=dict)
    problems: tuple[str, ...] = ()
    chunk_compression: str = "-"
    chunks: int = 0

    @property
    def duration_ns(self) -> int:
        """Log time span (ns)."""
        return max(0, self.end_ns - self.start_ns)

    @property
    def consistent(self) -> bool:
        """True when ``metadata.yaml`` matches the MCAP."""
        return not self.problems

    def topic(self, name: str) -> TopicInfo | None:
        """The topic named ``name``, or None."""
        return next((t for t in self.topics if t.name == name), None)


class BagMessage:
    """One recorded message: ``topic``, ``msgtype``, ``log_time_ns``, ``data`` (CDR bytes)."""

    __slots__ = ("_typestore", "data", "log_time_ns", "msgtype", "topic")

    def __init__(self, topic: str, msgtype: str, log_time_ns: int, data: bytes, typestore: Any) -> None:
        self.topic = topic
        self.msgtype = msgtype
        self.log_time_ns = log_time_ns
        self.data = data
        self._typestore = typestore

    def decode(self) -> Any:
        """The message decoded from the bag's embedded definition (rosbags object)."""
        return self._typestore.deserialize_cdr(self.data, self.msgtype)


def _check_mcap(path: Path, bag_dir: Path, chunk_kinds: list[str] | None = None) -> dict[str, int] | None:
    """Check one MCAP file; return its per-topic message counts from the summary.

    ``chunk_kinds``, if given, receives the compression of each chunk (``""`` for none).
    """
    if not path.is_file():
        raise BagError(f"bag {bag_dir}: MCAP file {path.name} listed in metadata.yaml is missing")
    size = path.stat().st_size
    with path.open("rb") as fh:
        head = fh.read(len(MCAP_MAGIC))
        if head != MCAP_MAGIC:
            raise BagError(f"bag {bag_dir}: {path.name} is not an MCAP file (bad magic {head[:8]!r})")
        fh.seek(max(0, size - len(MCAP_MAGIC)))
        tail = fh.read(len(MCAP_MAGIC))
        if size < 2 * len(MCAP_MAGIC) + 9 or tail != MCAP_MAGIC:
            raise BagError(
                f"bag {bag_dir}: {path.name} is truncated ({size} bytes, no MCAP footer; "
                f"the recorder was probably killed); " + _REPAIR_HINT.format(path=bag_dir)
            )
        fh.seek(0)
        try:
            summary = make_reader(fh).get_summary()
        except Exception as exc:  # noqa: BLE001 - mcap raises many types on corrupt input
            raise BagError(f"bag {bag_dir}: {path.name} is corrupt (summary unreadable: {exc!r})") from None
    if summary is not None and chunk_kinds is not None:
        chunk_kinds.extend(ci.compression for ci in summary.chunk_indexes)
    if summary is None or summary.statistics is None:
        return None
    counts: dict[str, int] = {}
    for cid, ch in summary.channels.items():
        counts[ch.topic] = counts.get(ch.topic, 0) + summary.statistics.channel_message_counts.get(cid, 0)
    return counts


def read_metadata_yaml(path: Path) -> Any:
    """Parse a bag's ``metadata.yaml`` with the project's bounded YAML reader.

    Raises:
        ValueError: naming the file, line and column of the first problem
            (never a Python repr).
    """
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path.name} is not UTF-8 text (byte {exc.start})") from None
    try:
        return parse_yaml_text(text, source=path.name)
    except ConfigError as exc:
        raise ValueError(str(exc)) from None


def open_bag(path: str | Path) -> BagInfo:
    """Validate a bag directory (or its ``metadata.yaml`` / ``.mcap``) and describe it.

    Raises:
        BagError: if the directory, ``metadata.yaml`` or an MCAP file is
            missing, truncated or corrupt (the message says which and what to do).
    """
    p = Path(path).expanduser()
    bag_dir = p.parent if p.is_file() else p
    if not bag_dir.is_dir():
        raise BagError(f"bag directory {bag_dir} does not exist")
    meta_path = bag_dir / "metadata.yaml"
    if not meta_path.is_file():
        hint = _REPAIR_HINT.format(path=bag_dir) if any(bag_dir.glob("*.mcap")) else "is this a bag directory?"
        raise BagError(f"bag {bag_dir} has no metadata.yaml; {hint}")
    try:
        doc = read_metadata_yaml(meta_path)
        info = doc["rosbag2_bagfile_information"]
        storage = info["storage_identifier"]
        files = list(info["relative_file_paths"])
        topics_meta = info["topics_with_message_count"] or []
        start_ns = int(info["starting_time"]["nanoseconds_since_epoch"])
        duration_ns = int(info["duration"]["nanoseconds"])
        total = int(info["message_count"])
    except (KeyError, TypeError, ValueError) as exc:
        what = f"lacks {exc}" if isinstance(exc, KeyError) else str(exc)
        raise BagError(f"bag {bag_dir}: metadata.yaml is corrupt ({what}); " + _REPAIR_HINT.format(path=bag_dir)) from None
    if storage != "mcap":
        raise BagError(f"bag {bag_dir}: storage {storage!r} is not supported (only mcap)")

    mcap_paths = tuple(bag_dir / f for f in files)
    mcap_counts: dict[str, int] | None = {}
    chunk_kinds: list[str] = []
    for mp in mcap_paths:
        c = _check_mcap(mp, bag_dir, chunk_kinds)
        if c is None or mcap_counts is None:
            mcap_counts = None
        else:
            for k, v in c.items():
                mcap_counts[k] = mcap_counts.get(k, 0) + v

    topics: list[TopicInfo] = []
    problems: list[str] = []
    for entry in topics_meta:
        tm = entry["topic_metadata"]
        qos = tm.get("offered_qos_profiles") or []
        if isinstance(qos, str):  # version <= 8 stores a YAML string
            qos = yaml.safe_load(qos) or []
        latched = any(str(q.get("durability", "")).lower() in ("transient_local", "1") for q in qos)
        mc = None if mcap_counts is None else mcap_counts.get(tm["name"], 0)
        topics.append(TopicInfo(tm["name"], tm["type"], int(entry["message_count"]), mc, latched))
        if mc is not None and mc != int(entry["message_count"]):
            problems.append(f"{tm['name']}: metadata.yaml says {entry['message_count']} messages, the MCAP holds {mc}")
    if mcap_counts is not None:
        listed = {t.name for t in topics}
        for name, n in sorted(mcap_counts.items()):
            if name not in listed and n:
                problems.append(f"{name}: {n} messages in the MCAP but not listed in metadata.yaml")
    if sum(t.count for t in topics) != total:
        problems.append(f"metadata.yaml message_count {total} != sum of topic counts {sum(t.count for t in topics)}")

    custom = info.get("custom_data") or {}
    run_metadata: dict[str, Any] = {}
    raw = custom.get(RUN_METADATA_KEY)
    if raw is None and (bag_dir / RUN_METADATA_FILE).is_file():
        raw = (bag_dir / RUN_METADATA_FILE).read_text(encoding="utf-8")
    if raw:
        try:
            run_metadata = json.loads(raw)
        except json.JSONDecodeError as exc:
            problems.append(f"run metadata is not valid JSON: {exc}")
    return BagInfo(
        path=bag_dir,
        mcap_paths=mcap_paths,
        topics=tuple(topics),
        message_count=total,
        start_ns=start_ns,
        end_ns=start_ns + duration_ns,
        run_metadata=run_metadata,
        problems=tuple(problems),
        chunk_compression="+".join(sorted({k or "none" for k in chunk_kinds})) or "-",
        chunks=len(chunk_kinds),
    )


def iter_messages(
    bag: str | Path | BagInfo,
    topics: Sequence[str] | None = None,
    start_ns: int | None = None,
) -> Iterator[BagMessage]:
    """Yield the bag's messages in log-time order.

    Args:
        bag: A bag directory or an already validated :class:`BagInfo`.
        topics: Only these topics (default: all).
        start_ns: Only messages with log time >= this (ns, absolute).

    Raises:
        BagError: if the bag is invalid, a requested topic is not in it, or a
            chunk turns out to be corrupt while reading.
    """
    info = bag if isinstance(bag, BagInfo) else open_bag(bag)
    if topics is not None:
        missing = sorted(set(topics) - {t.name for t in info.topics})
        if missing:
            raise BagError(f"bag {info.path} has no topic {', '.join(missing)}; it has {[t.name for t in info.topics]}")
    try:
        with AnyReader([info.path]) as reader:
            conns = [c for c in reader.connections if topics is None or c.topic in topics]
            if not conns:
                return
            ts = reader.typestore  # built from the bag's embedded definitions; outlives the reader
            for conn, t_ns, raw in reader.messages(connections=conns, start=start_ns):
                yield BagMessage(conn.topic, conn.msgtype, int(t_ns), bytes(raw), ts)
    except BagError:
        raise
    except (Exception, struct.error) as exc:  # noqa: BLE001 - rosbags/mcap raise many types on corrupt data
        raise BagError(f"bag {info.path} is corrupt: {exc!r}") from None


def final_diagnostics(bag: str | Path | BagInfo) -> dict[str, dict[str, str]]:
    """The last recorded ``/diagnostics`` key/values of every status name (node), e.g. final counts.

    Every vesselbot node publishes a last status with ``finished: true`` once
    its run is over, holding its final ``published:<topic>`` and
    ``received:<topic>`` counts.  Returns {} if the bag has no ``/diagnostics``.

    Raises:
        BagError: if the bag is invalid or corrupt.
    """
    diagnostics = topic("diagnostics").name
    info = bag if isinstance(bag, BagInfo) else open_bag(bag)
    if info.topic(diagnostics) is None:
        return {}
    out: dict[str, dict[str, str]] = {}
    for m in iter_messages(info, topics=[diagnostics]):
        for status in m.decode().status:
            out[status.name] = {v.key: v.value for v in status.values}
    return out


# --------------------------------------------------------------------------
# time series for the report and the metrics
# --------------------------------------------------------------------------
def _stamp_s(header: Any) -> float:
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def _v3(v: Any) -> list[float]:
    return [float(v.x), float(v.y), float(v.z)]


_FORCE_TERMS = ("magnetic", "drag", "apparent_weight", "contact", "van_der_waals", "electrostatic", "steric", "total")


#: What :func:`read_timeseries` holds per message read (its fields as Python floats, then as arrays): measured
#: 629 bytes over the synthetic bag's 24 thousand (tracemalloc peak), rounded up.
READ_BYTES_PER_MESSAGE = 1024


def read_timeseries(bag: str | Path | BagInfo) -> dict[str, np.ndarray]:
    """Arrays of the graph's recorded topics, keyed ``"<topic key>.<field>"``.

    Times ``*.t_s`` are the header stamps (sim time, s).  Vectors are (N, 3)
    ``(x, y, z)`` in frame ``vessel`` (y is 0 in a planar scenario's bag).  Keys
    (present when the topic was recorded):

    * ``truth.t_s, truth.p_WR`` (m), ``truth.v_WR`` (m/s), ``truth.v_blood``
      (m/s), ``truth.diameter_m``, ``truth.in_contact`` (bool),
      ``truth.applied_gradient`` (T/m), ``truth.F_<term>`` (N) for each term
      of eq. (1) and ``truth.F_total``;
    * ``estimate.t_s, estimate.p_hat`` (m), ``estimate.v_hat`` (m/s);
    * ``reference.t_s, reference.p_ref, reference.v_ref, reference.a_ref``;
    * ``measurement.t_s`` (acquisition stamp), ``measurement.log_t_s`` (log time
      since bag start), ``measurement.p_meas`` (m), ``measurement.fresh``
      (bool: stamp newer than the previous one);
    * ``command.t_s, command.u_cmd`` (T/m);
    * ``coil.t_s, coil.commanded, coil.applied`` (T/m), ``coil.saturated,
      coil.slew_limited_x, coil.slew_limited_y, coil.slew_limited_z, coil.rejected,
      coil.watchdog`` (bool; ``slew_limited_y`` false in planar runs and in bags
      recorded before 3-D trees), ``coil.max_gradient`` (T/m), ``coil.saturation_scale``,
      ``coil.slew_rate`` (T/m/s, the per-axis slew limit in force),
      ``coil.dbdt_limit`` (T/s, 0: none), ``coil.dbdt_radius`` (m);
    * ``phase.t_s`` (first tick the phase applies to), ``phase.phase`` (0
      continuous, 1 tracking, 2 dead, 3 propulsion), ``phase.period_index``,
      ``phase.window_start_s``, ``phase.window_end_s`` (s, the window
      ``[start, end)``), ``phase.latency_s``, ``phase.duty_cycle``: the scanner's
      sequence, one row per phase change;
    * ``faults.t_s`` / ``faults.kind`` (str) / ``faults.duration_s``: faults
      announced on ``/diagnostics`` by the imager (KeyValues ``fault_kind``,
      ``fault_start``, ``fault_duration``).

    Raises:
        BagError: if the bag is invalid or corrupt.
    """
    info = bag if isinstance(bag, BagInfo) else open_bag(bag)
    names = {topic(k).name: k for k in
             ("truth", "estimate", "reference", "measurement", "gradient_command", "coil_state", "sequence_phase",
              "diagnostics")}
    # before any message is read: the messages the MCAP holds (else metadata.yaml's count) bound the series held
    n = sum(max(t.count, t.mcap_count or 0) for t in info.topics if t.name in names)
    require_fits(f"bag {info.path}", f"{n} messages", READ_BYTES_PER_MESSAGE * n, what="reading its time series",
                 hint="read a shorter run (vesselbot bag info shows its topics)")
    present = [n for n in names if info.topic(n) is not None]
    rows: dict[str, dict[str, list[Any]]] = {k: {} for k in names.values()}

    def add(key: str, **vals: Any) -> None:
        d = rows[key]
        for k, v in vals.items():
            d.setdefault(k, []).append(v)

    last_meas_stamp = -np.inf
    fault_t: list[float] = []
    fault_kind: list[str] = []
    fault_dur: list[float] = []
    seen_faults: set[tuple[str, str]] = set()
    for m in iter_messages(info, topics=present):
        key = names[m.topic]
        msg = m.decode()
        if key == "truth":
            plant: dict[str, object] = {
                "t_s": _stamp_s(msg.header), "p_WR": _v3(msg.position), "v_WR": _v3(msg.velocity),
                "v_blood": _v3(msg.blood_velocity), "diameter_m": float(msg.vessel_diameter),
                "in_contact": bool(msg.in_contact), "applied_gradient": _v3(msg.applied_gradient),
                "gap_upper_m": float(msg.wall_gap_upper), "gap_lower_m": float(msg.wall_gap_lower),
            }
            for term in _FORCE_TERMS:
                plant[f"F_{term}"] = _v3(getattr(msg.forces, term))
            add(key, **plant)
        elif key == "estimate":
            add(key, t_s=_stamp_s(msg.header), p_hat=_v3(msg.pose.pose.position), v_hat=_v3(msg.twist.twist.linear))
        elif key == "reference":
            add(key, t_s=_stamp_s(msg.header), p_ref=_v3(msg.position), v_ref=_v3(msg.velocity),
                a_ref=_v3(msg.acceleration))
        elif key == "measurement":
            st = _stamp_s(msg.header)
            add(key, t_s=st, log_t_s=(m.log_time_ns - info.start_ns) * 1e-9, p_meas=_v3(msg.point),
                fresh=st > last_meas_stamp)
            last_meas_stamp = max(last_meas_stamp, st)
        elif key == "gradient_command":
            add(key, t_s=_stamp_s(msg.header), u_cmd=_v3(msg.vector))
        elif key == "coil_state":
            add(key, t_s=_stamp_s(msg.header), commanded=_v3(msg.commanded), applied=_v3(msg.applied),
                saturated=bool(msg.saturated), slew_limited_x=bool(msg.slew_limited_x),
                slew_limited_y=bool(getattr(msg, "slew_limited_y", False)),  # bags from before 3-D trees lack it
                slew_limited_z=bool(msg.slew_limited_z), rejected=bool(msg.command_rejected),
                watchdog=bool(msg.watchdog_active), max_gradient=float(msg.max_gradient),
                saturation_scale=float(msg.saturation_scale), slew_rate=float(msg.slew_rate),
                dbdt_limit=float(getattr(msg, "dbdt_limit", 0.0)),  # bags from before the dB/dt limit lack these
                dbdt_radius=float(getattr(msg, "dbdt_radius", 0.0)))
        elif key == "sequence_phase":
            add(key, t_s=_stamp_s(msg.header), phase=int(msg.phase), period_index=int(msg.period_index),
                window_start_s=float(msg.window_start), window_end_s=float(msg.window_end),
                latency_s=float(msg.latency), duty_cycle=float(msg.duty_cycle))
        elif key == "diagnostics":
            for status in msg.status:
                kv = {v.key: v.value for v in status.values}
                if "fault_kind" in kv and "fault_start" in kv:
                    ident = (kv["fault_kind"], kv["fault_start"])
                    if ident in seen_faults:
                        continue
                    seen_faults.add(ident)
                    try:
                        fault_t.append(float(kv["fault_start"]))
                        fault_dur.append(float(kv.get("fault_duration", "nan")))
                    except ValueError:
                        continue
                    fault_kind.append(kv["fault_kind"])

    prefix = {"gradient_command": "command", "coil_state": "coil", "sequence_phase": "phase"}
    out: dict[str, np.ndarray] = {}
    for key, d in rows.items():
        if key == "diagnostics":
            continue
        for fname, vals in d.items():
            arr = np.asarray(vals)
            if arr.dtype.kind == "f" or arr.dtype.kind == "i":
                arr = arr.astype(np.float64)
            out[f"{prefix.get(key, key)}.{fname}"] = arr
    out["faults.t_s"] = np.asarray(fault_t, dtype=np.float64)
    out["faults.duration_s"] = np.asarray(fault_dur, dtype=np.float64)
    out["faults.kind"] = np.asarray(fault_kind, dtype=str)
    return out
