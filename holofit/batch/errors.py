"""The batch runner's error types (apart, so that the backends and the runner share them)."""

from __future__ import annotations

__all__ = ["BatchError", "SchedulerError", "WorkerLost"]


class BatchError(RuntimeError):
    """A batch cannot start (conflicting earlier results, bad options, no cluster)."""


class SchedulerError(BatchError):
    """The Dask scheduler given cannot be used: no scheduler file, or no answer at the address."""


class WorkerLost(RuntimeError):
    """A worker process died (crash, out of memory, killed) while running a frame."""
