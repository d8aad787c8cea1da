"""Campaigns at the speed of their runs: the engine's run phase against ``run_many``, and 1000 runs end to end.

Usage: .venv/bin/python bench/bench_campaign.py [--runs N] [--rounds R] [--workers W] [--e2e-runs M]
                                                [--config config/sound_small_artery.yaml]

Measured side by side in one process on the sound scenario
(``config/sound_small_artery.yaml``, about 6 ms per compiled run warm: the
short runs where the engine's cost per run shows), on the same ``N`` seeds:

1. ``run_many``: :func:`~vesselbot_ros.sim.closed_loop.run_many` of the N
   seeds on W threads (the compiled loop releases the GIL), in this process,
   warm.  The arithmetic of the runs and nothing else.
2. ``campaign run phase``: what ``vesselbot campaign`` does between starting
   its cluster and drawing its report, on a LocalCluster of one worker process with W threads
   started and warmed beforehand (as :func:`~vesselbot_ros.campaign.engine.dask_client`
   starts it): :func:`~vesselbot_ros.campaign.engine.prepare` (resolving and
   hashing every run), the manifest, :func:`~vesselbot_ros.campaign.engine.pending`
   and :func:`~vesselbot_ros.campaign.engine.execute` (chunking, scheduling,
   serialisation, every Parquet part written), into a fresh folder each round.
   Its numbers are checked bit for bit against phase 1.

3. ``end to end``: ``vesselbot campaign`` itself on ``--e2e-runs`` runs
   (seeds 0..M-1) in a subprocess, into a fresh folder: interpreter start,
   spec, cluster start, runs, tables and figures (the bench's own cluster
   idles meanwhile).

The three alternate for ``--rounds`` rounds and the best of each counts, so a
burst of load from other users of the shared machine hits all of them alike.
Targets: run phase <= 1.2 x ``run_many``; 1000 runs end to end <= 8 s on 2
cores.  The load average is printed before and after, and after each phase.
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

from vesselbot_ros.campaign.engine import dask_client, execute, pending, prepare
from vesselbot_ros.campaign.runner import run_chunk
from vesselbot_ros.campaign.spec import campaign_spec_from_mapping
from vesselbot_ros.campaign.store import CampaignStore
from vesselbot_ros.config import load_yaml
from vesselbot_ros.sim.closed_loop import run_many
from vesselbot_ros.sim.scenario import scenario_from_mapping

ROOT = Path(__file__).resolve().parents[1]
RUN_PHASE_TARGET = 1.2
E2E_TARGET_S = 8.0


def _load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f} / {five:.2f} / {fifteen:.2f} (1/5/15 min) on {os.cpu_count()} cores"


def _same(a: object, b: object) -> bool:
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def _run_phase(base: dict, n: int, client, root: Path) -> tuple[float, object, CampaignStore]:
    """The campaign's run phase on seeds 0..n-1 into the fresh folder ``root``: wall time (s), outcome, store."""
    t0 = time.perf_counter()
    spec = campaign_spec_from_mapping({"name": "bench", "base": "-", "seeds": {"start": 0, "count": n}})
    prep = prepare(spec, base)
    store = CampaignStore(root)
    store.write_manifest(prep.manifest, {"name": "bench", "n_runs": n, "n_seeds": n, "varied_keys": [],
                                         "grid_keys": []}, "")
    out = execute(pending(prep.tasks, store), store, client, prep.code)
    return time.perf_counter() - t0, out, store


def _check_identical(rows: list, store: CampaignStore) -> int:
    """Runs whose every numeric metric equals run_many's, bit for bit (raises on the first difference)."""
    stored = {r["seed"]: r for r in store.assemble().to_pylist()}
    for res in rows:
        got = stored[res.metrics["seed"]]
        for k, v in res.metrics.items():
            if isinstance(v, (int, float)) and not isinstance(v, bool) and k in got and not _same(float(v), float(got[k])):
                raise AssertionError(f"seed {res.metrics['seed']}: {k} = {got[k]!r} in the campaign, {v!r} in run_many")
    return len(rows)


