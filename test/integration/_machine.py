"""How busy the machine was while a test ran: what a wall-clock test needs before it judges speed.

A wall-clock test checks the program's honesty always (its figures agree with the bag, its verdict follows
from its figures).  A claim about speed ("a quiet machine holds 0.05x real time") holds only on a quiet
machine, so such a test measures the CPU time that other work took while it ran (``/proc/stat``, minus what
this process and its children used; a VM's steal time counts as other work) and, when other work held a
sizeable part of a core, skips with a message that says so instead of failing a correct program.
"""

from __future__ import annotations

import os
import resource
import time
from dataclasses import dataclass

#: Other work of at most this many cores (on average over the run) leaves a machine quiet enough to judge speed.
QUIET_FOREIGN_CORES = 0.25


def _proc_stat() -> tuple[float, float]:
    """(busy, steal) CPU seconds of the whole machine since boot, from ``/proc/stat``."""
    with open("/proc/stat") as fh:
        fields = [int(x) for x in fh.readline().split()[1:]]
    tick = os.sysconf("SC_CLK_TCK")
    user, nice, system, _idle, _iowait, irq, softirq = fields[:7]
    steal = fields[7] if len(fields) > 7 else 0
    return (user + nice + system + irq + softirq) / tick, steal / tick


def _own_cpu_s() -> float:
    """CPU seconds of this process and of its children that were waited for (their descendants included)."""
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


@dataclass
class Load:
    """What the machine did during a ``with machine_load() as load:`` block (filled in at its end)."""

    wall_s: float = 0.0
    own_cpu_s: float = 0.0
    foreign_cpu_s: float = 0.0
    cores: int = os.cpu_count() or 1
    loadavg_before: float = 0.0
    loadavg_after: float = 0.0

    @property
    def foreign_cores(self) -> float:
        """Cores that other work (not this test and its children) kept busy, on average."""
        return self.foreign_cpu_s / self.wall_s if self.wall_s > 0 else 0.0

    @property
    def quiet(self) -> bool:
        """True if other work left the machine quiet enough to judge a claim about speed."""
        return self.foreign_cores <= QUIET_FOREIGN_CORES

    def __str__(self) -> str:
        return (f"other work kept {self.foreign_cores:.2f} of {self.cores} cores busy over {self.wall_s:.1f} s "
                f"(this test and its processes: {self.own_cpu_s:.1f} CPU s; load average {self.loadavg_before:.2f} "
                f"before, {self.loadavg_after:.2f} after; quiet means at most {QUIET_FOREIGN_CORES} cores)")


class machine_load:
    """Measure the machine's other work while the block runs (children must be waited for inside it)."""

    def __enter__(self) -> Load:
        self.load = Load(loadavg_before=os.getloadavg()[0])
        self._t0, self._own0 = time.monotonic(), _own_cpu_s()
        self._busy0, self._steal0 = _proc_stat()
        return self.load

    def __exit__(self, *exc: object) -> None:
        busy, steal = _proc_stat()
        ld = self.load
        ld.wall_s = time.monotonic() - self._t0
        ld.own_cpu_s = _own_cpu_s() - self._own0
        ld.foreign_cpu_s = max(0.0, (busy - self._busy0) - ld.own_cpu_s) + (steal - self._steal0)
        ld.loadavg_after = os.getloadavg()[0]


#: A calibration spin that gets at least this share of a core finds the machine free enough to judge speed.
QUIET_CPU_SHARE = 0.9


def cpu_share(seconds: float = 0.5) -> float:
    """Spin for ``seconds`` of wall time; the share of one core this process got meanwhile (1.0: a core free).

    For a test whose own processes are not its children (they outlived the launcher): how contended the
    machine is now, measured after the fact.
    """
    t_end = time.monotonic() + seconds
    c0, w0 = time.process_time(), time.monotonic()
    x = 0
    while time.monotonic() < t_end:
        x += 1
    return (time.process_time() - c0) / (time.monotonic() - w0)


#: A sleeper that wakes this much later than it asked saw the machine stall (a quiet machine wakes it in ~0.1 ms).
STALL_S = 0.002

_WITNESS = r"""
import json, select, sys, time
period, stall = float(sys.argv[1]), float(sys.argv[2])
events = []
due = time.monotonic()
print("ready", flush=True)
while True:
    due += period
    r, _, _ = select.select([sys.stdin], [], [], max(0.0, due - time.monotonic()))
    now = time.monotonic()
    if r:
        break
    if now - due > stall:
        events.append((due, now - due))
    if now > due + period:  # a stall: start the schedule again from now, do not count its ticks twice
        due = now
print(json.dumps(events), flush=True)
"""


@dataclass
class Stalls:
    """What :class:`stall_witness` saw: each wake-up later than :data:`STALL_S`, as (due, late) in monotonic s."""

    events: list[tuple[float, float]]

    def within(self, t0: float, t1: float) -> list[tuple[float, float]]:
        """The stalls that overlapped the monotonic window [t0, t1]."""
        return [(due, late) for due, late in self.events if due <= t1 and due + late >= t0]

    def total_s(self, t0: float, t1: float) -> float:
        """Wall time the witness was kept from running within [t0, t1] (s)."""
        return sum(late for _, late in self.within(t0, t1))

    def describe(self, t0: float, t1: float) -> str:
        ev = self.within(t0, t1)
        worst = max((late for _, late in ev), default=0.0)
        return (f"an independent sleeper woke {len(ev)} times more than {STALL_S * 1e3:g} ms late in the run's window "
                f"(worst {worst * 1e3:.1f} ms, {self.total_s(t0, t1) * 1e3:.1f} ms in all)")


class stall_witness:
    """A separate process that sleeps 1 ms at a time and notes every wake-up the machine delayed.

    What ``/proc/stat`` cannot see (a hypervisor that deschedules the VM without counting steal, a host's
    noisy neighbour, a page-reclaim storm) still delays a sleeper's wake-up: if a trivial process that asks for
    the CPU every millisecond was kept waiting for milliseconds while a real-time run ran, the machine stalled,
    and a deadline the run missed then says nothing about the program.
    """

    def __init__(self, period_s: float = 0.001) -> None:
        self.period_s = period_s

    def __enter__(self) -> Stalls:
        import subprocess
        import sys

        self.stalls = Stalls([])
        self._proc = subprocess.Popen([sys.executable, "-c", _WITNESS, str(self.period_s), str(STALL_S)],
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert self._proc.stdout is not None and self._proc.stdout.readline().strip() == "ready"
        return self.stalls

    def __exit__(self, *exc: object) -> None:
        import json

        out, _ = self._proc.communicate("", timeout=30)
        self.stalls.events[:] = [tuple(e) for e in json.loads(out.strip().splitlines()[-1])]
