"""One child-process wrapper for every node the project starts (launcher, tests, ``replay --into``).

:class:`ChildProcess` starts a command in its own session with its output in a
log file, and makes the kernel end it when its parent dies, however the parent
dies (SIGKILL, SIGHUP, a crash): the child asks for ``PR_SET_PDEATHSIG``
(SIGTERM, so nodes stop cleanly and the recorder finalises its bag) between
``fork`` and ``exec``, and exits at once if the parent is already gone.
Optionally the child inherits a domain lease's lock file descriptor
(``hold_fds``): the lease then stays held until the last child exits, so a
domain whose nodes still run is never handed to another run.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal as sig_mod
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

__all__ = ["ChildProcess", "set_parent_death_signal"]

_PR_SET_PDEATHSIG = 1
_libc: ctypes.CDLL | None = None


def set_parent_death_signal(sig: int = sig_mod.SIGTERM, parent_pid: int | None = None) -> None:
    """Ask the kernel to send ``sig`` to this process when its parent dies (Linux ``prctl``).

    If ``parent_pid`` is given and the parent already changed (it died before
    the call), exit at once.  A no-op where ``prctl`` is unavailable.
    """
    global _libc
    if not sys.platform.startswith("linux"):
        return
    if _libc is None:
        _libc = ctypes.CDLL(None, use_errno=True)
    _libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
    if parent_pid is not None and os.getppid() != parent_pid:
        os._exit(1)


def _preexec(parent_pid: int, sig: int) -> Callable[[], None]:
    def run() -> None:
        set_parent_death_signal(sig, parent_pid)

    return run


class ChildProcess:
    """A child process tied to this one, with its stdout and stderr in a log file.

    Args:
        label: Name used in messages (e.g. the node role).
        argv: The command; ``python`` as first element means this interpreter.
        env: Its environment.
        log_path: File receiving its stdout and stderr.
        hold_fds: File descriptors the child inherits (e.g. a domain lease's lock).
        death_signal: Signal the child gets when this process dies.
    """

    def __init__(self, label: str, argv: Sequence[str], env: dict[str, str], log_path: str | os.PathLike[str],
                 hold_fds: Sequence[int] = (), death_signal: int = sig_mod.SIGTERM) -> None:
        argv = list(argv)
        if argv and argv[0] == "python":
            argv[0] = sys.executable
        self.label = label
        self.argv = argv
        self.log_path = Path(log_path)
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self._log = open(self.log_path, "wb")  # noqa: SIM115 - closed in close()
        self.proc = subprocess.Popen(argv, env=env, stdout=self._log, stderr=subprocess.STDOUT, start_new_session=True,
                                     pass_fds=tuple(hold_fds), preexec_fn=_preexec(os.getpid(), death_signal))

    @property
    def pid(self) -> int:
        """The child's PID."""
        return int(self.proc.pid)

    def poll(self) -> int | None:
        """Exit code, or None while it runs."""
        return self.proc.poll()

    def alive(self) -> bool:
        """True while the process runs."""
        return self.proc.poll() is None

    def output(self) -> str:
        """Everything the process printed so far."""
        with contextlib.suppress(ValueError, OSError):
            self._log.flush()
        return self.log_path.read_text(errors="replace")

    def tail(self, n: int = 15) -> str:
        """Its last ``n`` output lines."""
        with contextlib.suppress(OSError):
            return "\n".join(self.output().splitlines()[-n:])
        return ""

    def signal(self, sig: int) -> None:
        """Send ``sig`` if it still runs."""
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                self.proc.send_signal(sig)

    def wait(self, timeout: float) -> int:
        """Wait up to ``timeout`` s for the exit, then SIGKILL its process group; return the exit code."""
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, sig_mod.SIGKILL)
            return self.proc.wait(timeout=10)

    def stop(self, timeout: float = 10.0, sig: int = sig_mod.SIGINT) -> int:
        """Signal it, wait up to ``timeout`` s (then SIGKILL), close the log; return the exit code."""
        self.signal(sig)
        code = self.wait(timeout)
        self.close()
        return code

    def close(self) -> None:
        """Close the log file."""
        with contextlib.suppress(OSError):
            self._log.close()

    def __enter__(self) -> ChildProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