def _e2e(config: Path, n: int, tmp: Path, tag: str) -> tuple[float, str]:
    spec = tmp / f"e2e-{tag}.yaml"
    spec.write_text(yaml.safe_dump({"name": f"e2e_{tag}", "base": str(config), "seeds": {"start": 0, "count": n}}))
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "vesselbot_ros.cli", "campaign", str(spec), "--out", str(tmp / tag),
                          "--no-progress"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"vesselbot campaign failed ({res.returncode}):\n{res.stderr}")
    ran = next((ln for ln in res.stdout.splitlines() if ln.startswith("ran ")), "?")
    return wall, ran


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=1000, help="runs (seeds 0..N-1) of each run_many / run-phase round")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2, help="threads of run_many = worker threads of the campaign")
    ap.add_argument("--e2e-runs", type=int, default=1000, help="runs of the end-to-end `vesselbot campaign` (0: skip)")
    ap.add_argument("--config", default=str(ROOT / "config" / "sound_small_artery.yaml"))
    args = ap.parse_args()
    config = Path(args.config).resolve()
    base = load_yaml(config)
    scenario = scenario_from_mapping(base)
    n, w = args.runs, args.workers
    print(f"bench_campaign: {n} runs of {config.name}, {w} threads (run_many) / worker threads (campaign), "
          f"{args.rounds} rounds; "
          f"before: {_load()}")
    t0 = time.perf_counter()
    run_many(scenario, [0, 1], workers=w)  # this process: numba cache loaded, stages built
    print(f"  run_many warmed in {time.perf_counter() - t0:.2f} s")

    best: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        t0 = time.perf_counter()
        with dask_client(None, w) as client:
            t1 = time.perf_counter()
            spec = campaign_spec_from_mapping({"name": "warm", "base": "-", "seeds": [0]})
            warm = prepare(spec, base).tasks
            client.gather([client.submit(run_chunk, warm, None, pure=False, workers=[a])
                           for a in client.scheduler_info()["workers"]])
            print(f"  cluster of {w} worker threads started in {t1 - t0:.2f} s, workers warmed in {time.perf_counter() - t1:.2f} s "
                  f"(not counted below)")
            for r in range(args.rounds):
                t0 = time.perf_counter()
                rows = run_many(scenario, range(n), workers=w)
                wall = time.perf_counter() - t0
                best["run_many"] = min(wall, best.get("run_many", math.inf))
                print(f"  round {r + 1} run_many            {wall:6.2f} s  {n / wall:7.1f} runs/s  "
                      f"{wall * w / n * 1e3:5.2f} ms per run per thread  ({_load()})")
                wall, out, store = _run_phase(base, n, client, tmp / f"phase-{r}")
                best["campaign"] = min(wall, best.get("campaign", math.inf))
                same = _check_identical(rows, store)
                print(f"  round {r + 1} campaign run phase  {wall:6.2f} s  {n / wall:7.1f} runs/s  "
                      f"{out.busy_s / n * 1e3:5.2f} ms per run on a worker, {out.n_tasks} Dask tasks, "
                      f"{same} runs bit-identical to run_many  ({_load()})")
                if args.e2e_runs:  # the bench's cluster idles meanwhile
                    wall, ran = _e2e(config, args.e2e_runs, tmp, f"r{r}")
                    best["e2e"] = min(wall, best.get("e2e", math.inf))
                    print(f"  round {r + 1} end to end: `vesselbot campaign` of {args.e2e_runs} runs {wall:.2f} s  "
                          f"[{ran}]  ({_load()})")
        ratio = best["campaign"] / best["run_many"]
        print(f"run phase / run_many (best of {args.rounds}): {best['campaign']:.2f} s / {best['run_many']:.2f} s = "
              f"x{ratio:.2f} (target <= x{RUN_PHASE_TARGET}: {'met' if ratio <= RUN_PHASE_TARGET else 'NOT met'})")
        if args.e2e_runs:
            e2e = best["e2e"]
            verdict = ("met" if e2e <= E2E_TARGET_S else "NOT met") if args.e2e_runs == 1000 else "target is for 1000 runs"
            print(f"end to end, {args.e2e_runs} runs (interpreter, spec, cluster start, runs, tables, figures; best of "
                  f"{args.rounds}): {e2e:.2f} s (target <= {E2E_TARGET_S:.0f} s on 2 cores: {verdict})")
    print(f"after: {_load()}")


if __name__ == "__main__":
    main()
