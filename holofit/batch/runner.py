"""The per-frame batch runner shared by ``holofit prefit`` and ``holofit fit``.

A batch applies one *frame function* to many frames independently (DESIGN.md: frame k never
waits for frame k-1). The frame function is a module-level function
``func(config, frame, payload) -> dict`` (picklable, so it can run in another process or on
another machine); ``config`` is a dataclass of settings, ``payload`` what the driver loaded for
that frame (a crop and its crop-table row). It returns one table row.

What the runner guarantees:

- **Lazy input, bounded memory**: frames are loaded by the driver one at a time, just before
  they are submitted, with a bounded number in flight.
- **Parallel**: a local pool of single-threaded processes by default, in-process on request,
  or a Dask cluster (:mod:`holofit.batch.backends`); all give identical rows.
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
  finished table) and runs only the frames that are missing, so a run killed at any point
  (even by SIGKILL) finishes with the same table as an uninterrupted run. A rerun with other
  settings refuses to mix results unless told to overwrite.
"""

from __future__ import annotations

import collections
import contextlib
import math
import os
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.batch.backends import (
    Backend,
    DaskBackend,
    ProcessPoolBackend,
    SerialBackend,
    WorkerLost,
)
from holofit.batch.journal import Journal, JournalError, read_journal
from holofit.io.tables import read_table, sidecar_path, write_table
from holofit.progress import progress_bar
from holofit.status import ERROR, FAILED_STATUSES

__all__ = [
    "FAILED_STATUSES",
    "BatchError",
    "BatchOptions",
    "BatchSummary",
    "Precomputed",
    "available_cpus",
    "journal_path",
    "make_backend",
    "partial_path",
    "run_batch",
    "run_frame",
]



class BatchError(RuntimeError):
    """A batch cannot start (conflicting earlier results, bad options)."""


@dataclass(frozen=True)
class Precomputed:
    """A frame whose row is known without running the frame function (e.g. no particle)."""

    row: dict[str, Any]


@dataclass(frozen=True)
class BatchOptions:
    """How a batch runs.

    Attributes
    ----------
    workers : int, optional
        Worker processes (default: the CPUs available to this process); 0 runs the frames in
        this process. With ``dask_local``, the workers of the local Dask cluster.
    scheduler : str, optional
        Address (``tcp://host:8786``) or scheduler-file path of a running Dask scheduler.
    dask_local : bool
        Run on a Dask ``LocalCluster`` on 127.0.0.1 (mostly to check a Dask set-up).
    retry_failed : bool
        On a rerun, run again the frames recorded as ``error`` or ``not_converged``.
    overwrite : bool
        Discard earlier results of the same output even if they came from other settings.
    progress : bool, optional
        Show a progress bar (default: when stderr is a terminal).
    flush_interval_s : float
        Seconds between atomic rewrites of the output table while the batch runs.
    max_in_flight : int, optional
        Frames submitted but not finished (default: 2 per worker + 2).
    """

    workers: int | None = None
    scheduler: str | None = None
    dask_local: bool = False
    retry_failed: bool = False
    overwrite: bool = False
    progress: bool | None = None
    flush_interval_s: float = 5.0
    max_in_flight: int | None = None

    def __post_init__(self) -> None:
        if self.workers is not None and self.workers < 0:
            raise ValueError(f"workers must be >= 0, got {self.workers}")
        if self.scheduler and self.dask_local:
            raise ValueError("give either a Dask scheduler address or dask_local, not both")


@dataclass
class BatchSummary:
    """What a batch did."""

    output: Path
    n_frames: int
    n_done_before: int
    n_run: int
    statuses: dict[str, int] = field(default_factory=dict)
    elapsed_s: float = 0.0
    backend: dict[str, Any] = field(default_factory=dict)

    @property
    def n_failed(self) -> int:
        return sum(self.statuses.get(s, 0) for s in FAILED_STATUSES)


