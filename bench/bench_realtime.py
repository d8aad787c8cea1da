"""The highest real-time factor each mode holds on this machine (prints figures, asserts nothing).

``vesselbot run --mode realtime`` on the default scenario (config/sound_small_artery.yaml), recorded as
`vesselbot run` records by default, for a ladder of real-time factors, in both modes side by side in one
run: one process per node (``processes``) and all nodes in one process (``--single-process``).  The modes
take turns at each factor (the machine is shared and its speed drifts within a minute), and a mode stops
climbing after it failed at two factors in a row.  Each run's verdict is the launcher's own
(:class:`vesselbot_ros.launch.graph.RealtimeReport`: held if no loop node missed more than 1 % of its
control periods and the average factor held is within 1 % of the asked one), read from ``--metrics-json``.

Per run it prints the average factor held, the worst node's missed periods and worst lateness, and the
load average before and after; at the end, per mode, the highest factor held (with every lower factor of
the ladder held too) and the highest held at all.

Usage: .venv/bin/python bench/bench_realtime.py [--duration S] [--factors F,F,...] [--modes processes,single]
       [--no-record]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config" / "sound_small_artery.yaml"
MODES = {"processes": [], "single": ["--single-process"]}
FACTORS = (0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0)


def run_once(mode: str, factor: float, duration: float, record: bool, tmp: Path) -> dict:
    """One real-time run; its ``real_time`` report with the load averages around it (or why it has none)."""
    metrics = tmp / f"{mode}_{factor:g}.json"
    cmd = [sys.executable, "-m", "vesselbot_ros.cli", "run", "--config", str(CONFIG), "--mode", "realtime",
           "--real-time-factor", f"{factor:g}", "--duration", f"{duration:g}", "--quiet",
           "--metrics-json", str(metrics), *MODES[mode]]
    cmd += ["--record-dir", str(tmp / f"bag_{mode}_{factor:g}")] if record else ["--no-record"]
    load0, t0 = os.getloadavg()[0], time.monotonic()
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
    out = {"load_before": load0, "load_after": os.getloadavg()[0], "wall_total_s": time.monotonic() - t0,
           "code": proc.returncode}
    if not metrics.exists():
        out["error"] = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        return out
    out.update(json.loads(metrics.read_text())["real_time"])
    return out


def line(mode: str, factor: float, r: dict) -> str:
    head = f"{mode:9s} x{factor:<5g}"
    loads = f"load {r['load_before']:.2f} -> {r['load_after']:.2f}"
    if "error" in r:
        return f"{head} no report (exit {r['code']}): {r['error']}   {loads}"
    worst = max(r["nodes"], key=lambda n: n["fraction"])
    return (f"{head} {'held    ' if not r['failed'] else 'NOT held'}  factor {r['factor_held']:.4f} "
            f"({100 * r['factor_held'] / factor:6.2f} %)   worst {worst['role']:11s} missed {worst['missed']:5d} of "
            f"{worst['periods']} ({100 * worst['fraction']:6.2f} %), worst {worst['lateness_max_s'] * 1e3:7.2f} ms late"
            f"   {loads}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=1.0, help="sim seconds per run (default 1)")
    ap.add_argument("--factors", default=",".join(f"{f:g}" for f in FACTORS), help="the ladder, ascending")
    ap.add_argument("--modes", default="processes,single", help="processes, single, or both (comma-separated)")
    ap.add_argument("--no-record", dest="record", action="store_false", help="runs without a bag")
    args = ap.parse_args()
    factors = sorted(float(f) for f in args.factors.split(","))
    modes = [m for m in args.modes.split(",") if m]
    for m in modes:
        if m not in MODES:
            ap.error(f"unknown mode {m!r}; known: {', '.join(MODES)}")
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    load0 = os.getloadavg()[0]
    print(f"real time, {args.duration:g} s of sim per run, {'recorded' if args.record else 'not recorded'}, "
          f"{os.cpu_count()} cores, load average {load0:.2f} at start", flush=True)
    results: dict[str, dict[float, dict]] = {m: {} for m in modes}
    failures_in_a_row = dict.fromkeys(modes, 0)
    with tempfile.TemporaryDirectory(prefix="bench_realtime_") as td:
        for i, factor in enumerate(factors):
            order = modes if i % 2 == 0 else modes[::-1]  # take turns at being first
            for m in order:
                if failures_in_a_row[m] >= 2:
                    continue
                r = run_once(m, factor, args.duration, args.record, Path(td))
                results[m][factor] = r
                print(line(m, factor, r), flush=True)
                held = "error" not in r and not r["failed"]
                failures_in_a_row[m] = 0 if held else failures_in_a_row[m] + 1
    print("highest factor held (every lower factor of the ladder held too; the highest held at all):")
    for m in modes:
        ladder = results[m]
        held = [f for f in factors if f in ladder and "error" not in ladder[f] and not ladder[f]["failed"]]
        steady = None
        for f in factors:
            if f not in ladder or f not in held:
                break
            steady = f
        print(f"  {m:9s} {'none' if steady is None else f'x{steady:g}':6s}  "
              f"{'none' if not held else f'x{max(held):g}'}")
    print(f"load average {load0:.2f} before, {os.getloadavg()[0]:.2f} after ({os.cpu_count()} cores; other jobs "
          f"share them)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
