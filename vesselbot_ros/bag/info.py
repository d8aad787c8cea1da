"""``vesselbot bag info``: what a bag holds, and whether its metadata matches its MCAP."""

from __future__ import annotations

import datetime as _dt
import json
from typing import Any

from vesselbot_ros.bag.reader import BagInfo

__all__ = ["format_info", "info_dict"]


def _iso(ns: int) -> str:
    return _dt.datetime.fromtimestamp(ns * 1e-9, tz=_dt.UTC).isoformat(timespec="milliseconds")


def info_dict(info: BagInfo) -> dict[str, Any]:
    """A JSON-ready description of a bag (what ``bag info --json`` prints)."""
    run = info.run_metadata
    return {
        "path": str(info.path),
        "files": [p.name for p in info.mcap_paths],
        "message_count": info.message_count,
        "chunk_compression": info.chunk_compression,
        "chunks": info.chunks,
        "start_ns": info.start_ns,
        "end_ns": info.end_ns,
        "duration_s": info.duration_ns * 1e-9,
        "topics": [
            {"name": t.name, "type": t.msgtype, "count": t.count, "mcap_count": t.mcap_count, "latched": t.latched}
            for t in info.topics
        ],
        "scenario": run.get("scenario"),
        "seed": run.get("seed"),
        "mode": run.get("mode"),
        "versions": run.get("versions"),
        "command": run.get("command"),
        "config": run.get("config"),
        "consistent": info.consistent,
        "problems": list(info.problems),
    }


def format_info(info: BagInfo, show_config: bool = True) -> str:
    """Human-readable summary of a bag."""
    run = info.run_metadata
    lines = [
        f"Bag:        {info.path}",
        f"Files:      {', '.join(p.name for p in info.mcap_paths)}",
        f"Scenario:   {run.get('scenario', '-')}   seed: {run.get('seed', '-')}   mode: {run.get('mode', '-')}",
        f"Duration:   {info.duration_ns * 1e-9:.3f} s (log time)",
        f"Start:      {_iso(info.start_ns)} ({info.start_ns} ns)",
        f"End:        {_iso(info.end_ns)} ({info.end_ns} ns)",
        f"Messages:   {info.message_count}",
        f"Chunks:     {info.chunks}, compression {info.chunk_compression}",
        "Topics:",
    ]
    width = max((len(t.name) for t in info.topics), default=10)
    twidth = max((len(t.msgtype) for t in info.topics), default=10)
    for t in info.topics:
        mark = "" if t.mcap_count is None or t.mcap_count == t.count else f"  (MCAP: {t.mcap_count})"
        latched = "  latched" if t.latched else ""
        lines.append(f"  {t.name:<{width}}  {t.msgtype:<{twidth}}  {t.count:>8}{mark}{latched}")
    if run.get("versions"):
        lines.append(f"Versions:   {json.dumps(run['versions'], sort_keys=True)}")
    if run.get("command"):
        cmd = run["command"]
        lines.append(f"Command:    {' '.join(cmd) if isinstance(cmd, list) else cmd}")
    if show_config and run.get("config") is not None:
        lines.append("Config:")
        lines += ["  " + ln for ln in json.dumps(run["config"], indent=2, sort_keys=True).splitlines()]
    if info.consistent:
        lines.append("Metadata:   consistent with the MCAP")
    else:
        lines.append("Metadata:   DOES NOT MATCH the MCAP:")
        lines += [f"  - {p}" for p in info.problems]
    return "\n".join(lines)
