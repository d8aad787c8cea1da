"""The project's error classes (one per concern, all plain ValueError/RuntimeError)."""

from __future__ import annotations

from vesselbot_ros.config import ConfigError

__all__ = ["ConfigError", "VesselbotError", "ModelInputError", "BagError"]


class VesselbotError(RuntimeError):
    """A run-time failure that the CLI reports as one clear line (exit code 2)."""


class ModelInputError(ValueError):
    """A non-finite or wrongly shaped value reached a pure-core function."""


class BagError(VesselbotError):
    """A bag directory is missing, truncated, corrupt or inconsistent."""
