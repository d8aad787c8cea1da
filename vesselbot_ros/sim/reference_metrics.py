"""Stored reference metrics: seeds 0-4 of every shipped scenario, compared within 1e-12 relative.

``tools/gen_reference_metrics.py`` regenerates ``test/data/reference_metrics.json``
(:func:`compute_reference`); ``test/unit/sim/test_reference_metrics.py`` reruns
every run and fails, naming each number that moved, when :func:`compare` finds a
difference.  A numpy, scipy, numba or glibc upgrade that changes a result by
more than 1e-12 relative therefore fails loudly; if the change is understood,
regenerate the file and commit it with the reason.

The file also records the library versions it was made with, so the failure
message can say what changed since.
"""

from __future__ import annotations

import json
import math
import platform
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import llvmlite
import numba
import numpy
import scipy

from vesselbot_ros.sim.closed_loop import run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios

__all__ = ["REFERENCE_FILE", "RTOL", "library_versions", "compute_reference", "compare", "load_reference"]

REFERENCE_FILE = Path(__file__).resolve().parents[2] / "test" / "data" / "reference_metrics.json"
RTOL = 1e-12
SEEDS = range(5)


def library_versions() -> dict[str, str]:
    """Versions of everything that can move a number: Python, numpy, scipy, numba, llvmlite, libc."""
    libc = "-".join(platform.libc_ver())
    return {
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,
        "llvmlite": llvmlite.__version__,
        "libc": libc,
    }


def compute_reference(names: Iterable[str] | None = None) -> dict[str, Any]:
    """Run seeds 0-4 of the shipped scenarios; ``{"versions": ..., "runs": {"<name>/<seed>": metrics}}``."""
    scenarios = shipped_scenarios()
    runs: dict[str, dict[str, Any]] = {}
    for name in sorted(names if names is not None else scenarios):
        scenario = load_scenario(scenarios[name])
        for seed in SEEDS:
            metrics = run_closed_loop(scenario, seed).metrics
            runs[f"{name}/{seed}"] = {k: v for k, v in sorted(metrics.items()) if isinstance(v, int | float)}
    return {"rtol": RTOL, "versions": library_versions(), "runs": runs}


def load_reference(path: Path = REFERENCE_FILE) -> dict[str, Any]:
    """The stored reference (see :func:`compute_reference`)."""
    data: dict[str, Any] = json.loads(Path(path).read_text(encoding="utf-8"))
    return data


def _close(a: float, b: float, rtol: float) -> bool:
    if isinstance(a, bool) or isinstance(b, bool) or (isinstance(a, int) and isinstance(b, int)):
        return a == b
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return abs(a - b) <= rtol * max(abs(a), abs(b))


def compare(stored: Mapping[str, Any], now: Mapping[str, Any], rtol: float = RTOL) -> list[str]:
    """Every difference between two references, one line each (empty: they agree).

    Integers (step counts, contact counts) must be equal; floats within ``rtol``
    relative (NaN equals NaN).  A run or a metric present in one and not the
    other is a difference too.
    """
    lines: list[str] = []
    s_runs, n_runs = stored["runs"], now["runs"]
    for run in sorted(set(s_runs) | set(n_runs)):
        if run not in n_runs or run not in s_runs:
            lines.append(f"{run}: {'missing now' if run not in n_runs else 'not in the stored file'}")
            continue
        a, b = s_runs[run], n_runs[run]
        for key in sorted(set(a) | set(b)):
            if key not in a or key not in b:
                lines.append(f"{run} {key}: {'missing now' if key not in b else 'not in the stored file'}")
            elif not _close(a[key], b[key], rtol):
                rel = abs(a[key] - b[key]) / max(abs(a[key]), abs(b[key]), 1e-300)
                lines.append(f"{run} {key}: stored {a[key]!r}, now {b[key]!r} (relative difference {rel:.3g})")
    if lines:
        sv, nv = stored.get("versions", {}), now.get("versions", {})
        changed = [f"{k} {sv.get(k)} -> {nv.get(k)}" for k in sorted(set(sv) | set(nv)) if sv.get(k) != nv.get(k)]
        lines.append("library versions: " + (", ".join(changed) if changed else "unchanged since the file was made"))
    return lines
