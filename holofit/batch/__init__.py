"""Per-frame batch processing shared by the stages (``holofit crop``'s search, ``prefit``,
``library``, ``fit``): parallel (local processes or Dask), failure-isolating, resumable,
writing results as they come.

- :mod:`holofit.batch.runner`: :func:`run_batch`; :mod:`holofit.batch.loop`, its run loop;
- :mod:`holofit.batch.options`: how a batch runs (:class:`BatchSettings`) and what it did
  (:class:`BatchSummary`);
- :mod:`holofit.batch.layout`: a stage table's files (:class:`StageTable`), publishing a
  derived table (:func:`publish_table`), its fingerprint (:func:`published_fingerprint`),
  removing its files (:func:`discard_outputs`);
- :mod:`holofit.batch.worker`: what a frame function makes once per worker process
  (:func:`worker_resource`);
- :mod:`holofit.batch.stage`: the stage skeleton (:func:`~holofit.batch.stage.run_stage`).

``journal_path`` and ``partial_path`` are exported for the tests that look into a run's files;
a stage uses the functions above instead.
"""

from holofit.batch.backends import DaskBackend, ProcessPoolBackend, SerialBackend
from holofit.batch.errors import BatchError, SchedulerError, WorkerLost
from holofit.batch.layout import (
    StageTable,
    discard_outputs,
    earlier_fingerprint,
    journal_path,
    partial_path,
    publish_table,
    published_fingerprint,
)
from holofit.batch.loop import run_frame
from holofit.batch.options import (
    FAILED_STATUSES,
    BatchSettings,
    BatchSummary,
    Precomputed,
    make_backend,
)
from holofit.batch.runner import run_batch
from holofit.batch.worker import release_worker_resources, worker_resource

__all__ = [
    "FAILED_STATUSES",
    "BatchError",
    "BatchSettings",
    "BatchSummary",
    "DaskBackend",
    "Precomputed",
    "ProcessPoolBackend",
    "SchedulerError",
    "SerialBackend",
    "StageTable",
    "WorkerLost",
    "discard_outputs",
    "earlier_fingerprint",
    "journal_path",
    "make_backend",
    "partial_path",
    "publish_table",
    "published_fingerprint",
    "release_worker_resources",
    "run_batch",
    "run_frame",
    "worker_resource",
]
