"""The stage skeleton: what every per-frame stage does around its frame function.

A stage (``holofit prefit``, ``holofit library``, both passes of ``holofit fit``, the
continuity sweeps) is

1. **inputs**: the crop folder (:func:`stage_inputs`: crops, instrument, the frames asked for,
   checked by :func:`check_frames`), and the tables of earlier stages;
2. **the shared frame loader and skip policy** (:class:`FrameLoader`): a frame is loaded only
   if the crop stage found a particle in it (:func:`crop_skip`), the prefit left a usable
   start (:func:`holofit.tables.inputs.usable_start`) and, where the stage needs one, the
   library found a candidate orientation; otherwise it becomes a ``skipped`` row without
   running;
3. **the batch** (:func:`holofit.batch.runner.run_batch`): parallel, resumable, failures
   recorded; its table (:class:`~holofit.batch.layout.StageTable`) laid out and published by
   :mod:`holofit.batch.layout` alone; what a frame function makes once per worker (an engine,
   a library, an open movie) kept by :func:`holofit.batch.worker.worker_resource`;
4. **a fingerprint** of the settings and inputs (:func:`fingerprint`): earlier results are
   reused only if it matches;
5. **finish and plots** (:func:`run_stage`'s ``complete``): run on the complete table before
   it is published under its own name, or on the published table when it was complete before
   this run.

The table is keyed by its key columns (:mod:`holofit.batch.keys`; ``("particle", "frame")``
for the stages here, the crop folder's :attr:`holofit.tables.cropset.CropSet.key_columns`):
:func:`run_stage` passes them to the runner untouched, and the loader takes such keys.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from holofit.batch.aperture import FROM_INSTRUMENT, ApertureChoice, fit_instrument
from holofit.batch.layout import StageTable
from holofit.batch.options import BatchSettings, BatchSummary, Precomputed
from holofit.batch.runner import run_batch
from holofit.config import Instrument
from holofit.status import FITTABLE_CROP_STATUSES, SKIPPED
from holofit.tables.cropset import CropSet, CropSetError, resolve_instrument
from holofit.tables.inputs import usable_start
from holofit.tables.library import candidate_values, n_candidate_columns

__all__ = [
    "START_COLUMNS",
    "FrameLoader",
    "FrameStart",
    "StageInputs",
    "StageTable",
    "check_frames",
    "crop_skip",
    "fingerprint",
    "run_stage",
    "stage_inputs",
]

#: the prefit's values a later stage starts from
START_COLUMNS = ("x_um", "y_um", "z_um", "alpha")
#: the crop-table values a frame needs to be fitted
_CROP_NEEDED = ("x_um", "y_um", "corner_row", "corner_col")


def fingerprint(doc: Any) -> str:
    """Identity of settings and inputs: 16 hex digits of the SHA-256 of ``doc`` as canonical
    JSON (keys sorted; values JSON cannot hold are written as ``str``)."""
    text = json.dumps(doc, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def check_frames(crops: CropSet, frames: Sequence[int] | None) -> list[Any]:
    """The frames a stage runs: all of the crop folder's, or ``frames``, each of which it must
    hold; for a folder of several tracks, the ``(particle, frame)`` keys of those frames.

    Raises
    ------
    CropSetError
        A frame the crop table does not have (the first five are named).
    """
    asked = None if frames is None else [int(f) for f in frames]
    unknown = sorted(set(asked or []) - set(crops.frames))
    if unknown:
        raise CropSetError(f"{crops.table_path}: no frame(s) {unknown[:5]}")
    if asked is None:
        return list(crops.keys)
    by_frame: dict[int, list[Any]] = {}
    for k in crops.keys:
        by_frame.setdefault(int(k[1]), []).append(k)
    return [k for f in asked for k in by_frame.get(f, [])]


def _finite(value: Any) -> bool:
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False


def crop_skip(row: dict[str, Any]) -> Precomputed | None:
    """The skip policy's first rule: a frame the crop stage found no fittable particle in
    (status not in :data:`~holofit.status.FITTABLE_CROP_STATUSES`), or whose crop-table row
    lacks its centre or corner, becomes a ``skipped`` row (None: the frame can be fitted)."""
    status = str(row.get("status", ""))
    if status not in FITTABLE_CROP_STATUSES:
        msg = str(row.get("message") or "")
        return Precomputed({"status": SKIPPED, "crop_status": status,
                            "message": f"crop stage: {status}" + (f": {msg}" if msg else "")})
    bad = [k for k in _CROP_NEEDED if not _finite(row.get(k))]
    if bad:
        return Precomputed({"status": SKIPPED, "crop_status": status,
                            "message": f"crop table has no {', '.join(bad)} for this frame"})
    return None


@dataclass(frozen=True)
class FrameStart:
    """One frame's inputs, loaded in the driver by :class:`FrameLoader`.

    Attributes
    ----------
    frame : int
        The frame.
    crop : ndarray
        The crop (float32, NaN marks pixels to leave out).
    corner : tuple of int
        Full-frame (row, col) of the crop's pixel [0, 0].
    crop_row : dict
        The frame's crop-table row.
    start : dict
        The prefit's ``x_um, y_um, z_um, alpha`` (empty when the stage reads no prefit).
    candidates : list of tuple
        The library's ``(psi, theta, phi, r2)`` (empty when the stage reads no library).
    """

    frame: int
    crop: NDArray[np.float32]
    corner: tuple[int, int]
    crop_row: dict[str, Any]
    start: dict[str, float] = field(default_factory=dict)
    candidates: list[tuple[float, ...]] = field(default_factory=list)


class FrameLoader:
    """The shared frame loader and skip policy of the per-frame stages.

    Calling the loader with a frame gives its :class:`FrameStart`, or a ``skipped``
    :class:`~holofit.batch.runner.Precomputed` row saying why not (the crop stage's status, the
    prefit's, the library's, in this order).

    Parameters
    ----------
    crops : CropSet
        The crop folder.
    prefit : pandas.DataFrame, optional
        The prefit table, indexed by frame (:func:`holofit.tables.inputs.read_stage_table`):
        a frame without a usable start is skipped.
    library : pandas.DataFrame, optional
        The library table, indexed by frame: a frame without a candidate is skipped.
    """

    def __init__(self, crops: CropSet, prefit: pd.DataFrame | None = None,
                 library: pd.DataFrame | None = None) -> None:
        self.crops = crops
        self.prefit = prefit
        self.library = library
        self.n_candidates = 0 if library is None else n_candidate_columns(library.columns)

    @staticmethod
    def _row(table: pd.DataFrame, frame: Any) -> dict[str, Any] | None:
        return table.loc[frame].to_dict() if frame in table.index else None

    def __call__(self, frame: Any) -> FrameStart | Precomputed:
        frame = self.crops.key(frame) if hasattr(self.crops, "key") else frame
        crow = self.crops.row(frame)
        skip = crop_skip(crow)
        if skip is not None:
            return skip
        start: dict[str, float] = {}
        if self.prefit is not None:
            prow = self._row(self.prefit, frame)
            why = usable_start(prow)
            if why:
                return Precomputed({"status": SKIPPED, "message": f"prefit: {why}"})
            assert prow is not None
            start = {k: float(prow[k]) for k in START_COLUMNS}
        cands: list[tuple[float, ...]] = []
        if self.library is not None:
            lrow = self._row(self.library, frame)
            cands = candidate_values(lrow, self.n_candidates)
            if not cands:
                status = lrow.get("status") if lrow else "missing"
                return Precomputed({"status": SKIPPED,
                                    "message": f"library: no candidate (status {status})"})
        return FrameStart(frame, self.crops.crop(frame),
                          (int(crow["corner_row"]), int(crow["corner_col"])), crow, start,
                          cands)


@dataclass
class StageInputs:
    """A stage's crop folder, the instrument it runs with and the frames it runs."""

    crops: CropSet
    instrument: Instrument
    frames: list[Any]


