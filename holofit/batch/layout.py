"""The file layout of a stage's table: the one module that knows a table's files, how a
finished table is published and where its fingerprint is kept.

A table ``<name>.csv`` of a stage has, beside it,

- ``<name>.csv.json``, its sidecar, whose ``batch`` entry holds the ``fingerprint`` of the
  settings and inputs it was made with, ``complete`` and ``frames_total``;
- while a batch runs, ``<name>.csv.journal`` (:mod:`holofit.batch.journal`: every row as it
  comes) and ``<name>.partial.csv`` (+ sidecar: the rows so far, rewritten atomically).

**Publishing** a table writes it under the partial table's name (sidecar first), then renames
the sidecar and at last the table into place, so the table under its own name (the file a
Makefile waits for) is the last file written and is complete whenever it exists. The batch
runner publishes its tables so (:class:`OutputFiles`); a stage that derives a table after its
batch (the fit's stitched chunks, the sweeps' rewrites) publishes it with
:func:`publish_table`, reads an earlier one's fingerprint with :func:`published_fingerprint`
and removes a table's files with :func:`discard_outputs`: no stage names the journal or the
partial table.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.batch.errors import BatchError
from holofit.batch.journal import JournalError, read_journal
from holofit.batch.keys import FRAME_KEY, Key, key_of_row, key_row, sorted_keys
from holofit.io.tables import read_table, sidecar_path, write_table
from holofit.status import ERROR

__all__ = [
    "OutputFiles",
    "StageTable",
    "discard_outputs",
    "earlier_fingerprint",
    "earlier_rows",
    "journal_path",
    "partial_path",
    "publish_table",
    "published_fingerprint",
]


@dataclass(frozen=True)
class StageTable:
    """The table one batch of a stage writes.

    Attributes
    ----------
    path : Path
        The CSV (sidecar beside it).
    columns : tuple of str
        Its columns, in order (the schema module's: :mod:`holofit.tables`); must include the
        key columns, ``status`` and ``message``.
    meta : dict
        The sidecar document; the runner adds its ``batch`` entry.
    fingerprint : str
        :func:`holofit.batch.stage.fingerprint` of the settings and inputs the table depends
        on: earlier results are reused only if it matches.
    desc : str
        The stage's name (progress bar, the folder's lock).
    finish : callable, optional
        Applied (in place) to the complete table just before it is written, with the whole
        movie at hand (e.g. outlier flags); changed statuses and messages are kept.
    key_columns : tuple of str
        The columns that name a row (:mod:`holofit.batch.keys`).
    replace_stale : bool
        Earlier results made with another fingerprint are discarded instead of refused: for a
        table derived from others (the crop's detections, the overlap refits), whose remedy
        is always to redo it.
    """

    path: Path
    columns: tuple[str, ...]
    meta: dict[str, Any]
    fingerprint: str
    desc: str
    finish: Callable[[pd.DataFrame], Any] | None = None
    key_columns: tuple[str, ...] = FRAME_KEY
    replace_stale: bool = False


def journal_path(output: str | Path) -> Path:
    """``prefit.csv`` -> ``prefit.csv.journal``."""
    output = Path(output)
    return output.with_name(output.name + ".journal")


def partial_path(output: str | Path) -> Path:
    """``prefit.csv`` -> ``prefit.partial.csv``: the table of the frames done so far."""
    output = Path(output)
    return output.with_name(output.stem + ".partial" + output.suffix)


def _remove(*paths: Path) -> None:
    for p in paths:
        with contextlib.suppress(FileNotFoundError):
            p.unlink()


def _promote(staged: Path, output: Path) -> None:
    """Rename a staged table into place: its sidecar first, the table last (and newest)."""
    os.replace(sidecar_path(staged), sidecar_path(output))
    os.replace(staged, output)  # the last file written: the run is complete
    os.utime(output)  # and the newest


def publish_table(path: str | Path, table: pd.DataFrame, meta: dict[str, Any],
                  fingerprint: str,
                  before_publish: Callable[[Path], Any] | None = None) -> Path:
    """Publish a finished table that a stage derived after its batch: CSV + sidecar whose
    ``batch`` entry is ``{"fingerprint", "complete": True, "frames_total": len(table)}``.

    It is staged under the partial table's name (sidecar first), ``before_publish(staged)``
    runs on it (a stage's sweeps and pictures), and the sidecar, then the table, are renamed
    into place: the table is the last file written, so a Makefile never takes a table being
    written for a finished one.

    Parameters
    ----------
    path : str or Path
        The table's own name (``fit.csv``).
    table : pandas.DataFrame
        Its rows, in its columns' order.
    meta : dict
        The sidecar document (not changed; its ``batch`` entry is replaced).
    fingerprint : str
        Identity of the settings and inputs (:func:`published_fingerprint` reads it back).
    before_publish : callable, optional
        Called with the staged table's path before it is renamed into place.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    staged = partial_path(path)
    doc = {**meta, "batch": {"fingerprint": fingerprint, "complete": True,
                             "frames_total": len(table)}}
    write_table(staged, table, doc)
    if before_publish is not None:
        before_publish(staged)
    _promote(staged, path)
    return path


def published_fingerprint(path: str | Path) -> str | None:
    """The fingerprint in a finished table's sidecar (None: no table, no sidecar, or none in
    it)."""
    path = Path(path)
    return _sidecar_fingerprint(path) if path.exists() else None


def _sidecar_fingerprint(path: Path) -> str | None:
    side = sidecar_path(path)
    try:
        return json.loads(side.read_text()).get("batch", {}).get("fingerprint")
    except (OSError, ValueError, AttributeError):
        return None


def earlier_fingerprint(output: str | Path) -> str | None:
    """The fingerprint of the earlier run of a batch into ``output`` (its journal's, else its
    finished table's); None if there is none, '' if its journal cannot be read."""
    output = Path(output)
    journal = journal_path(output)
    if journal.exists():
        try:
            return read_journal(journal)[0].get("fingerprint")
        except (JournalError, ValueError, KeyError):
            return ""
    return published_fingerprint(output)


def discard_outputs(path: str | Path) -> None:
    """Remove every file of a table: the table, its sidecar, its journal and its partial table
    (+ sidecar). Missing ones are fine."""
    path = Path(path)
    partial = partial_path(path)
    _remove(path, sidecar_path(path), journal_path(path), partial, sidecar_path(partial))


def complete_row(row: dict[str, Any], columns: Sequence[str],
                 key_columns: Sequence[str] = FRAME_KEY) -> dict[str, Any]:
    """``row`` with every column (NaN where missing), its key, status and message."""
    out = {c: row.get(c, math.nan) for c in columns}
    out.update(key_row(key_of_row(row, key_columns), key_columns))
    out["status"] = str(row.get("status") or ERROR)
    msg = row.get("message")
    out["message"] = "" if msg is None or (isinstance(msg, float) and math.isnan(msg)) else msg
    return out


class OutputFiles:
    """The files of one batch output: the table, the partial table and the journal.

    Parameters
    ----------
    table : StageTable
        The table, its columns, sidecar, key columns and ``finish``.
    before_publish : callable, optional
        Called with the complete table, written under the partial table's name, before it is
        published under its own (see :func:`holofit.batch.runner.run_batch`).
    """

    def __init__(self, table: StageTable,
                 before_publish: Callable[[Path], Any] | None = None) -> None:
        self.output = Path(table.path)
        self.columns = list(table.columns)
        self.key_columns = tuple(table.key_columns)
        self.meta = dict(table.meta or {})
        self.finish_table = table.finish
        self.before_publish = before_publish
        self.journal = journal_path(self.output)
        self.partial = partial_path(self.output)
        self._staged = False

    def complete(self, row: dict[str, Any]) -> dict[str, Any]:
        """``row`` with every column (NaN where missing), its key, status and message."""
        return complete_row(row, self.columns, self.key_columns)

    def write(self, rows: dict[Key, dict[str, Any]], info: dict[str, Any], *, final: bool,
              staged: bool = False) -> None:
        """Write the rows (sorted by key) as the final or the partial table, atomically
        (``staged``: the final table under the partial table's name)."""
        frames = sorted_keys(rows)
        table = pd.DataFrame([rows[f] for f in frames], columns=self.columns)
        if final and self.finish_table is not None:
            self.finish_table(table)
            kept = [*self.key_columns, "status", "message"]
            for rec in table[kept].to_dict(orient="records"):
                rows[key_of_row(rec, self.key_columns)].update(status=rec["status"],
                                                               message=rec["message"])
        doc = dict(self.meta)
        doc["batch"] = info | {"frames_done": len(frames)}
        write_table(self.output if final and not staged else self.partial, table, doc)

    def finish(self, rows: dict[Key, dict[str, Any]], info: dict[str, Any]) -> None:
        """Write the final table, then remove the journal and the partial table; with
        ``before_publish``, only stage it (:meth:`publish` completes)."""
        staged = self.before_publish is not None
        self.write(rows, info | {"complete": True}, final=True, staged=staged)
        if not staged:
            _remove(self.journal)
            self.remove_partial()
        self._staged = staged

    def publish(self) -> bool:
        """With ``before_publish``: call it on the staged table, then rename the table (its
        sidecar first) into place and remove the journal. Returns whether it published."""
        if self.before_publish is None or not self._staged:
            return False
        self.before_publish(self.partial)
        _promote(self.partial, self.output)
        _remove(self.journal)
        return True

    def remove_partial(self) -> None:
        """Remove the partial table and its sidecar."""
        _remove(self.partial, sidecar_path(self.partial))

    def discard_all(self) -> None:
        """Remove every file of earlier runs (``overwrite``)."""
        discard_outputs(self.output)


def _rows_from_table(path: Path, files: OutputFiles) -> dict[Key, dict[str, Any]]:
    table = read_table(path)
    missing = set(files.columns) - set(table.columns)
    if missing:
        raise BatchError(
            f"{path}: existing table lacks column(s) {', '.join(sorted(missing))}; "
            "use --overwrite or another output"
        )
    rows = {}
    for rec in table.to_dict(orient="records"):
        rows[key_of_row(rec, files.key_columns)] = files.complete(rec)
    return rows


def earlier_rows(files: OutputFiles, fingerprint: str,
                 overwrite: bool) -> dict[Key, dict[str, Any]]:
    """Rows of an earlier run of the same batch (journal first, else the finished table);
    with ``overwrite``, none (its files are removed).

    Raises
    ------
    BatchError
        If the earlier run had another fingerprint, or its journal or table cannot be used.
    """
    if overwrite:
        files.discard_all()
        return {}
    hint = "rerun with --overwrite to discard them, or choose another output"
    if files.journal.exists():
        try:
            header, rows, _ = read_journal(files.journal, files.key_columns)
        except JournalError as exc:
            raise BatchError(f"{exc}; {hint}") from None
        if header.get("fingerprint") != fingerprint:
            raise BatchError(
                f"{files.journal}: holds results of a batch with other settings or inputs; "
                f"{hint}"
            )
        return {k: files.complete(r) for k, r in rows.items()}
    if files.output.exists():
        if _sidecar_fingerprint(files.output) != fingerprint:
            raise BatchError(
                f"{files.output}: exists and was made with other settings or inputs; {hint}"
            )
        return _rows_from_table(files.output, files)
    return {}
