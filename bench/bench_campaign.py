"""Campaign throughput on Dask: runs/s with one and two workers, scaling, and the engine's overhead.

Usage: .venv/bin/python bench/bench_campaign.py [--runs N] [--rounds R] [--config config/paper_small_artery.yaml]

Measured side by side in one process, by default on the paper scenario as
printed (``config/paper_small_artery.yaml``, 2 s of the Section III-C closed
loop, about 1 s per run: the issue's reference for the engine's overhead), over
fresh seeds in every phase so no run is ever found already done.  With
``--config config/sound_small_artery.yaml`` (about 20 ms per run in the
compiled loop) the engine's fixed cost per Dask task (about 10 ms: scheduling,
one Parquet part) shows as 5-10 % of 40 runs; campaigns of such short runs
should use larger ``chunk_size``.  The phases:

* ``in-process``: the same chunk function called in a plain loop, no Dask;
* ``1 worker`` / ``2 workers``: the real engine path of ``vesselbot campaign``
  (:func:`~vesselbot_ros.campaign.engine.execute`: chunking, scheduling,
  serialisation, writing every part to disk) on a LocalCluster of one / two
  single-threaded worker processes, started and warmed (numba cache loaded)
  before the clock starts.

The phases alternate for ``--rounds`` rounds and the best round of each is
kept, so a burst of load from other users of the shared machine hits all of
them alike.  Printed: runs/s of each phase, scaling efficiency
``rate(2) / (2 rate(1))`` (target >= 80 %), and the engine's overhead per run
with one worker, ``(wall - sum of the runs' own times) / sum of the runs' own
times`` (target < 5 %), next to the same ratio against the in-process loop.
The scaling is split into what the engine can lose (the share of the wall
time the two workers spend inside runs) and what the machine takes (how much
slower one run is with two workers than with one: other users' load, shared
caches), since on a shared machine only the first is the engine's.
The machine's load average is printed before and after.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from vesselbot_ros.campaign.engine import execute, prepare
from vesselbot_ros.campaign.runner import run_chunk
from vesselbot_ros.campaign.spec import campaign_spec_from_mapping
from vesselbot_ros.campaign.store import CampaignStore
from vesselbot_ros.config import load_yaml

ROOT = Path(__file__).resolve().parents[1]


def _tasks(base: dict, first_seed: int, n: int) -> tuple[list, str]:
    spec = campaign_spec_from_mapping({"name": "bench", "base": "-", "seeds": {"start": first_seed, "count": n}})
    prep = prepare(spec, base)
    return prep.tasks, prep.code


def _load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f} / {five:.2f} / {fifteen:.2f} (1/5/15 min) on {os.cpu_count()} cores"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=16, help="runs per phase and round")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--config", default=str(ROOT / "config" / "paper_small_artery.yaml"))
    args = ap.parse_args()
    from distributed import Client, LocalCluster

    base = load_yaml(args.config)
    print(f"bench_campaign: {args.runs} runs of {Path(args.config).name} per phase, {args.rounds} rounds; before: {_load()}")
    seed = 1000
    warm, code = _tasks(base, 0, 1)
    t0 = time.perf_counter()
    run_chunk(warm, code)
    print(f"  in-process first run (numba cache load / JIT): {time.perf_counter() - t0:.2f} s")

    best: dict[str, tuple[float, float]] = {}  # phase -> (wall s, sum of run times s)
    chunks: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as tmp, \
            LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0") as c1, \
            LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as c2, \
            Client(c1) as k1, Client(c2) as k2:
        t0 = time.perf_counter()
        for client, n in ((k1, 1), (k2, 2)):  # warm every worker: one run each
            tasks, _ = _tasks(base, 0, n)
            client.gather([client.submit(run_chunk, [t], code, pure=False, workers=[w])
                           for t, w in zip(tasks, client.scheduler_info()["workers"])])
        print(f"  clusters started and workers warmed in {time.perf_counter() - t0:.1f} s (not counted below)")
        for r in range(args.rounds):
            for phase, client in (("in-process", None), ("1 worker", k1), ("2 workers", k2)):
                tasks, _ = _tasks(base, seed, args.runs)
                seed += args.runs
                if client is None:
                    t0 = time.perf_counter()
                    recs = run_chunk(tasks, code)
                    wall = time.perf_counter() - t0
                    busy = sum(x["run_time_s"] for x in recs)
                    chunks[phase] = 1
                else:
                    store = CampaignStore(Path(tmp) / f"{phase}-{r}")
                    out = execute(tasks, store, client, code)
                    wall, busy = out.wall_s, out.busy_s
                    chunks[phase] = out.n_tasks
                    assert out.n_failed == 0
                print(f"  round {r + 1} {phase:<10} {args.runs / wall:6.2f} runs/s  ({wall:.2f} s wall, "
                      f"{busy / args.runs * 1e3:.1f} ms per run on the worker)")
                if phase not in best or wall < best[phase][0]:
                    best[phase] = (wall, busy)

    rate = {p: args.runs / w for p, (w, _) in best.items()}
    w1, busy1 = best["1 worker"]
    print(f"runs/s (best of {args.rounds} rounds): in-process {rate['in-process']:.2f}, 1 worker {rate['1 worker']:.2f} "
          f"({chunks['1 worker']} Dask tasks), 2 workers {rate['2 workers']:.2f} ({chunks['2 workers']} Dask tasks)")
    eff = rate["2 workers"] / (2 * rate["1 worker"])
    print(f"scaling 1 -> 2 workers: x{rate['2 workers'] / rate['1 worker']:.2f}, efficiency {eff:.0%} "
          f"(target >= 80 %: {'met' if eff >= 0.8 else 'NOT met'})")
    w2, busy2 = best["2 workers"]
    util = busy2 / (2 * w2)
    slow = (busy2 / args.runs) / (busy1 / args.runs)
    print(f"  where the scaling goes: the 2 workers were inside runs {util:.0%} of the wall time (what the engine "
          f"can lose), and one run took x{slow:.2f} the time it took with 1 worker (the CPU share the machine gave: "
          f"x1.00 on an idle machine)")
    ovh = (w1 - busy1) / busy1
    vs_plain = w1 / best["in-process"][0] - 1
    print(f"engine overhead per run, 1 worker: {ovh:.1%} of the run time (wall {w1:.2f} s vs {busy1:.2f} s inside the runs; "
          f"target < 5 %: {'met' if ovh < 0.05 else 'NOT met'}); against the in-process loop: {vs_plain:+.1%}")
    print(f"after: {_load()}")


if __name__ == "__main__":
    main()
