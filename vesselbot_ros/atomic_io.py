"""Output files written atomically, and output places checked before a command does its work.

Every file a ``vesselbot`` command writes (metrics, figures, plans, tables,
bag side files, reports) goes through :func:`atomic_path`: the content is
written to a temporary file in the same folder (``.<stem>.<random>.tmp<suffix>``,
so that matplotlib, numpy and pyarrow still see the real extension), and
only a complete file is renamed over the destination (``os.replace``).  On
any failure (a full disk, a file size limit, an error while drawing) the
temporary file is removed and the destination keeps its old content, or is
not created at all: never a 0-byte or half-written output.  The rename is
atomic against a failing or killed process; it is not flushed to the disk
(no fsync), so it promises nothing across a power cut.

:func:`check_output_dir` and :func:`check_output_file` are the checks a
command runs *before* its work: the folder can be created and written (a
probe file is created, written and removed; it is removed on failure too), an
existing file can be replaced, and the file system has the free space the
command's estimate needs.  A refused check removes the folders it created.

Every failure is an :class:`~vesselbot_ros.errors.OutputError` (also an
``OSError``) whose message is one sentence naming the path; the ``vesselbot``
command prints it as one line and exits 2.

This module imports nothing from the package but its errors.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from vesselbot_ros.errors import OutputError

__all__ = [
    "OutputError",
    "FULL_DISK_ERRNOS",
    "atomic_path",
    "atomic_open",
    "write_text",
    "write_bytes",
    "write_error",
    "failure_reason",
    "save_figure",
    "check_output_dir",
    "check_output_file",
    "free_bytes",
    "probe_dir",
    "fmt_size",
]

#: errno values of a write that failed for lack of room: ENOSPC, EDQUOT, EFBIG (a file size limit).
FULL_DISK_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def fmt_size(n: float) -> str:
    """``n`` bytes for a message: ``512 B``, ``3.9 MiB``."""
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024:
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"


def _why(exc: OSError) -> str:
    text = exc.strerror or str(exc)
    if exc.errno in FULL_DISK_ERRNOS:
        return f"{text}: the disk is full or a file size limit was reached"
    return text


def failure_reason(exc: OSError) -> str:
    """Why a write failed, in words (``File too large: the disk is full or ...``), without the path."""
    return exc.reason if isinstance(exc, OutputError) and exc.reason else _why(exc)


def write_error(path: str | os.PathLike[str], exc: OSError) -> OutputError:
    """The one-line error of a file that could not be written at ``path``."""
    if isinstance(exc, OutputError):
        return exc
    err = OutputError(exc.errno or errno.EIO, f"cannot write {path} ({_why(exc)}); "
                      f"no partial file was left, an earlier {Path(path).name} is unchanged", str(path))
    err.reason = _why(exc)
    return err


def _umask() -> int:
    """This process's umask, read without changing it (``os.umask`` would race with other threads)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    return 0o022


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """A temporary path beside ``path`` to write; renamed onto ``path`` when the block ends without error.

    Use it for a writer that takes a file name (``fig.savefig(tmp)``,
    ``pq.write_table(table, tmp)``, ``np.savez_compressed(tmp, ...)``): the
    temporary name ends in ``path``'s own suffix.  The new file gets the mode
    of the file it replaces (else the usual ``0o666`` less the umask).

    Raises:
        OutputError: the temporary file cannot be created or written, or the
            rename fails (naming ``path``; the temporary file is removed and
            ``path`` is as before).  Other errors of the block pass through,
            with the temporary file removed too.
    """
    dest = Path(path)
    try:
        fd, name = tempfile.mkstemp(dir=dest.parent, prefix=f".{dest.stem}.", suffix=f".tmp{dest.suffix}")
    except OSError as exc:
        raise write_error(dest, exc) from None
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        try:
            mode = stat.S_IMODE(dest.stat().st_mode)
        except OSError:
            mode = 0o666 & ~_umask()
        os.chmod(tmp, mode)
        os.replace(tmp, dest)
    except OSError as exc:
        raise write_error(dest, exc) from None
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = "w", *, encoding: str | None = "utf-8",
                newline: str | None = None) -> Iterator[IO[Any]]:
    """``open(path, mode)`` for writing, atomically (see :func:`atomic_path`); ``mode`` is ``"w"`` or ``"wb"``."""
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open writes a whole file: mode must be 'w' or 'wb', got {mode!r}")
    with atomic_path(path) as tmp:
        if mode == "wb":
            with open(tmp, "wb") as fh:
                yield fh
        else:
            with open(tmp, "w", encoding=encoding, newline=newline) as fh:
                yield fh


