"""The one resource check: what a step sized by the input may take of this machine, refused before it starts.

:func:`vesselbot_ros.sim.scenario.check_resources` refuses a run whose time series do not fit; every other
allocation or solve whose size an input sets (the reference's anchors, a network's centreline samples, a mesh,
a sampling grid, a campaign's runs) estimates its bytes (and, where a solve time can be estimated, its
seconds) and calls :func:`require_fits` with the key and value that set it, before it allocates anything.
Both read the same budget, :func:`memory_budget_bytes`: half of this machine's physical memory, or less
when the process runs under a limit (``ulimit -v``, ``RLIMIT_AS``; a cgroup's ``memory.max``).

A step that does not fit raises :class:`~vesselbot_ros.errors.ConfigError` in one line naming the key, its
value and the estimate, which the ``vesselbot`` command prints and exits 2 on.

This module imports nothing from the package but its errors.
"""

from __future__ import annotations

import os
import resource
from pathlib import Path
from typing import Any

from vesselbot_ros.errors import ConfigError

__all__ = ["SETUP_TIME_BUDGET_S", "memory_budget_bytes", "fmt_bytes", "fmt_seconds", "require_fits",
           "spline_setup_cost"]

#: The longest a set-up step sized by the input (a spline's solve, a mesh and its flow solve, a grid's
#: sampling) may be estimated to take before it is refused (s): half an hour.
SETUP_TIME_BUDGET_S = 1800.0
#: :func:`vesselbot_ros.blas_free.interp_spline` through n points holds its (n + 2)^2 collocation matrix several
#: times over (scipy's identity basis, the evaluated rows, their stack and the solver's Python floats) and
#: eliminates in Python scalars: measured 82-112 bytes and 0.56-0.76 us per matrix entry at 1000-2000 points
#: (a 2-core machine, loaded); the estimate takes the upper figures.
SPLINE_BYTES_PER_ENTRY = 112.0
SPLINE_SECONDS_PER_ENTRY = 0.8e-6


def _status_bytes(field: str) -> int | None:
    """A ``/proc/self/status`` size (``VmSize``, ...) in bytes, or None where there is none."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _cgroup_headroom_bytes() -> int | None:
    """What this process's cgroup (v2) may still take: ``memory.max`` less ``memory.current``; None without a limit."""
    try:
        rel = next((ln.split("::", 1)[1] for ln in Path("/proc/self/cgroup").read_text().splitlines()
                    if ln.startswith("0::")), None)
        if rel is None:
            return None
        d = Path("/sys/fs/cgroup") / rel.strip().lstrip("/")
        limit = (d / "memory.max").read_text().strip()
        if limit == "max":
            return None
        return max(0, int(limit) - int((d / "memory.current").read_text().strip()))
    except (OSError, ValueError, StopIteration):
        return None


def memory_budget_bytes() -> int:
    """What one run or set-up step may hold (bytes): half of this machine's physical memory, or, under a limit,
    half of what the limit leaves (``RLIMIT_AS`` less this process's address space now; a cgroup's
    ``memory.max`` less its usage)."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        total = 8 * 2**30
    budget = int(total // 2)
    soft, _hard = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        used = _status_bytes("VmSize") or 0
        budget = min(budget, max(0, soft - used) // 2)
    cg = _cgroup_headroom_bytes()
    if cg is not None:
        budget = min(budget, cg // 2)
    return budget


def fmt_bytes(n: float) -> str:
    """``n`` bytes in B, KiB, MiB, GiB or TiB."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"  # pragma: no cover


def fmt_seconds(s: float) -> str:
    """``s`` seconds in s, min or h."""
    if s < 120.0:
        return f"{s:.0f} s"
    if s < 7200.0:
        return f"{s / 60.0:.0f} min"
    return f"{s / 3600.0:.3g} h"


def spline_setup_cost(n_points: int) -> tuple[float, float]:
    """(bytes, seconds) of :func:`~vesselbot_ros.blas_free.interp_spline` through ``n_points`` points (dense solve)."""
    entries = float(n_points + 2) ** 2
    return SPLINE_BYTES_PER_ENTRY * entries, SPLINE_SECONDS_PER_ENTRY * entries


def require_fits(key: str, value: Any, memory_bytes: float, seconds: float | None = None, *, what: str,
                 hint: str = "", memory_budget: int | None = None) -> None:
    """Refuse, before it starts, a step sized by ``key`` that would not fit in memory (or in time).

    Args:
        key: The dotted key (or option) whose value sizes the step, e.g. ``reference.anchors_x_m``.
        value: Its value as the message shows it (a number, or a phrase such as ``"35000 points"``).
        memory_bytes: The step's estimated peak memory (bytes).
        seconds: Its estimated duration (s), or None where none can be estimated.
        what: What the step is ("the reference's B-spline set-up").
        hint: What to change, appended after a colon.
        memory_budget: The budget (default: :func:`memory_budget_bytes`).

    Raises:
        ConfigError: one line: ``<key>=<value>: <what> needs about <estimate>, more than <budget> ...``.
    """
    budget = memory_budget_bytes() if memory_budget is None else memory_budget
    shown = value if isinstance(value, str) else repr(value)
    tail = f": {hint}" if hint else ""
    if not memory_bytes <= budget:  # NaN refuses too
        raise ConfigError(f"{key}={shown}: {what} needs about {fmt_bytes(memory_bytes)} of memory, more than the "
                          f"{fmt_bytes(budget)} a step may use (half of this machine's memory, or of its limit)"
                          f"{tail}")
    if seconds is not None and not seconds <= SETUP_TIME_BUDGET_S:
        raise ConfigError(f"{key}={shown}: {what} would take about {fmt_seconds(seconds)} "
                          f"({fmt_bytes(memory_bytes)} of memory), more than the "
                          f"{fmt_seconds(SETUP_TIME_BUDGET_S)} a set-up step may take{tail}")
