"""Bit-level fingerprints of closed-loop runs, for the reproducibility guarantees.

A run's fingerprint is the SHA-256 of every time-series column (name, dtype,
shape and raw bytes, columns in sorted order) and of every metric (``repr`` of
the value, which round-trips a float exactly).  Two runs with the same
fingerprint are bit-identical on every column, metric and run statistic.

``python -m vesselbot_ros.sim.fingerprint`` prints one line per shipped
scenario and seed (seeds 0-4 by default): the cross-kernel test runs it in
subprocesses under different OpenBLAS core types and compares the lines.
"""

from __future__ import annotations

import argparse
import ctypes
import hashlib
import json
import sys
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from vesselbot_ros.sim.closed_loop import SimResult, run_closed_loop
from vesselbot_ros.sim.scenario import load_scenario, shipped_scenarios

__all__ = ["fingerprint", "fingerprint_series", "fingerprint_runs", "openblas_cores", "cpu_core_types"]


def fingerprint_series(series: Mapping[str, Any]) -> str:
    """SHA-256 (hex) of the columns of a time-series dict, bit for bit."""
    h = hashlib.sha256()
    for key in sorted(series):
        a = np.ascontiguousarray(series[key])
        h.update(f"{key}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def fingerprint(result: SimResult) -> str:
    """SHA-256 (hex) of a run: every time-series column and every metric, bit for bit."""
    h = hashlib.sha256(fingerprint_series(result.timeseries).encode())
    for key in sorted(result.metrics):
        h.update(f"{key}={result.metrics[key]!r};".encode())
    return h.hexdigest()


def fingerprint_runs(names: Iterable[str], seeds: Iterable[int]) -> dict[str, str]:
    """``{"<scenario>/<seed>": fingerprint}`` for the shipped scenarios ``names``."""
    out: dict[str, str] = {}
    seeds = list(seeds)
    for name in names:
        scenario = load_scenario(shipped_scenarios()[name])
        for seed in seeds:
            out[f"{name}/{seed}"] = fingerprint(run_closed_loop(scenario, seed))
    return out


def openblas_cores() -> dict[str, str]:
    """``{library file: OpenBLAS core name}`` for the OpenBLAS copies numpy and scipy loaded.

    Reads ``*_get_corename*`` of every ``libscipy_openblas`` mapped into this
    process, so a caller can check which kernel family (``Haswell``,
    ``SkylakeX``, ...) ``OPENBLAS_CORETYPE`` actually selected.
    """
    # deferred: imported only to load scipy's own OpenBLAS copy (~0.3 s), which only this probe wants mapped
    import scipy.linalg  # noqa: F401

    out: dict[str, str] = {}
    with open("/proc/self/maps", encoding="utf-8") as fh:
        libs = sorted({line.split()[-1] for line in fh if "openblas" in line and line.rstrip().endswith(".so")})
    for lib in libs:
        dll = ctypes.CDLL(lib)
        for sym in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename", "openblas_get_corename"):
            fn = getattr(dll, sym, None)
            if fn is not None:
                fn.restype = ctypes.c_char_p
                out[lib.rsplit("/", 1)[-1]] = fn().decode()
                break
    return out


def cpu_core_types() -> list[str]:
    """OpenBLAS core types this x86-64 CPU can execute, newest first (read from ``/proc/cpuinfo``'s flags):
    ``SkylakeX`` (AVX-512), ``Haswell`` (AVX2 and FMA), and always ``Nehalem`` (SSE4.2: every CPU numpy 2.x runs
    on, its baseline being x86-64-v2)."""
    flags: set[str] = set()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    break
    except OSError:
        pass
    cores = []
    if {"avx512f", "avx512dq", "avx512bw", "avx512vl", "avx512cd"} <= flags:
        cores.append("SkylakeX")
    if {"avx2", "fma"} <= flags:
        cores.append("Haswell")
    cores.append("Nehalem")
    return cores


def main(argv: list[str] | None = None) -> int:
    """Print the fingerprints of shipped scenarios as JSON on stdout."""
    ap = argparse.ArgumentParser(prog="python -m vesselbot_ros.sim.fingerprint", description=__doc__)
    ap.add_argument("--scenario", action="append", help="shipped scenario name (repeatable; default: all)")
    ap.add_argument("--seeds", type=int, default=5, help="seeds 0..N-1 (default 5)")
    ap.add_argument("--with-cores", action="store_true", help="also report the OpenBLAS cores in use (key '_openblas')")
    args = ap.parse_args(argv)
    names = args.scenario or sorted(shipped_scenarios())
    out: dict[str, Any] = dict(fingerprint_runs(names, range(args.seeds)))
    if args.with_cores:
        out["_openblas"] = openblas_cores()
    json.dump(out, sys.stdout, indent=1, sort_keys=True)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
