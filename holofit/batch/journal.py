"""Append-only journal of finished frames: what makes a batch resumable after a kill.

One JSON document per line. The first line is a header with the batch's fingerprint (a hash
of its settings and inputs) and columns; every other line is one finished frame's row. A line
is written and flushed as soon as the frame finishes, so a run killed at any moment (SIGKILL,
power cut: lines are fsync'ed every few seconds) loses at most the line being written. A torn
last line is recognised (it does not end in a newline or is not valid JSON) and cut off when
the journal is reopened.

Floats are written with Python's shortest round-trip representation (NaN as ``NaN``), so a
value read back is bit-identical to the one computed.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from holofit.batch.keys import FRAME_KEY, Key, key_of_row

__all__ = ["Journal", "JournalError", "read_journal"]

FORMAT = "holofit-batch-journal/1"


class JournalError(ValueError):
    """A journal cannot be used (unreadable header, other batch)."""


def _plain(value: Any) -> Any:
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot store {type(value).__name__} in a journal row")


def _dumps(doc: dict[str, Any]) -> str:
    return json.dumps(doc, default=_plain, allow_nan=True, separators=(",", ":"))


def read_journal(
    path: str | Path, key_columns: Sequence[str] | None = None
) -> tuple[dict[str, Any], dict[Key, dict[str, Any]], int]:
    """Read a journal.

    Parameters
    ----------
    path : str or Path
        The journal.
    key_columns : sequence of str, optional
        The rows' key columns (:mod:`holofit.batch.keys`); default: the header's
        ``key_columns``, else ``("frame",)``.

    Returns
    -------
    header : dict
        The first line.
    rows : dict
        Key -> row of every complete line (a later line for the same key wins).
    good_bytes : int
        Length of the intact part of the file (everything up to the last complete line).

    Raises
    ------
    JournalError
        If the header is missing or not a holofit journal.
    """
    path = Path(path)
    raw = path.read_bytes()
    rows: dict[Key, dict[str, Any]] = {}
    header: dict[str, Any] | None = None
    pos = 0
    good = 0
    while pos < len(raw):
        end = raw.find(b"\n", pos)
        if end < 0:
            break  # torn last line
        line = raw[pos:end]
        pos = end + 1
        try:
            doc = json.loads(line)
        except ValueError:
            if pos >= len(raw):
                break  # torn last line that happens to end in a newline
            lineno = raw[:pos].count(b"\n")
            raise JournalError(f"{path}: line {lineno} is not JSON") from None
        if header is None:
            if not isinstance(doc, dict) or doc.get("format") != FORMAT:
                raise JournalError(
                    f"{path}: not a holofit batch journal (first line {line[:80]!r})"
                )
            header = doc
            if key_columns is None:
                key_columns = tuple(header.get("key_columns", FRAME_KEY))
        else:
            assert key_columns is not None
            rows[key_of_row(doc, key_columns)] = doc
        good = pos
    if header is None:
        raise JournalError(f"{path}: journal has no complete header line")
    return header, rows, good


class Journal:
    """Writer of an append-only journal.

    Parameters
    ----------
    path : str or Path
        The journal file. If it exists with an intact header it is continued (a torn last line
        is cut off); otherwise it is created with ``header``.
    header : dict
        Batch description (fingerprint, columns); stored on the first line of a new journal.
    fsync_interval_s : float
        Most seconds between fsyncs (every line is flushed to the OS at once).
    """

    def __init__(
        self, path: str | Path, header: dict[str, Any], fsync_interval_s: float = 5.0
    ) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh: BinaryIO
        good = None
        if self.path.exists() and self.path.stat().st_size > 0:
            _, _, good = read_journal(self.path)
        if good is None:
            self._fh = open(self.path, "wb")
            self._fh.write((_dumps({"format": FORMAT, **header}) + "\n").encode())
        else:
            self._fh = open(self.path, "r+b")
            self._fh.truncate(good)
            self._fh.seek(good)
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self._fsync_interval = fsync_interval_s
        self._last_sync = time.monotonic()

    def append(self, row: dict[str, Any]) -> None:
        """Record one finished item's row (must contain its key columns)."""
        self._fh.write((_dumps(row) + "\n").encode())
        self._fh.flush()
        now = time.monotonic()
        if now - self._last_sync >= self._fsync_interval:
            os.fsync(self._fh.fileno())
            self._last_sync = now

    def close(self) -> None:
        """Flush, fsync and close."""
        if not self._fh.closed:
            self._fh.flush()
            os.fsync(self._fh.fileno())
            self._fh.close()

    def __enter__(self) -> Journal:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
