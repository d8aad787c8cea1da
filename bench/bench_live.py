"""Cost of the live view (``vesselbot run --live``) on the lockstep loop: wall time of the same run, side by side.

Three variants of one recorded lockstep run, interleaved over REPEATS rounds so
that machine load hits each alike: live view off; on with nobody connected;
on with Foxglove's own client (``tools/js/ws_live.mjs``) subscribed to every
channel.  Prints the median wall time of each and its ratio to "off"; the
target is at most 1.05 with a client connected.  Lockstep results stay
bit-identical (``--metrics-json`` final states compared).

Usage: python bench/bench_live.py [--duration S] [--repeats N]
"""

from __future__ import annotations

import argparse
import json
import os
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


def one_run(work: Path, variant: str, duration: float, i: int) -> tuple[float, dict]:
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
    run = subprocess.run(args, cwd=work, capture_output=True, text=True, timeout=900)
    if run.returncode != 0:
        raise SystemExit(f"{variant}: {run.stderr[-2000:]}")
    if client is not None:
        got = json.loads(client.communicate(timeout=120)[0].splitlines()[-1])
        assert got["counts"] and not got["decode_errors"], got["decode_errors"]
    res = json.loads(out.with_suffix(".json").read_text())
    return float(res["wall_s"]), res["final"]


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=2.0, help="sim duration (s) of each run")
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    variants = ("off", "live", "client")
    walls: dict[str, list[float]] = {v: [] for v in variants}
    finals = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(a.repeats):
            for v in variants:
                w, final = one_run(Path(tmp), v, a.duration, i)
                walls[v].append(w)
                finals.setdefault(v, final)
    load = os.getloadavg()[0]
    base = statistics.median(walls["off"])
    print(f"lockstep run, sound_small_artery, {a.duration:g} s sim, recorded; median of {a.repeats} "
          f"(load average {load:.1f} on {os.cpu_count()} cores)")
    print(f"  {'variant':34s} {'wall s':>8s} {'ratio':>7s}   runs")
    names = {"off": "live view off", "live": "--live, no client", "client": "--live, Foxglove client on all"}
    for v in variants:
        m = statistics.median(walls[v])
        print(f"  {names[v]:34s} {m:8.2f} {m / base:7.3f}   " + " ".join(f"{w:.2f}" for w in walls[v]))
    same = all(finals[v] == finals["off"] for v in variants)
    print(f"final states bit-identical across variants: {same}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
