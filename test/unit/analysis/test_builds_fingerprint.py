"""Cross-kernel reproducibility of what a machine builds once: the plans, the 3-D wall field, the generated tree.

As ``test/unit/sim/test_fingerprint.py`` does for the per-run loop: each
variant runs ``python -m vesselbot_ros.analysis.builds_fingerprint`` in a fresh
process (OpenBLAS reads ``OPENBLAS_CORETYPE`` and numpy reads
``NPY_DISABLE_CPU_FEATURES`` only when they load), with its own empty cache
folders, so no variant reads what another built; the subprocess reports the
OpenBLAS core it really loaded.  The shipped files themselves (the plans in
``config/plans``, the tree's files) are compared with what the code makes by
``test_plan.py`` and ``test_tree_io.py``; the stored 3-D reference metrics by
``test/unit/sim/test_reference_metrics.py``.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from vesselbot_ros.analysis import builds_fingerprint as bf
from vesselbot_ros.blas_free import convolve_valid, dot3, solve3, sym3_least_eigvec
from vesselbot_ros.sim.fingerprint import cpu_core_types

REPO = Path(__file__).resolve().parents[3]


def _builds(env_extra: dict[str, str], folder: Path) -> dict[str, object]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES", "VESSELBOT_CFD_CACHE", "XDG_CACHE_HOME",
                        "NUMBA_NUM_THREADS", "OMP_WAIT_POLICY")}
    folder.mkdir(parents=True)
    env.update(env_extra, VESSELBOT_CFD_CACHE=str(folder / "cfd"), XDG_CACHE_HOME=str(folder / "xdg"))
    proc = subprocess.run(
        [sys.executable, "-m", "vesselbot_ros.analysis.builds_fingerprint", "--with-cores"],
        env=env, cwd=REPO, capture_output=True, text=True, timeout=1500, check=False,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    out: dict[str, object] = json.loads(proc.stdout)
    assert not any((folder / "cfd").rglob("*")), "the builds must not write (or read) a cache"
    return out


@pytest.mark.slow
@pytest.mark.timeout(1800)  # a subprocess per OpenBLAS kernel (plans, a wall block, the tree); generous for a loaded 2-core machine
@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="OpenBLAS core types are x86-64 names")
def test_once_per_machine_builds_bit_identical_under_every_openblas_kernel_and_numpy_simd_level(tmp_path: Path) -> None:
    cores = cpu_core_types()
    assert cores[-1] == "Nehalem"
    variants: dict[str, dict[str, str]] = {f"OPENBLAS_CORETYPE={c}": {"OPENBLAS_CORETYPE": c} for c in cores}
    # numpy's own SIMD dispatch must not matter either: the oldest kernel's run also has numpy at its baseline
    # (x86-64-v2 only), so that every OpenBLAS kernel and both numpy levels run, in one subprocess per kernel
    variants[f"OPENBLAS_CORETYPE={cores[-1]}"]["NPY_DISABLE_CPU_FEATURES"] = "X86_V3 X86_V4 AVX512_ICL AVX512_SPR"
    # the wall build's parallel loops: the native kernel's run on two threads, the others on one, so that the
    # thread count (a machine's core count) is checked not to matter either; one thread each also keeps two
    # variants at once from oversubscribing the cores (OpenMP's spinning threads cost a third more CPU)
    for i, env in enumerate(variants.values()):
        env.update(NUMBA_NUM_THREADS="2" if i == 0 else "1", OMP_WAIT_POLICY="PASSIVE")
    with ThreadPoolExecutor(max_workers=max(1, min(len(variants), os.cpu_count() or 1))) as pool:
        futures = {name: pool.submit(_builds, env, tmp_path / f"v{i}") for i, (name, env) in enumerate(variants.items())}
        results = {name: f.result() for name, f in futures.items()}
    for name, res in results.items():
        core = name.split("=", 1)[1]
        loaded = res.pop("_openblas")
        assert isinstance(loaded, dict) and loaded, f"{name}: no OpenBLAS found in the subprocess"
        assert set(loaded.values()) == {core}, f"{name}: OpenBLAS loaded {loaded}, not {core}"
    first_name, first = next(iter(results.items()))
    keys = set(first)
    assert {f"plan/{p}" for p in bf.PLAN_PRESETS} <= keys
    assert {"tree/generated.vtp", "tree/generated.yaml", "tree/imported"} <= keys
    wall = bf.WALL_BLOCK[0]
    assert {f"wall/{wall}/{n}" for n in ("field", "fine", "d", "surface")} <= keys
    # the block exercises every kind of cell the full build makes (a regression there would go unseen otherwise)
    cells = dict(kv.split("=") for kv in str(first[f"wall/{wall}/cells"]).split())
    assert all(float(cells[k]) > 0 for k in ("model_cells_1", "model_cells_2", "model_cells_3", "list_cells",
                                             "refined_blocks", "exact_cells")), cells
    for name, res in results.items():
        assert set(res) == keys, name
        differing = sorted(k for k in keys if res[k] != first[k])
        assert not differing, f"{name} differs from {first_name} on {differing}"


def test_convolve_valid_is_numpys_convolution_to_rounding_and_sums_a_long_kernel_in_one_order() -> None:
    rng = np.random.default_rng(0)
    x = rng.standard_normal(300)
    for n in (1, 5, 16, 21, 31, 32, 47, 300):
        w = rng.standard_normal(n)
        got, ref = convolve_valid(x, w), np.convolve(x, w, mode="valid")
        assert got.shape == ref.shape
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-13 * float(np.abs(w).sum()) * float(np.abs(x).max()))
    # 21 taps (the planner's): the products in 16 partial sums (folded pairwise), then the last five one by one
    w = rng.standard_normal(21)
    p = [x[i:i + 280] * w[::-1][i] for i in range(21)]
    half = [[p[4 * k] + p[4 * k + 2], p[4 * k + 1] + p[4 * k + 3]] for k in range(4)]
    pair = [(half[0][j] + half[1][j]) + (half[2][j] + half[3][j]) for j in range(2)]
    acc = pair[0] + pair[1]
    for i in range(16, 21):
        acc = acc + p[i]
    assert np.array_equal(convolve_valid(x, w), acc)


def test_the_compiled_3x3_helpers_agree_with_lapack_to_rounding() -> None:
    rng = np.random.default_rng(1)
    for trial in range(300):
        n = rng.standard_normal((30, 3))
        n[:, 2] *= 1e-3 if trial % 2 else 1.0  # nearly planar normals: a cylinder's
        n /= np.linalg.norm(n, axis=1)[:, None]
        mm = n.T @ n
        w, v = np.linalg.eigh(mm)
        lam, t = sym3_least_eigvec(mm)
        assert abs(lam - w[0]) <= 1e-14 * w[-1]
        if w[1] - w[0] > 1e-6 * w[-1]:
            assert abs(abs(float(v[:, 0] @ t)) - 1.0) < 1e-12
        assert abs(t).max() == max(t)  # one vector of the two: its largest component positive
        a, b = rng.standard_normal((3, 3)), rng.standard_normal(3)
        det, x = solve3(a, b)
        assert det == pytest.approx(np.linalg.det(a), rel=1e-12)
        np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-9, atol=1e-12)
        u, q = rng.standard_normal(3), rng.standard_normal(3)
        assert dot3(u, q) == (u[0] * q[0] + u[1] * q[1]) + u[2] * q[2]
    det, x = solve3(np.zeros((3, 3)), np.ones(3))
    assert det == 0.0 and np.isnan(x).all()
