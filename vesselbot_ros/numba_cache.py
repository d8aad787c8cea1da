"""One stamp over every source numba compiles, so no process ever loads a cache from other code.

numba's on-disk cache (``__pycache__/*.nbi`` index, ``*.nbc`` code, next to
each module) is keyed on the *defining* file's modification time and size
only.  Our compiled functions call and inline functions of other modules (the
compiled loop inlines the kernel, the integrator and every stage), so an edit
to one of those would leave stale machine code in the callers' caches.
:func:`ensure_fresh` hashes every module of the package that mentions numba
(:func:`numba_sources`: the compiled functions, the ``register_jitable``
formulas they inline, and the constants they freeze all live in such modules)
and, when the hash differs from the stamp kept beside the caches, deletes every
numba cache file of the package first.  Editing a module without numba code
(the runner's Python, the CLI, the nodes) keeps the cache.

It runs when :mod:`vesselbot_ros` is imported (about 1 ms), before any
compiled function can load its cache.  A user's compiled kind calls and inlines
our functions too, from its own module: :func:`freshen_dependent` drops that
module's numba cache when our sources changed since it was written (the stage
kinds' loader calls it before it imports the module).  :func:`vesselbot_ros.sim.warm.warm` fills the cache
(``tools/bootstrap.sh`` calls it once per version of the compiled sources, so
``make run``, ``make test`` and every node start without compiling).
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from pathlib import Path

from vesselbot_ros.atomic_io import write_text

__all__ = ["numba_sources", "source_digest", "ensure_fresh", "freshen_dependent"]

ROOT = Path(__file__).resolve().parent
STAMP_NAME = "numba.sources.sha256"


def numba_sources(root: Path = ROOT) -> list[Path]:
    """Every ``*.py`` below ``root`` whose text mentions ``numba``, sorted."""
    return sorted(p for p in root.rglob("*.py") if "__pycache__" not in p.parts and b"numba" in p.read_bytes())


def source_digest(root: Path = ROOT) -> str:
    """SHA-256 over the names and bytes of every numba source of the package at ``root``."""
    h = hashlib.sha256()
    for p in numba_sources(root):
        h.update(p.relative_to(root).as_posix().encode() + b"\0")
        h.update(p.read_bytes())
    return h.hexdigest()


def _refresh(stamp: Path, digest: str, caches: Iterable[Path]) -> bool:
    """Delete ``caches`` and write ``digest`` to ``stamp`` unless the stamp already holds it; True if it did not."""
    try:
        if stamp.is_file() and stamp.read_text() == digest:
            return False
        for f in caches:
            f.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        write_text(stamp, digest)
    except OSError:  # a read-only folder: numba then caches in its own user directory
        pass
    return True


_DIGESTS: dict[Path, str] = {}


def _digest(root: Path) -> str:
    """:func:`source_digest` of ``root``, hashed once per process (the package's sources do not change under it)."""
    if root not in _DIGESTS:
        _DIGESTS[root] = source_digest(root)
    return _DIGESTS[root]


def ensure_fresh(root: Path = ROOT) -> bool:
    """Delete the package's numba cache files if its sources changed since they were written.

    Returns:
        True if caches were dropped (or there was no stamp yet).
    """
    _DIGESTS.pop(root, None)  # read the sources now, whatever an earlier call saw
    return _refresh(root / "__pycache__" / STAMP_NAME, _digest(root), root.rglob("__pycache__/*.nb[ic]"))


def freshen_dependent(module_file: str | Path, root: Path = ROOT) -> bool:
    """Delete the numba cache files of a module outside the package (a user's compiled kind) if the package's
    compiled sources changed since they were written: numba keys them on that module's own file only, and the
    code in them calls or inlines ours.  The stamp is ``__pycache__/<stem>.vesselbot.sha256`` beside the module.

    Returns:
        True if caches were dropped (or there was no stamp yet).
    """
    path = Path(module_file)
    if path.suffix != ".py" or not path.is_file():
        return False
    cache = path.parent / "__pycache__"
    return _refresh(cache / f"{path.stem}.vesselbot.sha256", _digest(root), cache.glob(f"{path.stem}.*.nb[ic]"))
