"""``vesselbot campaign``: Monte-Carlo runs and parameter sweeps of the pure closed loop.

::

    vesselbot campaign SPEC.yaml [--out DIR] [--scheduler tcp://HOST:PORT] [--workers N]
                                 [--chunk-size N] [--run-timeout-s S] [--set KEY=VALUE ...] [--retry-failed]
                                 [--no-progress]
    vesselbot campaign report DIR

The spec format is in :mod:`vesselbot_ros.campaign.spec`, the folder layout and
the results table in :mod:`vesselbot_ros.campaign.store`, the summary and
figures in :mod:`vesselbot_ros.campaign.summary`.  Running the same command
again resumes: finished runs (found by their content hash) are not run again.

Exit codes: 0 every run is ``ok``, or some failed (their errors are in the
table); 1 every run failed, or some runs completed but cannot be trusted
(status ``rejected_commands``: the coil rejected controller commands and
ramped to zero; or ``diverged``), said in one warning line with their count;
2 bad input.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

from vesselbot_ros.config import ConfigError, check_positive
from vesselbot_ros.progress import add_progress_argument, suppressed

__all__ = ["register", "run"]


def register(parser: argparse.ArgumentParser) -> None:
    """Add the ``campaign`` arguments."""
    parser.add_argument("spec", metavar="SPEC.yaml|report",
                        help="campaign spec (e.g. config/campaigns/vf_error_seeds.yaml), or 'report' followed by DIR")
    parser.add_argument("dir", nargs="?", default=None, metavar="DIR",
                        help="with 'report': the campaign folder whose summary and figures to redraw")
    parser.add_argument("--out", default=None, help="campaign folder (default out/campaigns/<name>/)")
    parser.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                        help="run on this existing Dask scheduler instead of a local cluster")
    parser.add_argument("--workers", type=int, default=None,
                        help="parallel runs (threads of the local cluster's worker process; default: one per usable core)")
    parser.add_argument("--chunk-size", type=int, default=None,
                        help="runs per Dask task (default: the spec's chunk_size; 0 = automatic)")
    parser.add_argument("--run-timeout-s", type=float, default=None, metavar="S",
                        help="wall-clock budget of one run; a run over it is stopped and recorded with status "
                             "'timeout' (default: the spec's run_timeout_s; none if it has none)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a base-scenario value for every run, dotted key, YAML value "
                             "(e.g. sim.duration_s=0.5); repeatable")
    parser.add_argument("--retry-failed", action="store_true",
                        help="run again the runs recorded as failed or timed out")
    add_progress_argument(parser)


def _import_report_libraries() -> None:
    # deferred: the whole point of this function: the report's heavy libraries load on a thread while the runs go
    import matplotlib

    matplotlib.use("Agg")
    # deferred: as above (matplotlib's pyplot, and scipy.special for the confidence intervals)
    import matplotlib.pyplot
    import scipy.special  # noqa: F401


def report(root: Path) -> int:
    """Redraw the summary and figures of the campaign folder ``root``."""
    # deferred: the store pulls in pyarrow (~0.3 s); `vesselbot campaign --help` imports this module
    from vesselbot_ros.campaign.store import CampaignStore
    from vesselbot_ros.campaign.summary import write_report

    store = CampaignStore(root)
    meta = store.meta()
    rows = store.results().to_pylist()
    _, text = write_report(rows, meta, root)
    print(text, end="")
    print(f"-> {root}/summary.md, summary.csv, results.parquet, figures/")
    return 0


def run(args: argparse.Namespace) -> int:
    """Run (or resume) a campaign, or redraw a report; return the exit code."""
    if args.spec == "report":
        if not args.dir:
            raise ConfigError("campaign report needs the campaign folder: vesselbot campaign report DIR")
        return report(Path(args.dir))
    if args.dir is not None:
        raise ConfigError(f"unexpected argument {args.dir!r} after the spec (did you mean 'campaign report DIR'?)")
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {args.workers!r}")
    if args.chunk_size is not None and args.chunk_size < 0:
        raise ConfigError(f"--chunk-size must be >= 0, got {args.chunk_size!r}")
    if args.run_timeout_s is not None:
        check_positive("--run-timeout-s", args.run_timeout_s)
    if args.scheduler and args.workers is not None:
        raise ConfigError("--workers sizes the local cluster; it does not apply with --scheduler")

    # deferred: the engine, the spec and the scenario pull in pyarrow and the compiled core (~0.7 s);
    # `vesselbot campaign --help` imports this module
    from vesselbot_ros.campaign.engine import Progress, dask_client, execute, local_worker_count, pending, prepare
    from vesselbot_ros.campaign.spec import load_campaign_spec
    from vesselbot_ros.campaign.store import CampaignStore
    from vesselbot_ros.campaign.summary import write_report
    from vesselbot_ros.sim.scenario import overridden, scenario_from_mapping, scenario_overrides

    spec_path = Path(args.spec)
    spec, base = load_campaign_spec(spec_path)
    sets = scenario_overrides(args.set)  # the one --set parser (bounded YAML), as simulate and run read it
    if sets:
        base = overridden(base, sets)
        try:
            scenario_from_mapping(base)
        except ConfigError as exc:
            raise ConfigError(f"--set: {exc}") from None
    prepared = prepare(spec, base)
    root = Path(args.out) if args.out else Path("out") / "campaigns" / spec.name
    store = CampaignStore(root)
    budget = spec.run_timeout_s if args.run_timeout_s is None else args.run_timeout_s
    meta = {
        "name": spec.name,
        "spec": str(spec_path),
        "set": args.set,
        "code_version": prepared.code,
        "n_runs": len({t.run_id for t in prepared.tasks}),
        "n_seeds": len(spec.seed_list()),
        "grid_keys": list(spec.group_keys()),
        "varied_keys": list(spec.varied_keys()),
        "run_timeout_s": budget,
        "written_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    store.write_manifest(prepared.manifest, meta, spec_path.read_text(encoding="utf-8"))
    chunk = spec.chunk_size if args.chunk_size is None else args.chunk_size
    todo = pending(prepared.tasks, store, args.retry_failed)
    n_before = meta["n_runs"] - len(todo)
    where = args.scheduler or f"a local cluster of {args.workers or local_worker_count()} worker thread(s)"
    print(f"campaign {spec.name}: {meta['n_runs']} runs, {n_before} already in {root}, code {prepared.code}"
          + (f", running {len(todo)} on {where}" if todo else ""), file=sys.stderr)
    closing: list[threading.Thread] = []  # the cluster closes while the report is drawn
    if todo:
        # the report's imports (matplotlib: 0.3 s) happen while this process waits for the runs
        threading.Thread(target=_import_report_libraries, name="vesselbot-report-imports", daemon=True).start()
        progress = Progress(f"campaign {spec.name}", meta["n_runs"], n_before, enabled=not suppressed(args.no_progress))
        try:
            with dask_client(args.scheduler, args.workers, closing) as client:
                outcome = execute(todo, store, client, prepared.code, chunk_size=chunk, progress=progress,
                                  run_timeout_s=budget)
        except KeyboardInterrupt:
            print(f"\ncampaign {spec.name}: interrupted; finished runs are saved in {root}: "
                  f"run the same command again to resume", file=sys.stderr)
            return 130
        rate = outcome.n_ran / outcome.wall_s if outcome.wall_s > 0 else float("nan")
        over = f", {outcome.n_timeout} of them over the run budget" if outcome.n_timeout else ""
        ran = (f"ran {outcome.n_ran} runs ({outcome.n_failed} failed{over}) in {outcome.wall_s:.1f} s on {outcome.n_workers} "
               f"worker thread(s): {rate:.2f} runs/s in {outcome.n_tasks} Dask tasks")
    else:
        ran = "nothing to run"
    try:
        rows = store.assemble().to_pylist()
        _, text = write_report(rows, store.meta(), root)
    finally:
        for thread in closing:
            thread.join()
    print(text, end="")
    print(f"{ran}; {n_before} run(s) were already done")
    print(f"-> {root}/results.parquet, summary.md, summary.csv, figures/")
    n_failed_total = sum(1 for r in rows if r.get("status") in ("error", "timeout"))
    if n_failed_total:
        print(f"campaign {spec.name}: {n_failed_total} run(s) failed or ran over the run budget; their errors are in "
              f"the 'error' column of results.parquet", file=sys.stderr)
    # runs that completed but cannot be trusted: commands the coil rejected (it ramped to zero), or diverged
    untrusted = [r for r in rows if r.get("status") not in ("ok", "error", "timeout", None)]
    if untrusted:
        n_rej = sum(1 for r in untrusted if r.get("status") == "rejected_commands")
        print(f"vesselbot: warning: campaign {spec.name}: {len(untrusted)} of {len(rows)} run(s) completed but cannot "
              f"be trusted ({n_rej} on rejected controller commands, {len(untrusted) - n_rej} diverged or other); "
              f"their status and warning line are in the 'status' and 'error' columns of results.parquet",
              file=sys.stderr)
        return 1
    return 1 if rows and n_failed_total == len(rows) else 0
