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
here, :func:`run_batch` checks its arguments and takes the folder lock, and :class:`_BatchRun`
owns the state of one run (rows, journal, progress, frames in flight) and moves frames through
it: :meth:`~_BatchRun.feed` loads and submits, :meth:`~_BatchRun.collect` takes finished frames
(and handles dead workers), :meth:`~_BatchRun.record` files one row, :meth:`~_BatchRun.flush`
rewrites the partial table.
"""

from __future__ import annotations

import collections
import contextlib
import functools
import time
import traceback
import warnings
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from holofit.batch.backends import Backend
from holofit.batch.errors import BatchError, WorkerLost
from holofit.batch.journal import Journal
from holofit.batch.keys import (
    FRAME_KEY,
    Key,
    check_key_columns,
    item_rows,
    key_of_row,
    key_row,
    normal_key,
)
from holofit.batch.layout import (
    OutputFiles,
    StageTable,
    earlier_fingerprint,
    earlier_rows,
    journal_path,
    partial_path,
)
from holofit.batch.mainguard import GUARD_ADVICE, refuse_while_worker_starts
from holofit.batch.options import (
    BatchOptions,
    BatchSummary,
    Precomputed,
    available_cpus,
    backend_for,
    make_backend,
)
from holofit.io.lock import output_lock
from holofit.progress import progress_bar
from holofit.status import ERROR, FAILED_STATUSES, SKIPPED

__all__ = [
    "FAILED_STATUSES",
    "BatchError",
    "BatchOptions",
    "BatchSummary",
    "Precomputed",
    "StageTable",
    "available_cpus",
    "earlier_fingerprint",
    "journal_path",
    "make_backend",
    "partial_path",
    "run_batch",
    "run_frame",
]

#: seconds the driver waits for a finished frame before it looks at the clock again
WAIT_S = 0.5


def run_frame(
    func: Callable[[Any, Any, Any], Any], config: Any, frame: Key, payload: Any,
    key_columns: Sequence[str] = FRAME_KEY,
) -> dict[str, Any] | list[dict[str, Any]]:
    """Run the frame function for one item (a frame), turning an exception into an ``error``
    row.

    This is what a worker executes. The item's key columns (:mod:`holofit.batch.keys`) are
    set from its key; ``fit_time_s`` (wall time in the worker) is added if the frame function
    did not set it. A *multi-row item* (e.g. a chunk of a track: :mod:`holofit.fit.tracked`)
    returns a list of rows, each with its own key columns, one of them the item's own key:
    that row is put last (:func:`holofit.batch.keys.item_rows`), so that a journal holding
    it holds the whole item.
    """
    t0 = time.perf_counter()
    try:
        got = func(config, frame, payload)
        if isinstance(got, list):
            rows = item_rows(got, frame, key_columns)
            for row in rows:
                row.setdefault("fit_time_s", (time.perf_counter() - t0) / len(rows))
            return rows
        row = dict(got)
    except Exception as exc:
        where = traceback.extract_tb(exc.__traceback__)[-1]
        row = {
            "status": ERROR,
            "message": f"{type(exc).__name__}: {exc} "
            f"(at {Path(where.filename).name}:{where.lineno})",
        }
    row.update(key_row(frame, key_columns))
    row.setdefault("fit_time_s", time.perf_counter() - t0)
    return row


@dataclass(frozen=True)
class _Task:
    """An item on its way to a worker; ``attempts`` counts the workers it was lost with."""

    frame: Key
    payload: Any
    attempts: int = 0


class _BatchRun:
    """The state of one run: rows so far, journal, progress bar, frames in flight.

    Parameters
    ----------
    func, config
        The frame function and its settings.
    backend : Backend
        Where frames run.
    files : OutputFiles
        The output's files; the journal is continued or started here.
    rows : dict
        Frame -> complete row of the frames done (earlier runs included); updated in place.
    progress : tqdm
        The progress bar.
    summary : BatchSummary
        ``n_run`` is counted up.
    info : dict
        The sidecar's ``batch`` entry.
    options : BatchOptions
        In-flight bound and flush interval.
    n_failed : int
        Failed frames among those done before (shown beside the progress bar).
    """

    def __init__(
        self,
        func: Callable[[Any, Any, Any], dict[str, Any]],
        config: Any,
        backend: Backend,
        files: OutputFiles,
        rows: dict[Key, dict[str, Any]],
        progress: Any,
        summary: BatchSummary,
        info: dict[str, Any],
        options: BatchOptions,
        n_failed: int,
    ) -> None:
        self.func = func
        self.config = config
        self.backend = backend
        self.files = files
        self.rows = rows
        self.progress = progress
        self.summary = summary
        self.info = info
        self.max_in_flight = options.max_in_flight or 2 * backend.slots + 2
        self.flush_interval_s = options.flush_interval_s
        self.n_failed = n_failed
        self.in_flight: dict[Any, _Task] = {}
        self.retry: collections.deque[_Task] = collections.deque()
        self.journal = _open_journal(files, info["fingerprint"], rows)
        #: what a worker runs: the frame function for one item, its key columns set
        self.run_item = (run_frame if files.key_columns == FRAME_KEY
                         else functools.partial(run_frame, key_columns=files.key_columns))
        self._last_flush = time.monotonic()

    def run(self, todo: collections.deque[Key], load: Callable[[Any], Any]) -> None:
        """Run every frame of ``todo``; on success write the final table; on any
        interruption keep what is done (journal, partial table) and re-raise; if every
        frame ended in ``error``, write the partial table only and raise :class:`BatchError`."""
        try:
            while todo or self.in_flight or self.retry:
                self.feed(todo, load)
                if not self.in_flight:
                    continue
                self.collect(WAIT_S)
                self.flush()
            self.journal.close()
            failure = _total_failure(self.rows, self.files)
            if failure:  # no table: the journal and the partial table keep the rows
                self.files.write(self.rows, self.info, final=False)
            else:
                self.files.finish(self.rows, self.info)
        except BaseException:
            self.salvage()
            raise
        if failure:
            raise BatchError(failure)

    def record(self, row: dict[str, Any] | list[dict[str, Any]]) -> None:
        """File one finished item (one row, or a multi-row item's rows, its own last): rows,
        journal, progress."""
        for one in row if isinstance(row, list) else [row]:
            full = self.files.complete(one)
            self.rows[key_of_row(full, self.files.key_columns)] = full
            self.journal.append(full)
        self.summary.n_run += 1
        if full["status"] in FAILED_STATUSES:
            self.n_failed += 1
            self.progress.set_postfix(failed=self.n_failed, refresh=False)
        self.progress.update(1)

    def submit(self, task: _Task) -> None:
        fut = self.backend.submit(self.run_item, self.func, self.config, task.frame,
                                  task.payload)
        self.in_flight[fut] = task

    def failed_row(self, key: Key, message: str) -> dict[str, Any]:
        """The ``error`` row of item ``key``."""
        return {**key_row(key, self.files.key_columns), "status": ERROR, "message": message}

    def feed(self, todo: collections.deque[Key], load: Callable[[Any], Any]) -> None:
        """Load and submit frames while the in-flight bound allows; frames that were running
        when a worker died go one at a time, alone (quarantine)."""
        quarantine = any(t.attempts >= 1 for t in self.in_flight.values())
        if self.retry and not self.in_flight:
            self.submit(self.retry.popleft())
            quarantine = True
        while (todo and not self.retry and not quarantine
               and len(self.in_flight) < self.max_in_flight):
            frame = todo.popleft()
            try:
                payload = load(frame)
            except Exception as exc:
                self.record(self.failed_row(frame, f"loading: {exc}"))
                continue
            if isinstance(payload, Precomputed):
                self.record({**payload.row, **key_row(frame, self.files.key_columns)})
                continue
            self.submit(_Task(frame, payload))

    def collect(self, timeout: float) -> None:
        """Record the frames that finish within ``timeout`` s."""
        for fut in self.backend.wait(self.in_flight, timeout=timeout):
            task = self.in_flight.pop(fut)
            try:
                self.record(self.backend.result(fut))
            except WorkerLost as exc:
                if self.backend.isolates_lost_workers:  # only this frame was lost
                    self._requeue([task], exc)
                    continue
                self._worker_lost(task, exc)
                break
            except Exception as exc:  # infrastructure error for this one future
                self.record(self.failed_row(task.frame, f"{exc}"))

    def _worker_lost(self, task: _Task, exc: WorkerLost) -> None:
        """A pool worker died: every frame in flight is lost. Restart the pool, requeue them."""
        lost = [task, *self.in_flight.values()]
        self.in_flight.clear()
        self.backend.restart()
        self._requeue(lost, exc)

    def _requeue(self, lost: list[_Task], exc: WorkerLost) -> None:
        """Frames lost with a worker are retried one at a time, alone (a frame that was only
        beside the culprit then succeeds); a frame that ran alone and lost its worker again
        killed it: ``error``."""
        for t in lost:
            if t.attempts >= 1 and len(lost) == 1:
                self.record(self.failed_row(t.frame, str(exc)))
            else:
                self.retry.append(_Task(t.frame, t.payload, t.attempts + 1))

    def flush(self) -> None:
        """Rewrite the partial table if the last rewrite is ``flush_interval_s`` old."""
        if time.monotonic() - self._last_flush >= self.flush_interval_s:
            self.files.write(self.rows, self.info, final=False)
            self._last_flush = time.monotonic()

    def salvage(self) -> None:
        """After an interruption: record results already back, close the journal, write the
        partial table of everything recorded."""
        for fut in list(self.in_flight):
            if fut.done():
                with contextlib.suppress(BaseException):
                    self.record(self.backend.result(fut))
        self.journal.close()
        with contextlib.suppress(Exception):
            self.files.write(self.rows, self.info, final=False)


#: messages of frames whose worker died (holofit.batch.backends)
_WORKER_DIED = ("a worker process died", "Dask workers died")


def _total_failure(rows: dict[Key, dict[str, Any]], files: OutputFiles) -> str:
    """Why a batch failed as a whole ('' if it did not): every frame tried (not ``skipped``)
    ended in ``error``."""
    tried = [r for r in rows.values() if r["status"] != SKIPPED]
    if not tried or any(r["status"] != ERROR for r in tried):
        return ""
    messages = collections.Counter(str(r.get("message") or "(no message)") for r in tried)
    message, count = messages.most_common(1)[0]
    if any(message.startswith(w) for w in _WORKER_DIED):
        cause = ("workers that die on every frame are most often started by a script that "
                 "calls holofit's stages without the main guard, which they run again: "
                 f"{GUARD_ADVICE}; or they lack memory: use fewer (-j, JOBS=)")
    else:
        cause = "fix the cause and rerun: frames in error are run again"
    return (f"every frame failed: {len(tried)} of {len(tried)} in error; the most common "
            f"message ({count} frame(s)): {message}. {cause[0].upper()}{cause[1:]}; each "
            f"frame's message is in {files.partial}")


def _open_journal(
    files: OutputFiles, fingerprint: str, rows: dict[Key, dict[str, Any]]
) -> Journal:
    """Continue the journal, or start one holding the rows of a finished table (so that
    they survive if this run is killed)."""
    fresh = not files.journal.exists()
    header: dict[str, Any] = {"fingerprint": fingerprint, "columns": files.columns}
    if files.key_columns != FRAME_KEY:
        header["key_columns"] = list(files.key_columns)
    journal = Journal(files.journal, header)
    if fresh:
        for f in sorted(rows):
            journal.append(rows[f])
    return journal


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
    options: BatchOptions
    backend: Backend | None

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

    def _run_todo(self, todo: collections.deque[Key], rows: dict[Key, dict[str, Any]],
                  summary: BatchSummary, info: dict[str, Any]) -> None:
        opts = self.options
        n_failed = sum(1 for f in self.frames
                       if f in rows and rows[f]["status"] in FAILED_STATUSES)
        disable = None if opts.progress is None else not opts.progress
        with (
            backend_for(opts, self.backend) as be,
            progress_bar(len(self.frames), self.table.desc, disable=disable) as bar,
        ):
            summary.backend = be.describe()
            info.update(summary.backend)
            bar.update(summary.n_done_before)
            run = _BatchRun(self.func, self.config, be, self.files, rows, bar, summary, info,
                            opts, n_failed)
            run.run(todo, self.load)


#: the keywords of the old form of :func:`run_batch` (the table's fields spelled out)
_LEGACY_TABLE = ("columns", "fingerprint", "meta", "desc", "finish", "key_columns")


def _legacy_table(output: str | Path, columns: tuple[Any, ...],
                  given: dict[str, Any]) -> StageTable:
    """The :class:`StageTable` of a call in the old form ``run_batch(func, config, frames,
    load, output, columns, *, fingerprint, meta, desc, finish, key_columns, ...)``."""
    unknown = sorted(set(given) - set(_LEGACY_TABLE))
    if unknown:
        raise TypeError(f"run_batch() got unexpected keyword argument(s) {unknown}")
    if len(columns) > 1 or (columns and "columns" in given) or not (columns or "columns" in given):
        raise TypeError("run_batch() takes its table as one StageTable")
    if "fingerprint" not in given:
        raise TypeError("run_batch() needs a StageTable (or, in the old form, fingerprint=)")
    warnings.warn("run_batch(func, config, frames, load, output, columns, fingerprint=...) is "
                  "deprecated: give the table as a StageTable", DeprecationWarning,
                  stacklevel=3)
    cols = columns[0] if columns else given["columns"]
    return StageTable(Path(output), tuple(cols), dict(given.get("meta") or {}),
                      given["fingerprint"], given.get("desc", "batch"), given.get("finish"),
                      tuple(given.get("key_columns", FRAME_KEY)))


def run_batch(
    func: Callable[[Any, Any, Any], dict[str, Any]],
    config: Any,
    items: Sequence[Any],
    load: Callable[[Any], Any],
    table: StageTable,
    *legacy: Any,
    options: BatchOptions | None = None,
    backend: Backend | None = None,
    before_publish: Callable[[Path], Any] | None = None,
    **legacy_table: Any,
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
    options : BatchOptions, optional
        Backend and resumption settings.
    backend : Backend, optional
        Use this backend (left open) instead of making one from ``options``.
    before_publish : callable, optional
        ``before_publish(table_path)`` is called with the complete table, written under the
        partial table's name, after the backend has closed and before it is renamed to
        its own name (the file ``make`` waits for, so the last one written): a stage draws
        its pictures there. An interruption keeps the journal; a rerun calls it again.
    *legacy, **legacy_table
        Deprecated: the old form, ``table`` a path followed by ``columns`` and the keywords
        ``fingerprint``, ``meta``, ``desc``, ``finish``, ``key_columns``.

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
    if not isinstance(table, StageTable):
        table = _legacy_table(table, legacy, legacy_table)
    elif legacy or legacy_table:
        raise TypeError("run_batch() takes its table as one StageTable: no columns or "
                        f"table keywords beside it (got {sorted(legacy_table)})")
    refuse_while_worker_starts(f"the {table.desc} stage")
    table = replace(table, key_columns=check_key_columns(table.key_columns))
    items = _checked_frames(items, table.columns, table.key_columns)
    return _Batch(func, config, items, load, table, OutputFiles(table, before_publish),
                  options or BatchOptions(), backend).run()