def write_text(path: str | os.PathLike[str], text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically; return ``path``."""
    with atomic_open(path, "w", encoding=encoding) as fh:
        fh.write(text)
    return Path(path)


def write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; return ``path``."""
    with atomic_open(path, "wb") as fh:
        fh.write(data)
    return Path(path)


def save_figure(fig: Any, path: str | os.PathLike[str], **savefig_kwargs: Any) -> Path:
    """``fig.savefig(path, **savefig_kwargs)`` atomically (a matplotlib figure; the format from ``path``'s suffix)."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **savefig_kwargs)
    return Path(path)


def _existing_ancestor(path: Path) -> Path:
    p = path
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def free_bytes(path: str | os.PathLike[str]) -> int:
    """Free bytes on the file system of ``path`` (or of its nearest existing parent)."""
    return int(shutil.disk_usage(_existing_ancestor(Path(path).expanduser().absolute())).free)


def probe_dir(folder: str | os.PathLike[str]) -> None:
    """Create, write one byte to and remove a file in ``folder``; the file never outlives the call."""
    fd, name = tempfile.mkstemp(dir=folder, prefix=".write_probe_")
    try:
        os.write(fd, b"x")
    finally:
        os.close(fd)
        with contextlib.suppress(OSError):
            os.unlink(name)


def check_output_dir(path: str | os.PathLike[str], what: str = "output folder", need_bytes: int = 0,
                     need_why: str = "") -> Path:
    """Check, before any work, that files can be written in the folder ``path``; create it if needed.

    In this order: the free space of its file system (``need_bytes``, the
    caller's estimate; ``need_why`` says what it is made of), then the folder
    is created and a probe file is written in it and removed.  A refused
    check removes the folders it created; the probe never stays.

    Args:
        path: The folder.
        what: What it is, for the message (``--out``, ``bag folder``).
        need_bytes: Bytes the command will write there, at most (its estimate).
        need_why: How ``need_bytes`` was reckoned, for the message.

    Returns:
        The folder, absolute.

    Raises:
        OutputError: one line naming the folder (and both sizes when space is short).
    """
    out = Path(path).expanduser().absolute()
    base = _existing_ancestor(out)
    if not base.is_dir():
        raise OutputError(errno.ENOTDIR, f"{what} {out}: {base} is not a folder", str(out))
    if need_bytes > 0:
        free = int(shutil.disk_usage(base).free)
        if free < need_bytes:
            why = f" ({need_why})" if need_why else ""
            raise OutputError(errno.ENOSPC, f"{what} {out}: the outputs need {fmt_size(need_bytes)} free{why}, "
                                            f"only {fmt_size(free)} is free on {base}; nothing was written", str(out))
    created = [p for p in (out, *out.parents) if not p.exists()]
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe_dir(out)
    except OSError as exc:
        for p in created:  # deepest first; a folder someone else filled meanwhile stays
            with contextlib.suppress(OSError):
                p.rmdir()
        raise OutputError(exc.errno or errno.EIO, f"{what} {out} is not writable ({_why(exc)}); nothing was written",
                          str(out)) from None
    return out


def check_output_file(path: str | os.PathLike[str], what: str = "output file") -> Path:
    """Check, before any work, that the file ``path`` can be written: its folder exists and is writable,
    and an existing file there is a file that may be written (it is not changed).

    Raises:
        OutputError: one line naming the file.
    """
    dest = Path(path).expanduser().absolute()
    if dest.is_dir():
        raise OutputError(errno.EISDIR, f"{what} {dest} is a folder", str(dest))
    if not dest.parent.is_dir():
        raise OutputError(errno.ENOENT, f"{what} {dest}: folder {dest.parent} does not exist", str(dest))
    try:
        probe_dir(dest.parent)
        if dest.exists():  # opened for writing, not truncated: a read-only file is refused, its bytes untouched
            os.close(os.open(dest, os.O_WRONLY | getattr(os, "O_NONBLOCK", 0)))
    except OSError as exc:
        raise OutputError(exc.errno or errno.EIO, f"{what} {dest} is not writable ({_why(exc)}); nothing was written",
                          str(dest)) from None
    return dest
