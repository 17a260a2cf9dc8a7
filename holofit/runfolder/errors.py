"""The error of a run folder that cannot be set up."""

from __future__ import annotations

from holofit.config_schema import ConfigError

__all__ = ["RunFolderError"]


class RunFolderError(ConfigError):
    """A run folder cannot be written as asked: a missing or unreadable input, a path that make
    cannot handle, an option the Makefile sets itself, or a Makefile that exists already.

    A :class:`~holofit.config_schema.ConfigError` (the configuration of a run), so the command
    line reports it as one line.
    """
