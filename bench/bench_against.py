"""The compiled loop of this checkout against another commit's, side by side in one run (prints figures, asserts nothing).

A restructuring of the loop (issue 40: one loop on any number of axes) must not slow it down.  This bench exports
``--ref`` (default ``HEAD~1``) with ``git archive`` into a temporary folder and times the same runs in both trees,
in subprocesses that take turns (so the machine's drift falls on both alike); each subprocess compiles first
(untimed: numba's cache is per tree) and then times ``--runs`` warm runs in-process, in CPU time.  Printed per
case: the fastest and the median CPU ms per simulated second of each tree, and new / ref of each (the fastest is
the cost with the least interference from other work: interference only adds).

Cases:

1. ``sound_small_artery`` (the planar paper loop, 2 s), compiled;
2. ``sound_small_artery_ekf`` (the extended Kalman filter and the flow-compensating law), compiled;
3. ``paper_iiic_network_upper`` (the planar network) and ``paper_iiic_network_upper_3d`` (the same route as a 3-D
   tree), compiled, as ms per simulated second, and the 3-D run's cost over the planar one's in each tree
   (issue 40's target: <= 1.5x).

Usage: .venv/bin/python bench/bench_against.py [--ref REF] [--runs N] [--rounds K]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CASES = ("sound_small_artery", "sound_small_artery_ekf", "paper_iiic_network_upper", "paper_iiic_network_upper_3d")
TIMER = """
import sys, time
from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios
sc = load_scenario(shipped_scenarios()[sys.argv[1]])
r = run_closed_loop(sc, 0)  # compiles (or loads the cache), builds the flow and wall lookups
assert r.path == "compiled", r.path
out = []
for seed in range(int(sys.argv[2])):
    t0 = time.process_time()  # this process's CPU time: what other jobs on the machine add shows less than in wall time
    run_closed_loop(sc, seed)
    out.append((time.process_time() - t0) * 1e3 / sc.sim.duration_s)
print(" ".join(repr(v) for v in out))
"""


def _times(tree: Path, case: str, runs: int) -> list[float]:
    env = {**os.environ, "PYTHONPATH": str(tree), "VESSELBOT_NO_PROGRESS": "1"}
    proc = subprocess.run([sys.executable, "-c", TIMER, case, str(runs)], cwd=tree, env=env, capture_output=True,
                          text=True, timeout=3600)
    if proc.returncode != 0:
        raise SystemExit(f"bench_against: {case} in {tree} exited {proc.returncode}:\n{proc.stderr[-2000:]}")
    return [float(v) for v in proc.stdout.split()]


#: The commit issue 40 measured "today" on (before one loop on any number of axes): the benches' default reference.
ISSUE_40_BASE = "783b807"


def side_by_side(ref: str, cases: list[str], runs: int = 5, rounds: int = 3,
                 ratios: tuple[tuple[str, str, str], ...] = ()) -> dict[tuple[str, str], float]:
    """Time ``cases`` in the ``ref`` commit and in this checkout, taking turns; print one line per case (fastest
    and median CPU ms per simulated second, new / ref) and, for each ``(numerator, denominator, label)`` of
    ``ratios``, the two cases' ratio in each tree.  Returns the fastest figures by ``(case, "ref" | "new")``."""
    rev = subprocess.run(["git", "rev-parse", "--short", ref], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout.strip()
    print(f"this checkout against {rev} (load average {os.getloadavg()[0]:.2f}); CPU ms per simulated s, "
          f"{rounds} x {runs} warm runs each, taking turns")
    medians: dict[tuple[str, str], float] = {}
    fastest: dict[tuple[str, str], float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        ref_tree = Path(tmp) / "ref"
        ref_tree.mkdir()
        archive = subprocess.run(["git", "archive", rev], cwd=ROOT, capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(ref_tree)], input=archive, check=True)
        for case in cases:
            got: dict[str, list[float]] = {"ref": [], "new": []}
            for _ in range(rounds):
                got["ref"] += _times(ref_tree, case, runs)
                got["new"] += _times(ROOT, case, runs)
            for tree in ("ref", "new"):
                medians[(case, tree)] = statistics.median(got[tree])
                fastest[(case, tree)] = min(got[tree])
            r, n = fastest[(case, "ref")], fastest[(case, "new")]
            mr, mn = medians[(case, "ref")], medians[(case, "new")]
            print(f"  {case:28s} fastest: {rev} {r:7.2f}  this {n:7.2f}  this/{rev} {n / r:5.3f};  "
                  f"median: {mr:7.2f} {mn:7.2f}  {mn / mr:5.3f}")
    for num, den, label in ratios:
        for tree, name in (("ref", rev), ("new", "this")):
            if (num, tree) in fastest and (den, tree) in fastest:
                print(f"  {label} ({name}): {fastest[(num, tree)] / fastest[(den, tree)]:.2f}x")
    print(f"  load average after: {os.getloadavg()[0]:.2f}")
    return fastest


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref", default="HEAD~1", help="the commit to compare with (git rev)")
    ap.add_argument("--runs", type=int, default=5, help="timed runs per subprocess")
    ap.add_argument("--rounds", type=int, default=3, help="subprocesses per tree and case, taking turns")
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated shipped scenarios (default: all four)")
    args = ap.parse_args()
    side_by_side(args.ref, [c for c in args.cases.split(",") if c], args.runs, args.rounds,
                 ratios=(("paper_iiic_network_upper_3d", "paper_iiic_network_upper",
                          "3-D tree / planar network, same route [issue 40 target <= 1.5x]"),))
    return 0


if __name__ == "__main__":
    sys.exit(main())
