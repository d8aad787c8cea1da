"""Progress bars for the long steps a user waits on (a CFD solve, a 3-D wall field, the compiled code's warm-up).

The core never draws anything: a long step takes a callback ``progress(done, total)``
(:data:`ProgressFn`) and calls it as it goes.  The steps that run deep inside a
command (a field solved or a wall lookup built the first time a run asks for it)
get theirs from :func:`step`, which is a no-op unless a command-line shell turned
bars on with :func:`session`.  Only then is tqdm imported, and its bar drawn on
stderr.

Whether a command draws bars (:func:`wanted`): never with ``--no-progress``
(:func:`add_progress_argument`, the one flag every command that can wait long
takes) or with ``VESSELBOT_NO_PROGRESS=1`` in the environment; always with
``VESSELBOT_PROGRESS=1`` (forced); otherwise only when stderr is a terminal, so a
log, a pipe or a test capturing stderr gets no bar (and a one-line error stays
one line).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from collections.abc import Callable, Iterator
from typing import Any, TextIO

__all__ = ["ProgressFn", "NO_PROGRESS_ENV", "FORCE_PROGRESS_ENV", "add_progress_argument", "suppressed", "wanted",
           "bar", "session", "step", "active", "COMPILE_NOTICE"]

#: A long step's report: ``progress(done, total)``, ``done`` rising to ``total``.
ProgressFn = Callable[[int, int], None]
#: ``VESSELBOT_NO_PROGRESS=1``: no bar, whatever the command line says.
NO_PROGRESS_ENV = "VESSELBOT_NO_PROGRESS"
#: ``VESSELBOT_PROGRESS=1``: a bar even when stderr is not a terminal (unless suppressed).
FORCE_PROGRESS_ENV = "VESSELBOT_PROGRESS"

_TRUE = {"1", "true", "yes", "on"}
#: The stream bars are drawn on while a :func:`session` is on; None: no bars.
_stream: TextIO | None = None


def _env(name: str) -> bool:
    return os.environ.get(name, "").strip().lower() in _TRUE


def add_progress_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--no-progress`` to a command that can wait long (the one definition of the flag; once per parser)."""
    if "--no-progress" in parser._option_string_actions:
        return
    parser.add_argument("--no-progress", action="store_true",
                        help=f"no progress bars on stderr (also {NO_PROGRESS_ENV}=1; bars are drawn only on a "
                             f"terminal unless {FORCE_PROGRESS_ENV}=1)")


def suppressed(no_progress: bool = False) -> bool:
    """True if the user turned progress off: ``--no-progress`` or ``VESSELBOT_NO_PROGRESS=1``."""
    return bool(no_progress) or _env(NO_PROGRESS_ENV)


def wanted(no_progress: bool = False, stream: TextIO | None = None, *, force: bool = False) -> bool:
    """Whether to draw bars on ``stream`` (default stderr): not :func:`suppressed`, and forced or a terminal."""
    if suppressed(no_progress):
        return False
    if force or _env(FORCE_PROGRESS_ENV):
        return True
    stream = sys.stderr if stream is None else stream
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


def _noop(done: int, total: int) -> None:
    del done, total


@contextlib.contextmanager
def bar(name: str, stream: TextIO | None = None) -> Iterator[ProgressFn]:
    """A tqdm bar named ``name`` on ``stream`` (default stderr), driven by the callback it yields; closed on exit."""
    from tqdm import tqdm  # deferred: only a shell that draws bars pays for it

    stream = sys.stderr if stream is None else stream
    t: Any = tqdm(desc=name, total=None, file=stream, leave=True, dynamic_ncols=True, mininterval=0.2)

    def update(done: int, total: int) -> None:
        if t.total != total:
            t.total = total
            t.refresh()
        if done != t.n:
            t.update(done - t.n)

    try:
        yield update
    finally:
        t.close()


#: The one line a session prints when numba starts compiling the package's code (a cache miss: a case the
#: bootstrap did not warm, or the first run after the compiled sources changed).
COMPILE_NOTICE = ("vesselbot: compiling the compiled loop for this case (numba, once per version of the code; "
                  "later runs load it from the cache)")


def _compile_listener(stream: TextIO) -> Any:
    """A numba event listener that writes :data:`COMPILE_NOTICE` once, at the first compile of our code."""
    # deferred: numba is heavy; a session that draws nothing never loads it for this
    from numba.core import event

    class Notice(event.Listener):
        said = False

        def on_start(self, ev: Any) -> None:
            func = getattr(ev.data.get("dispatcher"), "py_func", None)
            if not self.said and str(getattr(func, "__module__", "")).startswith("vesselbot_ros"):
                self.said = True
                print(COMPILE_NOTICE, file=stream, flush=True)

        def on_end(self, ev: Any) -> None:
            del ev

    return Notice()


@contextlib.contextmanager
def session(enabled: bool, stream: TextIO | None = None) -> Iterator[None]:
    """Within it, every :func:`step` draws a bar on ``stream`` (default stderr) if ``enabled``, none otherwise.

    An enabled session also says, in one line, when numba starts compiling the package's code
    (:data:`COMPILE_NOTICE`): the minute a first run of an unwarmed case waits is not silent.
    """
    global _stream
    before = _stream
    _stream = (sys.stderr if stream is None else stream) if enabled else None
    listener = None
    if _stream is not None:
        from numba.core import event  # deferred: see _compile_listener

        listener = _compile_listener(_stream)
        event.register("numba:compile", listener)
    try:
        yield
    finally:
        _stream = before
        if listener is not None:
            event.unregister("numba:compile", listener)


def active() -> bool:
    """True within a :func:`session` that draws bars."""
    return _stream is not None


@contextlib.contextmanager
def step(name: str) -> Iterator[ProgressFn]:
    """The callback of a long step named ``name``: a bar within an enabled :func:`session`, else a no-op."""
    if _stream is None:
        yield _noop
        return
    with bar(name, _stream) as update:
        yield update
