"""Per-tick against compiled closed loop, batches on 1 and 2 cores, cold start; then accuracy.

Usage: .venv/bin/python bench/bench_closed_loop.py [--runs 1000] [--config config/sound_small_artery.yaml]
       [--ekf-config config/sound_small_artery_ekf.yaml]

Prints, side by side in one run (the compiled loop's targets in brackets):

1. ms per run of the same scenario and seeds, warm, the two paths interleaved:
   the per-tick Python loop (``path="per_tick"``) and the compiled loop; ratio [>= 10x];
2. ``run_many`` of ``--runs`` runs (seeds 0..runs-1) on 1 and on 2 threads: seconds [<= 8 s on 2
   cores for 1000 runs], scaling [>= 1.8x], and the share of the batch spent outside the kernel;
3. the first ``run_closed_loop`` call in a fresh process with the numba cache warm [<= 2 s], and the
   whole process (interpreter, imports, first run);
4. the machine's load average before and after (other jobs share the cores: read the figures with it);
5. accuracy: key metrics against a run with 100x tighter integrator tolerances, and seeds 0-4;
6. the compiled loop's cost against a reference commit's, side by side (``--ref``, default the commit issue 40
   measured before one loop served any number of axes; ``--ref ''`` skips it): CPU ms per simulated second of
   both scenarios in both trees, taking turns (``bench_against.side_by_side``).

Sections 1-3 run for the paper scenario and again for the extended-Kalman-filter scenario
(``--ekf-config``; ``--ekf-config ''`` skips it), whose filter and flow-compensating law run compiled too.

The default scenario is the one ``make run`` runs: Section III-C with the sound readings
(``config/sound_small_artery.yaml``, 2000 ticks at 1 kHz).  The as-printed variant
(``config/paper_small_artery.yaml``) is stiff (the printed H(-delta) forces ~335,000 integrator
steps per run): its time is arithmetic, not per-tick overhead, so the two paths are close there.
"""

from __future__ import annotations

import argparse
import dataclasses as dc
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from bench_against import ISSUE_40_BASE, side_by_side  # this folder's: the same timing as bench_against.py

from vesselbot_ros.sim.closed_loop import run_closed_loop, run_many
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios

ROOT = Path(__file__).resolve().parents[1]
KEYS = ("tracking_error_max_m", "tracking_error_rms_m", "estimation_error_max_m", "estimation_error_rms_m")
COLD = """
import time, sys
t0 = time.perf_counter()
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario
sc = load_scenario(sys.argv[1])
t1 = time.perf_counter()
run_closed_loop(sc)
t2 = time.perf_counter()
print(t1 - t0, t2 - t1)
"""


def _load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (1 min), {five:.2f} (5 min) on {os.cpu_count()} cores"


def per_run(path: str, n: int) -> None:
    sc = load_scenario(path)
    run_closed_loop(sc, path="per_tick")
    run_closed_loop(sc)
    tick, comp, tick_cpu, comp_cpu = [], [], [], []
    for i in range(n):  # interleaved, same seeds: both paths see the same machine
        t0, c0 = time.perf_counter(), time.thread_time()
        a = run_closed_loop(sc, i, path="per_tick")
        t1, c1 = time.perf_counter(), time.thread_time()
        b = run_closed_loop(sc, i)
        t2, c2 = time.perf_counter(), time.thread_time()
        assert repr(a.metrics) == repr(b.metrics), "paths differ"
        tick.append(t1 - t0)
        comp.append(t2 - t1)
        tick_cpu.append(c1 - c0)
        comp_cpu.append(c2 - c1)
    mt, mc = statistics.median(tick), statistics.median(comp)
    ct, cc = statistics.median(tick_cpu), statistics.median(comp_cpu)
    print(f"1. {sc.name}, {sc.sim.n_ticks} ticks, median of {n} warm runs each, interleaved:")
    print(f"   wall: per-tick loop {mt * 1e3:8.1f} ms/run (best {min(tick) * 1e3:.1f})   compiled loop {mc * 1e3:6.1f} ms/run "
          f"(best {min(comp) * 1e3:.1f})   ratio {mt / mc:5.1f}x (best/best {min(tick) / min(comp):.1f}x)  [target >= 10x]")
    print(f"   CPU:  per-tick loop {ct * 1e3:8.1f} ms/run (best {min(tick_cpu) * 1e3:.1f})   compiled loop {cc * 1e3:6.1f} ms/run "
          f"(best {min(comp_cpu) * 1e3:.1f})   ratio {ct / cc:5.1f}x (best/best {min(tick_cpu) / min(comp_cpu):.1f}x)")


