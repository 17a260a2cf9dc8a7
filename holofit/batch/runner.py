"""The per-frame batch runner shared by ``holofit prefit``, ``holofit library`` and ``holofit fit``.

A batch applies one *frame function* to many frames independently (frame k never waits for
frame k-1). The frame function is a module-level function ``func(config, frame, payload) ->
dict`` (picklable, so it can run in another process or on another machine); ``config`` is a
dataclass of settings, ``payload`` what the driver loaded for that frame (a crop and its
crop-table row). It returns one table row.

What the runner guarantees:

- **One writer**: the output folder is locked for the run (:mod:`holofit.io.lock`); a second
  run into the same folder is refused with a message naming the holder.
- **Lazy input, bounded memory**: frames are loaded by the driver one at a time, just before
  they are submitted, with a bounded number in flight.
- **Parallel**: a local pool of single-threaded processes by default, in-process on request,
  or a Dask cluster (:mod:`holofit.batch.backends`); all give identical rows. Local workers
  end with the driver, even when it is killed.
- **Failure isolation**: an exception in a frame becomes a row with status ``error`` and the
  message; a frame function reports a fit that did not converge as ``not_converged``; a worker
  that dies is replaced, the frames it may have been running are retried one at a time, and a
  frame that kills a worker again is recorded as ``error``. The batch always goes on.
- **Results as they come, atomically**: every finished row is appended to a journal
  (:mod:`holofit.batch.journal`) at once; the table of the frames done so far,
  ``<name>.partial.csv`` (+ sidecar), is rewritten atomically every few seconds; the output
  table (CSV + sidecar JSON, sorted by frame) appears under its own name only when every frame
  is done, so a Makefile target never mistakes an interrupted run for a finished one.
- **Resumable**: a rerun of the same batch (same fingerprint) reads the journal (or the
  finished table) and runs only the frames that are missing or recorded as ``error`` (an
  exception or a dead worker: a cause the user may have fixed since; ``ok``, ``poor_fit`` and
  the other outcomes of a fit are kept, ``not_converged`` too unless ``retry_failed``), so a
  run killed at any point (even by SIGKILL) finishes with the same table as an uninterrupted
  run. A rerun with other settings refuses to mix results unless told to overwrite.
- **No silent total failure**: a batch in which every frame that was tried ended in
  ``error`` raises :class:`BatchError` naming the most common message (and, for workers that
  died, the most common cause) instead of writing its table; the journal and the partial
  table keep the rows, and a rerun tries them all again.

The pieces: :mod:`holofit.batch.options` holds the settings, the summary and the choice of
backend; :mod:`holofit.batch.layout` the files of one output (table, partial table, journal,
fingerprint, publishing) and the rows of earlier runs (:func:`~holofit.batch.layout.earlier_rows`);
:mod:`holofit.batch.loop` the run loop (:class:`~holofit.batch.loop.BatchRun`: rows, journal,
progress, frames in flight; :func:`~holofit.batch.loop.run_frame`, what a worker runs); here,
:func:`run_batch` checks its arguments, takes the folder lock, finds the earlier rows and
hands the rest to the loop.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from holofit.batch.backends import Backend
from holofit.batch.keys import Key, check_key_columns, normal_key
from holofit.batch.layout import (
    OutputFiles,
    StageTable,
    earlier_fingerprint,
    earlier_rows,
)
from holofit.batch.loop import BatchRun
from holofit.batch.mainguard import refuse_while_worker_starts
from holofit.batch.options import (
    BatchSettings,
    BatchSummary,
    backend_for,
)
from holofit.io.lock import output_lock
from holofit.progress import progress_bar
from holofit.status import ERROR, FAILED_STATUSES

__all__ = ["run_batch"]


def _checked_frames(frames: Iterable[Any], columns: Sequence[str],
                    key_columns: Sequence[str]) -> list[Key]:
    for required in (*key_columns, "status", "message"):
        if required not in columns:
            raise ValueError(f"columns must include {required!r}")
    out = [normal_key(f, key_columns) for f in frames]
    if len(set(out)) != len(out):
        raise ValueError("frames must be unique")
    return out


@dataclass
class _Batch:
    """One call of :func:`run_batch`, its arguments checked."""

    func: Callable[[Any, Any, Any], dict[str, Any]]
    config: Any
    frames: list[Key]
    load: Callable[[Any], Any]
    table: StageTable
    files: OutputFiles
    options: BatchSettings
    backend: Backend | None
    sizes: Mapping[Any, int] | None = None

    def run(self) -> BatchSummary:
        """Take the lock, reuse earlier rows, run the rest, write and publish the table."""
        t0 = time.perf_counter()
        files, opts, frames, key = self.files, self.options, self.frames, self.table.fingerprint
        with output_lock(files.output.parent, stage=self.table.desc) as lock:
            stale = (self.table.replace_stale
                     and earlier_fingerprint(files.output) not in (None, key))
            rows = earlier_rows(files, key, opts.overwrite or stale)
            again = (ERROR, *FAILED_STATUSES) if opts.retry_failed else (ERROR,)
            rows = {k: r for k, r in rows.items() if r["status"] not in again}
            todo = collections.deque(f for f in frames if f not in rows)
            summary = BatchSummary(files.output, len(frames), len(frames) - len(todo), 0)
            if lock.note:
                summary.notes.append(lock.note)
            info = {"fingerprint": key, "complete": False, "frames_total": len(frames)}
            if todo:
                self._run_todo(todo, rows, summary, info)
            elif not files.output.exists() or files.journal.exists():
                # finished in the journal but never consolidated: write the table now
                files.finish(rows, info)
            files.publish()
        summary.statuses = dict(collections.Counter(rows[f]["status"] for f in frames
                                                    if f in rows))
        summary.elapsed_s = time.perf_counter() - t0
        return summary

    def _n_rows(self, items: Sequence[Key]) -> int:
        """The rows of ``items``: one each, or the sizes the stage gave (a chunk's frames)."""
        if self.sizes is None:
            return len(items)
        return sum(int(self.sizes.get(k, 1)) for k in items)

    def _run_todo(self, todo: collections.deque[Key], rows: dict[Key, dict[str, Any]],
                  summary: BatchSummary, info: dict[str, Any]) -> None:
        opts = self.options
        n_failed = sum(1 for f in self.frames
                       if f in rows and rows[f]["status"] in FAILED_STATUSES)
        disable = None if opts.progress is None else not opts.progress
        with (
            backend_for(opts, self.backend) as be,
            progress_bar(self._n_rows(self.frames), self.table.desc, disable=disable) as bar,
        ):
            summary.backend = be.describe()
            info.update(summary.backend)
            bar.update(self._n_rows([f for f in self.frames if f in rows]))
            run = BatchRun(self.func, self.config, be, self.files, rows, bar, summary, info,
                            opts, n_failed)
            run.run(todo, self.load)


def run_batch(
    func: Callable[[Any, Any, Any], dict[str, Any]],
    config: Any,
    items: Sequence[Any],
    load: Callable[[Any], Any],
    table: StageTable,
    *,
    options: BatchSettings | None = None,
    backend: Backend | None = None,
    before_publish: Callable[[Path], Any] | None = None,
    sizes: Mapping[Any, int] | None = None,
) -> BatchSummary:
    """Run ``func`` on every item, in parallel, resumably, writing a table keyed by item.

    Parameters
    ----------
    func : callable
        Module-level item function ``func(config, key, payload) -> row dict``; the row
        should hold ``status`` (``ok``, ``not_converged``, ...) and ``message``.
    config : object
        Picklable settings passed to every call.
    items : sequence
        Keys of the items to run (:mod:`holofit.batch.keys`): frame numbers for the default
        key columns, tuples for several key columns.
    load : callable
        ``load(key)`` in the driver process returns the payload of an item, or a
        :class:`Precomputed` row. An exception is recorded as that item's ``error``.
    table : StageTable
        The CSV table written (path, columns, sidecar, fingerprint, the stage's name,
        ``finish``, key columns; :mod:`holofit.batch.layout`): its sidecar JSON beside it;
        while running, the journal ``<name>.csv.journal`` and the table so far,
        ``<name>.partial.csv``. Its folder is locked for the run
        (:func:`holofit.io.lock.output_lock`, stage ``table.desc``). Earlier results are
        reused only if their fingerprint matches.
    options : BatchSettings, optional
        Backend and resumption settings.
    backend : Backend, optional
        Use this backend (left open) instead of making one from ``options``.
    before_publish : callable, optional
        ``before_publish(table_path)`` is called with the complete table, written under the
        partial table's name, after the backend has closed and before it is renamed to
        its own name (the file ``make`` waits for, so the last one written): a stage draws
        its pictures there. An interruption keeps the journal; a rerun calls it again.
    sizes : mapping, optional
        Item key -> the rows it writes (a chunk of frames): the progress bar counts rows.

    Returns
    -------
    BatchSummary

    Raises
    ------
    holofit.io.lock.OutputLocked
        If another run is writing into the output folder.
    BatchError
        If earlier results came from other settings, the backend cannot start, or every
        item tried ended in ``error`` (no table is written then; the partial table and the
        journal hold the rows).
    SystemExit
        In a spawned worker re-running a script without the main guard (:mod:`.mainguard`).
    """
    refuse_while_worker_starts(f"the {table.desc} stage")
    table = replace(table, key_columns=check_key_columns(table.key_columns))
    items = _checked_frames(items, table.columns, table.key_columns)
    return _Batch(func, config, items, load, table, OutputFiles(table, before_publish),
                  options or BatchSettings(), backend,
                  None if sizes is None else {normal_key(k, table.key_columns): n
                                              for k, n in sizes.items()}).run()
