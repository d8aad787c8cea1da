"""numba caches are dropped whenever any compiled source changes (never a cache from other code)."""

from __future__ import annotations

from pathlib import Path

from vesselbot_ros import numba_cache


def _fake_package(root: Path) -> list[Path]:
    caches = []
    for d in ("physics", "control", "sim"):
        (root / d / "__pycache__").mkdir(parents=True)
        (root / d / "mod.py").write_text(f"import numba  # {d}\n")
        for ext in ("nbi", "nbc"):
            f = root / d / "__pycache__" / f"mod.fn-1.py311.{ext}"
            f.write_bytes(b"x")
            caches.append(f)
    (root / "blas_free.py").write_text("import numba  # blas\n")
    (root / "runner.py").write_text("# no compiled code here\n")
    (root / "__pycache__").mkdir()
    return caches


def test_cache_dropped_when_any_numba_source_changes(tmp_path: Path) -> None:
    caches = _fake_package(tmp_path)
    assert numba_cache.ensure_fresh(tmp_path)  # no stamp yet: start clean
    assert not any(f.exists() for f in caches)
    for f in caches:
        f.write_bytes(b"x")
    assert not numba_cache.ensure_fresh(tmp_path)  # same sources: the cache is kept
    assert all(f.exists() for f in caches)
    # an edit to a module that another module's compiled code inlines drops every cache
    (tmp_path / "physics" / "mod.py").write_text("# physics, edited\n")
    assert numba_cache.ensure_fresh(tmp_path)
    assert not any(f.exists() for f in caches)
    assert not numba_cache.ensure_fresh(tmp_path)
    (tmp_path / "runner.py").write_text("# edited, still no compiled code\n")
    assert not numba_cache.ensure_fresh(tmp_path)  # a module without numba code keeps the cache
    (tmp_path / "blas_free.py").write_text("import numba  # blas, edited\n")
    assert numba_cache.ensure_fresh(tmp_path)


def test_the_installed_package_is_stamped_with_its_own_sources() -> None:
    stamp = numba_cache.ROOT / "__pycache__" / numba_cache.STAMP_NAME
    assert stamp.read_text() == numba_cache.source_digest()
