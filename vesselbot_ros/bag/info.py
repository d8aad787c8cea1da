"""``vesselbot bag info``: what a bag holds, and whether its metadata matches its MCAP."""

from __future__ import annotations

import datetime as _dt
import json
import math
import struct
from dataclasses import dataclass
from typing import Any

from mcap.reader import make_reader

from vesselbot_ros.bag.reader import BagInfo
from vesselbot_ros.errors import BagError
from vesselbot_ros.graph_spec import topic

__all__ = ["Coverage", "coverage", "format_info", "info_dict", "run_settings"]


@dataclass(frozen=True)
class Coverage:
    """The sim-time span a bag covers, against the run's planned duration.

    Attributes:
        first_s: Sim time of the first recorded tick (s).
        last_s: Sim time of the last recorded tick (s).
        dt_s: The run's control period (s; None if the run's config does not say).
        planned_s: The run's planned duration, ``sim.duration_s`` (s; None if not recorded).
    """

    first_s: float
    last_s: float
    dt_s: float | None
    planned_s: float | None

    @property
    def covered_s(self) -> float:
        """Sim time the bag covers: its first to its last tick, and the last tick's control period (s)."""
        return self.last_s - self.first_s + (self.dt_s or 0.0)

    @property
    def partial(self) -> bool:
        """True when the bag ends more than half a control period before the planned end of the run."""
        if self.planned_s is None:
            return False
        return self.covered_s < self.planned_s - 0.5 * (self.dt_s or 0.0) - 1e-9

    def line(self) -> str:
        """``covers 0.83 s of the 2.00 s run (partial: its last tick is at sim t = 0.829 s)``."""
        if self.planned_s is None:
            return (f"covers {self.covered_s:.2f} s of sim time ({self.first_s:.3f} to {self.last_s:.3f} s); "
                    f"the run's planned duration is not recorded")
        if self.partial:
            return (f"covers {self.covered_s:.2f} s of the {self.planned_s:.2f} s run (partial: its last tick is at "
                    f"sim t = {self.last_s:.3f} s)")
        return f"covers {self.covered_s:.2f} s of the {self.planned_s:.2f} s run (complete)"

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready fields (``bag info --json``, the report's ``metrics.json``)."""
        return {"sim_time_first_s": self.first_s, "sim_time_last_s": self.last_s,
                "sim_time_covered_s": self.covered_s, "planned_duration_s": self.planned_s, "partial": self.partial}


def _config_number(run: dict[str, Any], key: str) -> float | None:
    try:
        v = float(run["config"]["sim"][key])
    except (KeyError, TypeError, ValueError):
        return None
    return v if math.isfinite(v) and v > 0 else None


def coverage_of_ticks(run: dict[str, Any], first_s: float, last_s: float) -> Coverage:
    """The :class:`Coverage` of ticks from ``first_s`` to ``last_s`` (s) of the run described by ``run``."""
    rate = _config_number(run, "control_rate_Hz")
    return Coverage(first_s, last_s, 1.0 / rate if rate else None, _config_number(run, "duration_s"))


def _clock_s(data: bytes) -> float:
    # rosgraph_msgs/Clock in CDR: the 4-byte encapsulation header, then builtin_interfaces/Time (int32, uint32)
    sec, nsec = struct.unpack_from("<iI" if data[1] == 1 else ">iI", data, 4)
    return sec + 1e-9 * nsec


def coverage(info: BagInfo) -> Coverage | None:
    """The sim-time span of the bag's ``/clock`` (its first and last message only), or None without one.

    Raises:
        BagError: if the MCAP cannot be read.
    """
    clock = topic("clock").name
    if info.topic(clock) is None:
        return None
    first: float | None = None
    last: float | None = None
    try:
        for path in info.mcap_paths:
            with path.open("rb") as fh:
                reader = make_reader(fh)
                for reverse in (False, True):  # the first message, then the last (the summary's index: two chunks)
                    t = next((_clock_s(m.data) for _s, _c, m in reader.iter_messages(topics=[clock], reverse=reverse)),
                             None)
                    if t is not None:
                        first = t if first is None else min(first, t)
                        last = t if last is None else max(last, t)
    except Exception as exc:  # noqa: BLE001 - mcap and struct raise many types on bad data
        raise BagError(f"bag {info.path}: cannot read its /clock: {exc!r}") from None
    if first is None or last is None:
        return None
    return coverage_of_ticks(info.run_metadata, first, last)


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
        "coverage": cov.as_dict() if (cov := coverage(info)) is not None else None,
    }