@contextlib.contextmanager
def stage_inputs(
    crop_dir: str | Path,
    frames: Sequence[int] | None = None,
    instrument: Instrument | None = None,
    override_instrument: bool = False,
    numerical_aperture: ApertureChoice = FROM_INSTRUMENT,
    fit_na: bool = False,
) -> Iterator[StageInputs]:
    """Open a crop folder for a stage: the instrument (the crops' own unless one is given:
    :func:`~holofit.tables.cropset.resolve_instrument`; its NA as chosen:
    :func:`~holofit.batch.aperture.fit_instrument`) and the frames (:func:`check_frames`).
    The crops are closed on leaving."""
    with CropSet(crop_dir) as crops:
        inst = fit_instrument(resolve_instrument(crops, instrument, override_instrument),
                              numerical_aperture, fit_na)
        yield StageInputs(crops, inst, check_frames(crops, frames))


def run_stage(
    func: Callable[[Any, Any, Any], dict[str, Any]],
    config: Any,
    keys: Sequence[Any],
    load: Callable[[Any], Any],
    table: StageTable,
    *,
    batch: BatchSettings | None = None,
    complete: Callable[[Path], Any] | None = None,
    sizes: Mapping[Any, int] | None = None,
) -> tuple[BatchSummary, Any]:
    """Run one batch of a stage and finish its table.

    Parameters
    ----------
    func, config, keys, load
        The frame function, its picklable settings, the items (frames) and the loader, as
        for :func:`~holofit.batch.runner.run_batch`.
    table : StageTable
        The table written.
    batch : BatchSettings, optional
        Backend and resumption.
    sizes : mapping, optional
        Item -> the rows it writes (a chunk's frames), for the progress bar.
    complete : callable, optional
        ``complete(path)``: what is done with the complete table (pictures, sweeps that
        rewrite it), before it is published under its own name (the file ``make`` waits for is
        the last one written); when the table was complete before this run, on the published
        table.

    Returns
    -------
    summary : BatchSummary
    completed : object
        What ``complete`` returned (None without it).
    """
    done: list[Any] = []

    def before_publish(path: Path) -> None:
        assert complete is not None
        done.append(complete(path))

    summary = run_batch(func, config, keys, load, table, options=batch,
                        before_publish=before_publish if complete else None,
                        sizes=sizes)
    if complete is not None and not done:  # complete before this run: from the table
        done.append(complete(table.path))
    return summary, (done[0] if done else None)
