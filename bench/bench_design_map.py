"""Benchmark: the full Fig. 7 set (12 maps at 200x200) and the numba kernel.

Run:  .venv/bin/python bench/bench_design_map.py

Prints the design-map wall time (target <= 2 s on 2 cores), the time per
``accel()`` call from Python and inside an njit loop, and the kernel's
first-call compile time versus its cached-load time (both measured in fresh
subprocesses with a private NUMBA_CACHE_DIR).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

_FIRST_CALL = """
import time, numpy as np
t0 = time.perf_counter()
from vesselbot_ros.physics import kernel
from vesselbot_ros.physics.params import PhysicsParams
p = kernel.pack_params(PhysicsParams()); c = np.zeros(4)
t1 = time.perf_counter()
kernel.accel(0.1, 0.0, 1e-4, 0.0, 0.0, 0.0, 0.0, c, p)
kernel.update_contact(c, -1e-6, p)
print(t1 - t0, time.perf_counter() - t1)
"""


def _first_call(cache_dir: str) -> tuple[float, float]:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", _FIRST_CALL], env=env, capture_output=True, text=True, check=True)
    a, b = out.stdout.split()
    return float(a), float(b)


def main() -> int:
    import numba
    import numpy as np

    from vesselbot_ros.analysis.design_map import DesignStudy, all_design_maps
    from vesselbot_ros.physics import kernel
    from vesselbot_ros.physics.params import PhysicsParams

    params = PhysicsParams()
    study = DesignStudy()
    all_design_maps(params, study)  # warm-up (imports, caches)
    runs = []
    for _ in range(5):
        t0 = time.perf_counter()
        maps = all_design_maps(params, study)
        runs.append(time.perf_counter() - t0)
    n = study.grid.n_lambda * study.grid.n_delta
    print(f"design maps: {len(maps)} maps x {study.grid.n_lambda}x{study.grid.n_delta} "
          f"({len(maps) * n} points): best {min(runs):.3f} s, median {sorted(runs)[2]:.3f} s (target <= 2 s)")

    p = kernel.pack_params(params)
    c = np.zeros(4)
    kernel.accel(0.1, 0.0, 1e-4, 0.0, 0.0, 0.0, 0.0, c, p)
    n_calls = 20000
    t0 = time.perf_counter()
    for i in range(n_calls):
        kernel.accel(0.1 + i * 1e-6, 0.0, 1e-4, 0.01, 0.0, 0.01, 0.02, c, p)
    py = (time.perf_counter() - t0) / n_calls

    @numba.njit
    def loop(n: int, c: np.ndarray, p: np.ndarray) -> float:
        s = 0.0
        for i in range(n):
            ax, az = kernel.accel(0.1 + i * 1e-6, 0.0, 1e-4 + i * 1e-10, 0.01, 0.0, 0.01, 0.02, c, p)
            s += ax + az
        return s

    loop(10, c, p)
    n_loop = 1_000_000
    t0 = time.perf_counter()
    loop(n_loop, c, p)
    jit = (time.perf_counter() - t0) / n_loop
    print(f"kernel.accel: {py * 1e6:.2f} us per call from Python, {jit * 1e9:.0f} ns per call inside an njit loop")

    with tempfile.TemporaryDirectory() as tmp:
        imp1, first = _first_call(tmp)
        imp2, cached = _first_call(tmp)
    print(f"kernel first call: {first:.2f} s with an empty cache (compile), {cached:.3f} s from the cache "
          f"(import + pack_params: {imp1:.2f} s / {imp2:.2f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
