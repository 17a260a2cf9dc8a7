"""The run loop of one batch: what a worker runs for an item (:func:`run_frame`) and the
driver's state of one run (:class:`BatchRun`: rows so far, journal, progress, frames in
flight), which moves frames through it: :meth:`~BatchRun.feed` loads and submits,
:meth:`~BatchRun.collect` takes finished frames (and handles dead workers),
:meth:`~BatchRun.record` files one row, :meth:`~BatchRun.flush` rewrites the partial table.

:func:`holofit.batch.runner.run_batch` checks the arguments, takes the folder's lock and finds
the rows of earlier runs before it hands the rest to a :class:`BatchRun`.
"""

from __future__ import annotations

import collections
import contextlib
import functools
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from holofit.batch.backends import Backend
from holofit.batch.errors import BatchError, WorkerLost
from holofit.batch.journal import Journal
from holofit.batch.keys import FRAME_KEY, Key, item_rows, key_of_row, key_row, sorted_keys
from holofit.batch.layout import OutputFiles
from holofit.batch.mainguard import GUARD_ADVICE
from holofit.batch.options import BatchSettings, BatchSummary, Precomputed
from holofit.status import ERROR, FAILED_STATUSES, SKIPPED

__all__ = ["WAIT_S", "BatchRun", "run_frame"]

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


class BatchRun:
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
    options : BatchSettings
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
        options: BatchSettings,
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
        self.journal = open_journal(files, info["fingerprint"], rows)
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
            failure = total_failure(self.rows, self.files)
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
        # a multi-row item (a chunk of frames) advances the bar by its frames
        self.progress.update(len(row) if isinstance(row, list) else 1)

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


def total_failure(rows: dict[Key, dict[str, Any]], files: OutputFiles) -> str:
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


def open_journal(
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
        for f in sorted_keys(rows):
            journal.append(rows[f])
    return journal


