"""How a batch runs and what it did: its settings (:class:`BatchSettings`: workers, Dask,
resumption), the backend they choose (:func:`make_backend`), a row known without running
(:class:`Precomputed`) and the summary of a run (:class:`BatchSummary`)."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from holofit.batch.backends import (
    Backend,
    DaskBackend,
    ProcessPoolBackend,
    SerialBackend,
)
from holofit.status import FAILED_STATUSES

__all__ = [
    "FAILED_STATUSES",
    "BatchSettings",
    "BatchSummary",
    "Precomputed",
    "available_cpus",
    "backend_for",
    "make_backend",
]


@dataclass(frozen=True)
class Precomputed:
    """A frame whose row is known without running the frame function (e.g. no particle)."""

    row: dict[str, Any]


@dataclass(frozen=True)
class BatchSettings:
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
        On a rerun, run again the frames recorded as ``not_converged`` too (those recorded
        as ``error`` are always run again).
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
    """What a batch did.

    ``notes`` holds what the user should know that is not an error (e.g. that the lock of a
    killed earlier run was taken over).
    """

    output: Path
    n_frames: int
    n_done_before: int
    n_run: int
    statuses: dict[str, int] = field(default_factory=dict)
    elapsed_s: float = 0.0
    backend: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def n_failed(self) -> int:
        return sum(self.statuses.get(s, 0) for s in FAILED_STATUSES)


def available_cpus() -> int:
    """CPUs this process may run on."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # pragma: no cover - not Linux
        return max(os.cpu_count() or 1, 1)


def make_backend(options: BatchSettings) -> Backend:
    """The backend chosen by ``options``."""
    workers = options.workers if options.workers is not None else available_cpus()
    if options.scheduler:
        return DaskBackend(scheduler=options.scheduler)
    if options.dask_local:
        return DaskBackend(scheduler=None, workers=max(workers, 1))
    if workers == 0:
        return SerialBackend()
    return ProcessPoolBackend(workers)


@contextlib.contextmanager
def backend_for(options: BatchSettings, given: Backend | None) -> Iterator[Backend]:
    """The backend given (left open), or one made from ``options`` (closed afterwards)."""
    if given is not None:
        yield given
        return
    backend = make_backend(options)
    try:
        yield backend
    finally:
        backend.close()


#: the former name, kept for existing code (deprecated)
BatchOptions = BatchSettings
