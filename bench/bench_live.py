"""Cost of the live view (``vesselbot run --live``) on the lockstep loop: wall time of the same run, side by side.

Three variants of one recorded lockstep run, interleaved over REPEATS rounds so
that machine load hits each alike: live view off; on with nobody connected;
on with Foxglove's own client (``tools/js/ws_live.mjs``) subscribed to every
channel.  Prints the median wall time of each and its ratio to "off"; the
target is at most 1.05 with a client connected.  On a loaded machine wall
times scatter by tens of per cent, so the CPU seconds the run's processes
used (launcher, nodes, recorder: ``RUSAGE_CHILDREN``; the client's own CPU
apart) are printed too: they are what the live view adds to the loop's
machine, and vary far less with load.  Lockstep results stay
bit-identical (``--metrics-json`` final states compared).

Usage: python bench/bench_live.py [--duration S] [--repeats N]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _children_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def one_run(work: Path, variant: str, duration: float, i: int) -> tuple[float, float, dict]:
    out = work / f"{variant}_{i}"
    args = [sys.executable, "-m", "vesselbot_ros.cli", "run", "--duration", str(duration), "--quiet",
            "--record-dir", str(out / "bag"), "--metrics-json", str(out.with_suffix(".json"))]
    client = None
    if variant != "off":
        port = free_port()
        args += ["--live-port", str(port)]
        if variant == "client":
            client = subprocess.Popen([shutil.which("node") or "node", str(REPO / "tools" / "js" / "ws_live.mjs"),
                                       str(port), "120", "60"], cwd=REPO / "tools" / "js",
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    cpu0 = _children_cpu()
    run = subprocess.run(args, cwd=work, capture_output=True, text=True, timeout=900)
    cpu = _children_cpu() - cpu0
    if run.returncode != 0:
        raise SystemExit(f"{variant}: {run.stderr[-2000:]}")
    if client is not None:
        got = json.loads(client.communicate(timeout=120)[0].splitlines()[-1])
        assert got["counts"] and not got["decode_errors"], got["decode_errors"]
    res = json.loads(out.with_suffix(".json").read_text())
    return float(res["wall_s"]), cpu, res["final"]


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=2.0, help="sim duration (s) of each run")
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    variants = ("off", "live", "client")
    walls: dict[str, list[float]] = {v: [] for v in variants}
    cpus: dict[str, list[float]] = {v: [] for v in variants}
    finals = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(a.repeats):
            for v in variants:
                w, cpu, final = one_run(Path(tmp), v, a.duration, i)
                walls[v].append(w)
                cpus[v].append(cpu)
                finals.setdefault(v, final)
    load = os.getloadavg()[0]
    base = statistics.median(walls["off"])
    cbase = statistics.median(cpus["off"])
    print(f"lockstep run, sound_small_artery, {a.duration:g} s sim, recorded; median of {a.repeats} "
          f"(load average {load:.1f} on {os.cpu_count()} cores)")
    print(f"  {'variant':34s} {'wall s':>8s} {'ratio':>7s} {'CPU s':>7s} {'ratio':>7s}   wall s of each run")
    names = {"off": "live view off", "live": "--live, no client", "client": "--live, Foxglove client on all"}
    for v in variants:
        m = statistics.median(walls[v])
        c = statistics.median(cpus[v])
        print(f"  {names[v]:34s} {m:8.2f} {m / base:7.3f} {c:7.2f} {c / cbase:7.3f}   "
              + " ".join(f"{w:.2f}" for w in walls[v]))
    same = all(finals[v] == finals["off"] for v in variants)
    print(f"final states bit-identical across variants: {same}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