def batches(path: str, runs: int) -> None:
    sc = load_scenario(path)
    run_many(sc, [0, 1], workers=2)
    t, cpu = {}, {}
    for workers in (1, 2):
        t0, c0 = time.perf_counter(), time.process_time()
        rows = run_many(sc, range(runs), workers=workers)
        t[workers], cpu[workers] = time.perf_counter() - t0, time.process_time() - c0
        assert len(rows) == runs
    print(f"2. run_many({sc.name}, seeds 0..{runs - 1}), metrics rows:")
    print(f"   1 thread {t[1]:6.2f} s ({t[1] / runs * 1e3:.1f} ms/run)   2 threads {t[2]:6.2f} s "
          f"({t[2] / runs * 1e3:.1f} ms/run)   scaling {t[1] / t[2]:.2f}x   [targets: <= 8 s for 1000 runs on 2 cores, >= 1.8x]")
    print(f"   CPU time: 1 thread {cpu[1]:6.2f} s, 2 threads {cpu[2]:6.2f} s in all ({cpu[2] / 2:.2f} s per core: the wall "
          f"time of the batch on two otherwise idle cores)")


def cold(path: str) -> None:
    out = subprocess.run([sys.executable, "-c", COLD, path], capture_output=True, text=True, check=True, cwd=ROOT)
    imports, first = map(float, out.stdout.split())
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", COLD, path], capture_output=True, text=True, check=True, cwd=ROOT)
    whole = time.perf_counter() - t0
    print(f"3. fresh process, warm numba cache: first run_closed_loop {first:.2f} s  [target <= 2 s]; "
          f"imports {imports:.2f} s; whole process (interpreter + imports + first run) {whole:.2f} s")


def accuracy(path: str) -> None:
    sc = load_scenario(path)
    res = run_closed_loop(sc)
    ig = sc.sim.integrator
    tight = dc.replace(sc, sim=dc.replace(sc.sim, integrator=dc.replace(
        ig, rtol=ig.rtol / 100, atol_position_m=ig.atol_position_m / 100,
        atol_velocity_m_per_s=ig.atol_velocity_m_per_s / 100)))
    ref = run_closed_loop(tight)
    print(f"5. {sc.name}: plant rhs evals {res.metrics['plant_rhs_evals']}, forced steps {res.metrics['plant_forced_steps']}, "
          f"observer rhs evals {res.metrics['observer_rhs_evals']}")
    for k in KEYS:
        a, b = res.metrics[k], ref.metrics[k]
        print(f"   {k:28s} {a * 1e6:10.2f} um  tight-tolerance ref {b * 1e6:10.2f} um  rel diff {abs(a - b) / abs(b):.2e}")
    rows = [r.metrics for r in run_many(sc, range(5))]
    for k in KEYS + ("contact_time_s",):
        vals = [m[k] for m in rows]
        scale, unit = (1.0, "s ") if k.endswith("_s") else (1e6, "um")
        print(f"   seeds 0-4 {k:24s} mean {sum(vals) / len(vals) * scale:9.3f} {unit} worst {max(vals) * scale:9.3f} {unit}"
              f"  per seed {[round(v * scale, 3) for v in vals]}")


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default=str(ROOT / "config" / "sound_small_artery.yaml"))
    ap.add_argument("--runs", type=int, default=1000, help="runs per batch (section 2)")
    ap.add_argument("--ekf-config", default=str(ROOT / "config" / "sound_small_artery_ekf.yaml"))
    ap.add_argument("--warm-runs", type=int, default=15, help="runs per path (section 1)")
    ap.add_argument("--ref", default=ISSUE_40_BASE, help="section 6's reference commit ('' skips it)")
    args = ap.parse_args(argv)
    print(f"4. before: {_load()}; every wall figure stretches with the load, the CPU figures much less")
    for path in [args.config] + ([args.ekf_config] if args.ekf_config else []):
        per_run(path, args.warm_runs)
        batches(path, args.runs)
        cold(path)
        print(f"4. now:    {_load()}")
    accuracy(args.config)
    if args.ref:
        print("6. ", end="")
        names = [load_scenario(path).name for path in [args.config] + ([args.ekf_config] if args.ekf_config else [])]
        side_by_side(args.ref, [n for n in names if n in shipped_scenarios()])


if __name__ == "__main__":
    main(sys.argv[1:])
