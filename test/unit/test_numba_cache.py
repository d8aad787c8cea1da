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


def test_a_users_compiled_module_loses_its_cache_when_ours_changes(tmp_path: Path) -> None:
    """A user's compiled kind calls and inlines our functions: its module's numba cache, keyed by numba on its own
    file only, is dropped when our compiled sources change (a cache that named a moved module of ours would not
    load), and kept while they do not; other modules' caches beside it are left alone."""
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    _fake_package(pkg)
    user = tmp_path / "user"
    (user / "__pycache__").mkdir(parents=True)
    mod = user / "my_kind.py"
    mod.write_text("import numba\n")
    mine = [user / "__pycache__" / f"my_kind.step-3.py311.{e}" for e in ("nbi", "nbc")]
    other = user / "__pycache__" / "other.step-3.py311.nbc"
    for f in (*mine, other):
        f.write_bytes(b"x")
    assert numba_cache.freshen_dependent(mod, pkg)  # no stamp yet
    assert not any(f.exists() for f in mine) and other.exists()
    for f in mine:
        f.write_bytes(b"x")
    numba_cache._DIGESTS.clear()
    assert not numba_cache.freshen_dependent(mod, pkg)  # our sources unchanged: kept
    assert all(f.exists() for f in mine)
    (pkg / "physics" / "mod.py").write_text("import numba  # physics, moved\n")
    numba_cache._DIGESTS.clear()
    assert numba_cache.freshen_dependent(mod, pkg)
    assert not any(f.exists() for f in mine) and other.exists()
    assert not numba_cache.freshen_dependent(tmp_path / "nothing.py", pkg)
