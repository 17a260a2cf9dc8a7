"""Keeping third-party libraries' log lines out of the user's terminal.

Libraries such as tifffile log what they notice about a file (``invalid page offset``) through
Python's :mod:`logging`; with no handler configured those lines are printed to stderr before
holofit's own message, which is the one that names the file and the frame. Inside
:func:`capture_log` they are collected instead, so that holofit can put them into its own error
or its sidecar.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator

__all__ = ["capture_log"]


class _Collect(logging.Handler):
    def __init__(self, sink: list[str]) -> None:
        super().__init__(logging.DEBUG)
        self.sink = sink

    def emit(self, record: logging.LogRecord) -> None:
        try:
            message = record.getMessage()
        except Exception:  # a malformed record must not break reading
            message = str(record.msg)
        if record.levelno >= logging.WARNING and message not in self.sink:
            self.sink.append(message)


@contextlib.contextmanager
def capture_log(name: str) -> Iterator[list[str]]:
    """Collect the warnings logged to logger ``name`` (and its children) in a list.

    While the block runs, the logger's records go to the list only (not to stderr nor to any
    parent handler); the logger is restored afterwards.

    Yields
    ------
    list of str
        The messages, in order, without repeats.
    """
    logger = logging.getLogger(name)
    sink: list[str] = []
    handler = _Collect(sink)
    propagate = logger.propagate
    logger.addHandler(handler)
    logger.propagate = False
    try:
        yield sink
    finally:
        logger.removeHandler(handler)
        logger.propagate = propagate
