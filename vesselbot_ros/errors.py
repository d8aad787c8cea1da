"""The package's one error root, :class:`VesselbotError`, and its subclasses.

Every error vesselbot_ros raises on purpose is a :class:`VesselbotError`, so
``except VesselbotError`` catches them all, and the ``vesselbot`` command
prints any of them as one line and exits with code 2::

    VesselbotError (RuntimeError)
    ├── ConfigError (also ValueError)      a configuration value is missing, unknown or invalid
    ├── ModelInputError (also ValueError)  a non-finite or wrongly shaped value reached the core
    ├── BagError                           a bag is missing, truncated, corrupt or inconsistent
    ├── RunError                           a run failed while it ran
    │   ├── NodeDied                       (vesselbot_ros.launch.supervision)
    │   └── RecordingMismatch              (vesselbot_ros.launch.graph)
    └── OutputError (also OSError)         an output file or folder cannot be written (full disk, read-only)

:class:`ConfigError` and :class:`ModelInputError` stay ``ValueError`` too, so
code that catches ``ValueError`` keeps working.  They are importable from
their old homes as well (``vesselbot_ros.config.ConfigError``).

This is the lowest layer of the package: it imports nothing from it.
"""

from __future__ import annotations

__all__ = ["VesselbotError", "ConfigError", "ModelInputError", "BagError", "RunError", "OutputError"]


class VesselbotError(RuntimeError):
    """The root of every error vesselbot_ros raises; the CLI reports it as one clear line (exit code 2)."""


class ConfigError(VesselbotError, ValueError):
    """A configuration value is missing, unknown, of the wrong type or out of range.

    The message always names the field (dotted path) and the offending value.
    """


class ModelInputError(VesselbotError, ValueError):
    """A non-finite or wrongly shaped value reached a pure-core function."""


class BagError(VesselbotError):
    """A bag directory is missing, truncated, corrupt or inconsistent."""


class RunError(VesselbotError):
    """A run could not go on: a node died, a recording mismatched, a node or cluster did not answer."""


class OutputError(OSError, VesselbotError):
    """An output file or folder cannot be written (a full disk, a file size limit, a read-only place).

    Raised by :mod:`vesselbot_ros.atomic_io`.  It stays an ``OSError`` (with
    ``errno`` and ``filename``), and its message is one sentence that names
    the path and what was left as it was.
    """

    #: Why it failed, without the path (``File too large: the disk is full ...``); "" if not known.
    reason: str = ""

    def __str__(self) -> str:
        return str(self.strerror)