def _get(config: Any, dotted: str) -> Any:
    """``config``'s value at a dotted key, or None where the run's config does not have it."""
    node = config
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def _num(value: Any, scale: float = 1.0) -> str:
    """A recorded number for a person (``0.045`` T/m scaled to mT/m: ``45``); a non-number as it is."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return str(value)
    return f"{value * scale:g}"


def run_settings(config: Any) -> list[str]:
    """The few settings of a run's config that tell runs apart (what ``bag info`` prints without ``--full``).

    The loop (duration, rate, controller, observer, reference), the hardware
    (coil, sequence, imager) and the vessel; a line or a part the config does not
    have is left out.
    """
    def part(label: str, key: str, fmt: Any = str) -> str:
        v = _get(config, key)
        return "" if v is None or v == "" or v == [] else f"{label}{fmt(v)}"

    def joined(*parts: str, sep: str = ", ") -> str:
        return sep.join(p for p in parts if p)

    loop = joined(joined(part("", "sim.duration_s", lambda v: f"{_num(v)} s"),
                         part("at ", "sim.control_rate_Hz", lambda v: f"{_num(v)} Hz"), sep=" "),
                  joined(part("controller ", "controller.kind"), part("observer ", "observer.kind"),
                         part("reference ", "reference.kind")), sep="; ")
    hardware = joined(part("coil ", "coil.saturation_T_per_m", lambda v: f"{_num(v, 1e3)} mT/m"),
                      part("sequence ", "sequence.mode"), part("dB/dt ", "dbdt.mode"),
                      joined(part("imager ", "imager.kind"),
                             part("at ", "imager.frame_rate_Hz", lambda v: f"{_num(v)} frames/s"), sep=" "),
                      part("noise ", "imager.noise_sigma_m", lambda v: f"{_num(v, 1e6)} um"))
    vessel = joined(part("network ", "physics.vessel.network")
                    or part("straight, D = ", "physics.vessel.diameter_m", lambda v: f"{_num(v, 1e3)} mm"),
                    part("to outlet ", "reference.route_outlet"),
                    part("bead r = ", "physics.robot.radius_m", lambda v: f"{_num(v, 1e6)} um"))
    return [f"{label:<12}{text}" for label, text in (("Loop:", loop), ("Hardware:", hardware), ("Vessel:", vessel))
            if text]


def format_info(info: BagInfo, full: bool = False, show_config: bool = True) -> str:
    """Human-readable summary of a bag.

    The default is short: the scenario, seed and mode, the settings that tell
    runs apart (:func:`run_settings`), the command, the duration and sim-time
    coverage, the topics with their counts, and whether the metadata matches the
    MCAP.  ``full`` adds the files, start and end times, chunks, versions and
    (unless ``show_config`` is False) the run's whole config.
    """
    run = info.run_metadata
    config = run.get("config")
    lines = [f"Bag:        {info.path}"]
    if full:
        lines.append(f"Files:      {', '.join(p.name for p in info.mcap_paths)}")
    lines.append(f"Scenario:   {run.get('scenario', '-')}   seed: {run.get('seed', '-')}   mode: {run.get('mode', '-')}")
    lines += run_settings(config)
    if run.get("command"):
        cmd = run["command"]
        lines.append(f"Command:    {' '.join(cmd) if isinstance(cmd, list) else cmd}")
    lines += [
        f"Duration:   {info.duration_ns * 1e-9:.3f} s (log time)",
        f"Sim time:   {cov.line() if (cov := coverage(info)) is not None else 'no /clock recorded'}",
    ]
    if full:
        lines += [
            f"Start:      {_iso(info.start_ns)} ({info.start_ns} ns)",
            f"End:        {_iso(info.end_ns)} ({info.end_ns} ns)",
        ]
    lines.append(f"Messages:   {info.message_count}")
    if full:
        lines.append(f"Chunks:     {info.chunks}, compression {info.chunk_compression}")
    lines.append("Topics:")
    width = max((len(t.name) for t in info.topics), default=10)
    twidth = max((len(t.msgtype) for t in info.topics), default=10)
    for t in info.topics:
        mark = "" if t.mcap_count is None or t.mcap_count == t.count else f"  (MCAP: {t.mcap_count})"
        latched = "  latched" if t.latched else ""
        lines.append(f"  {t.name:<{width}}  {t.msgtype:<{twidth}}  {t.count:>8}{mark}{latched}")
    if full and run.get("versions"):
        lines.append(f"Versions:   {json.dumps(run['versions'], sort_keys=True)}")
    if full and show_config and config is not None:
        lines.append("Config:")
        lines += ["  " + ln for ln in json.dumps(config, indent=2, sort_keys=True).splitlines()]
    if info.consistent:
        lines.append("Metadata:   consistent with the MCAP")
    else:
        lines.append("Metadata:   DOES NOT MATCH the MCAP:")
        lines += [f"  - {p}" for p in info.problems]
    if not full:
        lines.append("More:       --full adds the files, start and end times, chunks, versions"
                     + (" and the run's whole config" if config is not None else ""))
    return "\n".join(lines)