def available_cpus() -> int:
    """CPUs this process may run on."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # pragma: no cover - not Linux
        return max(os.cpu_count() or 1, 1)


def journal_path(output: str | Path) -> Path:
    """``prefit.csv`` -> ``prefit.csv.journal``."""
    output = Path(output)
    return output.with_name(output.name + ".journal")


def partial_path(output: str | Path) -> Path:
    """``prefit.csv`` -> ``prefit.partial.csv``: the table of the frames done so far."""
    output = Path(output)
    return output.with_name(output.stem + ".partial" + output.suffix)


def _remove_partial(output: Path) -> None:
    part = partial_path(output)
    for p in (part, sidecar_path(part)):
        with contextlib.suppress(FileNotFoundError):
            p.unlink()


def make_backend(options: BatchOptions) -> Backend:
    """The backend chosen by ``options``."""
    workers = options.workers if options.workers is not None else available_cpus()
    if options.scheduler:
        return DaskBackend(scheduler=options.scheduler)
    if options.dask_local:
        return DaskBackend(scheduler=None, workers=max(workers, 1))
    if workers == 0:
        return SerialBackend()
    return ProcessPoolBackend(workers)


def run_frame(
    func: Callable[[Any, int, Any], dict[str, Any]], config: Any, frame: int, payload: Any
) -> dict[str, Any]:
    """Run the frame function for one frame, turning an exception into an ``error`` row.

    This is what a worker executes. ``fit_time_s`` (wall time in the worker) is added if the
    frame function did not set it.
    """
    t0 = time.perf_counter()
    try:
        row = dict(func(config, frame, payload))
    except Exception as exc:
        where = traceback.extract_tb(exc.__traceback__)[-1]
        row = {
            "status": ERROR,
            "message": f"{type(exc).__name__}: {exc} "
            f"(at {Path(where.filename).name}:{where.lineno})",
        }
    row["frame"] = int(frame)
    row.setdefault("fit_time_s", time.perf_counter() - t0)
    return row


def _complete_row(row: dict[str, Any], columns: Sequence[str]) -> dict[str, Any]:
    out = {c: row.get(c, math.nan) for c in columns}
    out["frame"] = int(row["frame"])
    out["status"] = str(row.get("status") or ERROR)
    msg = row.get("message")
    out["message"] = "" if msg is None or (isinstance(msg, float) and math.isnan(msg)) else msg
    return out


def _rows_from_table(path: Path, columns: Sequence[str]) -> dict[int, dict[str, Any]]:
    table = read_table(path)
    missing = set(columns) - set(table.columns)
    if missing:
        raise BatchError(
            f"{path}: existing table lacks column(s) {', '.join(sorted(missing))}; "
            "use --overwrite or another output"
        )
    rows = {}
    for rec in table.to_dict(orient="records"):
        rows[int(rec["frame"])] = _complete_row(rec, columns)
    return rows


def _read_fingerprint(path: Path) -> str | None:
    import json

    side = sidecar_path(path)
    if not side.exists():
        return None
    try:
        return json.loads(side.read_text()).get("batch", {}).get("fingerprint")
    except (ValueError, AttributeError):
        return None


def _earlier_rows(
    output: Path, columns: Sequence[str], fingerprint: str, overwrite: bool
) -> dict[int, dict[str, Any]]:
    """Rows of an earlier run of the same batch (journal first, else the finished table)."""
    jpath = journal_path(output)
    if overwrite:
        for p in (jpath, output, sidecar_path(output)):
            with contextlib.suppress(FileNotFoundError):
                p.unlink()
        _remove_partial(output)
        return {}
    hint = "rerun with --overwrite to discard them, or choose another output"
    if jpath.exists():
        try:
            header, rows, _ = read_journal(jpath)
        except JournalError as exc:
            raise BatchError(f"{exc}; {hint}") from None
        if header.get("fingerprint") != fingerprint:
            raise BatchError(
                f"{jpath}: holds results of a batch with other settings or inputs; {hint}"
            )
        return {k: _complete_row(r, columns) for k, r in rows.items()}
    if output.exists():
        if _read_fingerprint(output) != fingerprint:
            raise BatchError(f"{output}: exists and was made with other settings or inputs; {hint}")
        return _rows_from_table(output, columns)
    return {}


def _write(
    output: Path,
    rows: dict[int, dict[str, Any]],
    columns: Sequence[str],
    meta: dict[str, Any],
    batch_info: dict[str, Any],
) -> None:
    frames = sorted(rows)
    table = pd.DataFrame([rows[f] for f in frames], columns=list(columns))
    doc = dict(meta)
    doc["batch"] = batch_info | {"frames_done": len(frames)}
    write_table(output, table, doc)


def run_batch(
    func: Callable[[Any, int, Any], dict[str, Any]],
    config: Any,
    frames: Sequence[int],
    load: Callable[[int], Any],
    output: str | Path,
    columns: Sequence[str],
    *,
    fingerprint: str,
    meta: dict[str, Any] | None = None,
    options: BatchOptions | None = None,
    backend: Backend | None = None,
    desc: str = "batch",
) -> BatchSummary:
    """Run ``func`` on every frame, in parallel, resumably, writing a table keyed by frame.

    Parameters
    ----------
    func : callable
        Module-level frame function ``func(config, frame, payload) -> row dict``; the row
        should hold ``status`` (``ok``, ``not_converged``, ...) and ``message``.
    config : object
        Picklable settings passed to every call.
    frames : sequence of int
        Frames to run.
    load : callable
        ``load(frame)`` in the driver process returns the payload of a frame, or a
        :class:`Precomputed` row. An exception is recorded as that frame's ``error``.
    output : str or Path
        The CSV table (sidecar JSON beside it; while running, the journal
        ``<output>.journal`` and the table so far, ``<name>.partial.csv``).
    columns : sequence of str
        Columns of the table, in order; must include ``frame``, ``status``, ``message``.
    fingerprint : str
        Identity of the settings and inputs: earlier results are reused only if it matches.
    meta : dict, optional
        Sidecar document (:func:`holofit.provenance.sidecar`); a ``batch`` entry is added.
    options : BatchOptions, optional
        Backend and resumption settings.
    backend : Backend, optional
        Use this backend instead of making one from ``options`` (it is not closed).
    desc : str
        Label of the progress bar.

    Returns
    -------
    BatchSummary
    """
    t0 = time.perf_counter()
    opts = options or BatchOptions()
    output = Path(output)
    columns = list(columns)
    for required in ("frame", "status", "message"):
        if required not in columns:
            raise ValueError(f"columns must include {required!r}")
    frames = [int(f) for f in frames]
    if len(set(frames)) != len(frames):
        raise ValueError("frames must be unique")
    meta = dict(meta or {})

    rows = _earlier_rows(output, columns, fingerprint, opts.overwrite)
    if opts.retry_failed:
        rows = {k: r for k, r in rows.items() if r["status"] not in FAILED_STATUSES}
    wanted = set(frames)
    todo = collections.deque(f for f in frames if f not in rows)
    n_before = len(wanted) - len(todo)
    summary = BatchSummary(output, len(frames), n_before, 0)

    def statuses() -> dict[str, int]:
        return dict(collections.Counter(rows[f]["status"] for f in frames if f in rows))

    jpath = journal_path(output)
    if not todo:
        if not output.exists() or jpath.exists():
            # finished in the journal but never consolidated: write the table now
            info = {"fingerprint": fingerprint, "complete": True, "frames_total": len(frames)}
            _write(output, rows, columns, meta, info)
            with contextlib.suppress(FileNotFoundError):
                jpath.unlink()
            _remove_partial(output)
        summary.statuses = statuses()
        summary.elapsed_s = time.perf_counter() - t0
        return summary

    own_backend = backend is None
    be = backend or make_backend(opts)
    summary.backend = be.describe()
    info = {
        "fingerprint": fingerprint,
        "complete": False,
        "frames_total": len(frames),
        **summary.backend,
    }
    max_in_flight = opts.max_in_flight or 2 * be.slots + 2
    fresh_journal = not jpath.exists()
    journal = Journal(jpath, {"fingerprint": fingerprint, "columns": columns})
    if fresh_journal:
        for f in sorted(rows):  # rows of a finished table: keep them if this run is killed
            journal.append(rows[f])
    bar = progress_bar(
        len(frames), desc, disable=None if opts.progress is None else not opts.progress
    )
    bar.update(n_before)
    in_flight: dict[Any, tuple[int, Any, int]] = {}
    retry: collections.deque[tuple[int, Any, int]] = collections.deque()
    last_flush = time.monotonic()
    n_failed = sum(1 for f in frames if f in rows and rows[f]["status"] in FAILED_STATUSES)

    def record(row: dict[str, Any]) -> None:
        nonlocal n_failed
        full = _complete_row(row, columns)
        rows[full["frame"]] = full
        journal.append(full)
        summary.n_run += 1
        if full["status"] in FAILED_STATUSES:
            n_failed += 1
            bar.set_postfix(failed=n_failed, refresh=False)
        bar.update(1)

    def submit(frame: int, payload: Any, attempts: int) -> None:
        fut = be.submit(run_frame, func, config, frame, payload)
        in_flight[fut] = (frame, payload, attempts)

    try:
        while todo or in_flight or retry:
            # frames that were running when a worker died go one at a time, alone
            quarantine = any(a >= 1 for _, _, a in in_flight.values())
            if retry and not in_flight:
                submit(*retry.popleft())
                quarantine = True
            while todo and not retry and not quarantine and len(in_flight) < max_in_flight:
                frame = todo.popleft()
                try:
                    payload = load(frame)
                except Exception as exc:
                    record({"frame": frame, "status": ERROR, "message": f"loading: {exc}"})
                    continue
                if isinstance(payload, Precomputed):
                    record({**payload.row, "frame": frame})
                    continue
                submit(frame, payload, 0)
            if not in_flight:
                continue
            for fut in be.wait(in_flight, timeout=0.5):
                frame, payload, attempts = in_flight.pop(fut)
                try:
                    record(be.result(fut))
                except WorkerLost as exc:
                    if be.isolates_lost_workers:
                        record({"frame": frame, "status": ERROR, "message": str(exc)})
                        continue
                    lost = [(frame, payload, attempts), *list(in_flight.values())]
                    in_flight.clear()
                    be.restart()
                    for f, p, a in lost:
                        if a >= 1 and len(lost) == 1:  # it ran alone: it killed the worker
                            record({"frame": f, "status": ERROR, "message": str(exc)})
                        else:
                            retry.append((f, p, a + 1))
                    break
                except Exception as exc:  # infrastructure error for this one future
                    record({"frame": frame, "status": ERROR, "message": f"{exc}"})
            if time.monotonic() - last_flush >= opts.flush_interval_s:
                _write(partial_path(output), rows, columns, meta, info)
                last_flush = time.monotonic()
        info["complete"] = True
        _write(output, rows, columns, meta, info)
        journal.close()
        jpath.unlink()
        _remove_partial(output)
    except BaseException:
        # keep what is done: results already back, then the table of everything recorded
        for fut in list(in_flight):
            if fut.done():
                with contextlib.suppress(BaseException):
                    record(be.result(fut))
        journal.close()
        with contextlib.suppress(Exception):
            _write(partial_path(output), rows, columns, meta, info)
        raise
    finally:
        bar.close()
        if own_backend:
            be.close()
    summary.statuses = statuses()
    summary.elapsed_s = time.perf_counter() - t0
    return summary
