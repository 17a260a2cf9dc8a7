"""Per-frame batch processing shared by ``holofit prefit``, ``holofit library`` and ``holofit
fit``: parallel (local processes or Dask), failure-isolating, resumable, writing results as they
come.
See :mod:`holofit.batch.runner`."""

from holofit.batch.backends import DaskBackend, ProcessPoolBackend, SerialBackend
from holofit.batch.errors import BatchError, SchedulerError, WorkerLost
from holofit.batch.runner import (
    FAILED_STATUSES,
    BatchOptions,
    BatchSummary,
    Precomputed,
    journal_path,
    make_backend,
    partial_path,
    run_batch,
    run_frame,
)

__all__ = [
    "FAILED_STATUSES",
    "BatchError",
    "BatchOptions",
    "BatchSummary",
    "DaskBackend",
    "Precomputed",
    "ProcessPoolBackend",
    "SchedulerError",
    "SerialBackend",
    "WorkerLost",
    "journal_path",
    "make_backend",
    "partial_path",
    "run_batch",
    "run_frame",
]
