"""``holofit prefit``: Lorenz-Mie fit of every crop (step 2 of the paper's procedure).

Reads a crop folder (:mod:`holofit.tables.cropset`), fits the exact Lorenz-Mie hologram of a
sphere to each crop from an automatic start (:func:`holofit.prefit.sphere.fit_sphere_crop`)
and writes one row per frame to ``prefit.csv`` (its schema: :mod:`holofit.tables.prefit`)
through the stage skeleton (:mod:`holofit.batch.stage`): in parallel, resumable, failures
recorded, frames without a particle skipped.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from holofit.batch import BatchSettings, BatchSummary, Precomputed
from holofit.batch.aperture import FROM_INSTRUMENT, ApertureChoice
from holofit.batch.stage import FrameLoader, StageTable, fingerprint, run_stage, stage_inputs
from holofit.config import ConfigError, Instrument
from holofit.holomodel.pictures import write_frame_pictures
from holofit.holomodel.result import result_row
from holofit.io.tables import read_table
from holofit.particles import Sphere
from holofit.prefit.sphere import SphereFitSettings, fit_sphere_crop
from holofit.provenance import sidecar
from holofit.quality import FLAG_PROBABILITY, outlier_rule, outlier_sidecar
from holofit.scattering.mie import LorenzMie
from holofit.tables.crop import CROP_UNITS, keyed_columns
from holofit.tables.cropset import CropSet
from holofit.tables.prefit import PREFIT_COLUMNS, PREFIT_UNITS, prefit_columns

__all__ = [
    "PREFIT_COLUMNS",
    "PREFIT_UNITS",
    "CropPayload",
    "PrefitConfig",
    "PrefitResult",
    "prefit_columns",
    "prefit_frame",
    "run_prefit",
]


@dataclass(frozen=True)
class PrefitConfig:
    """Everything a worker needs to fit a frame (picklable).

    Attributes
    ----------
    instrument : Instrument
        Optics and pixel size.
    fit : SphereFitSettings
        Fit settings.
    """

    instrument: Instrument
    fit: SphereFitSettings = field(default_factory=SphereFitSettings)

    def as_dict(self) -> dict[str, Any]:
        """Plain form for the sidecar and the fingerprint."""
        return {"instrument": self.instrument.as_dict(), "fit": dataclasses.asdict(self.fit)}


@dataclass(frozen=True)
class CropPayload:
    """What the driver sends a worker for one frame."""

    crop: NDArray[np.float32]
    row: dict[str, Any]


def prefit_frame(config: PrefitConfig, frame: int, payload: CropPayload) -> dict[str, Any]:
    """Fit one crop; the frame function of the prefit batch.

    Parameters
    ----------
    config : PrefitConfig
        Settings.
    frame : int or tuple
        Frame number (also the seed of random pixel subsets), or a ``(particle, frame)`` key.
    payload : CropPayload
        The crop and its crop-table row.

    Returns
    -------
    dict
        One row of :data:`PREFIT_COLUMNS` (status ``ok``, ``poor_fit``, ``not_converged`` or
        ``failed``; an exception becomes an ``error`` row in the batch runner).
    """
    row = payload.row
    inst = config.instrument
    frame = int(frame[-1]) if isinstance(frame, tuple) else frame  # a (particle, frame) key
    corner = (int(row["corner_row"]), int(row["corner_col"]))
    centre = (float(row["x_um"]), float(row["y_um"]))
    fit = fit_sphere_crop(payload.crop, corner, centre, inst.optics, inst.pixel_size_um,
                          config.fit, seed=frame)
    out = result_row(frame, frame / inst.frame_rate_hz if inst.frame_rate_hz else math.nan, fit)
    out["crop_status"] = row.get("status", "")
    return out


def _load(loader: FrameLoader, frame: int) -> CropPayload | Precomputed:
    """The shared loader's frame as the prefit's payload."""
    got = loader(frame)
    return got if isinstance(got, Precomputed) else CropPayload(got.crop, got.crop_row)


@dataclass
class PrefitResult:
    """What :func:`run_prefit` wrote."""

    table: Path
    summary: BatchSummary
    plot: Path | None


def fingerprint_of(config: PrefitConfig, inputs: dict[str, Any]) -> str:
    """Hash of the settings and inputs that determine the prefit table."""
    return fingerprint({"config": config.as_dict(), "inputs": inputs})


def run_prefit(
    crop_dir: str | Path,
    out_dir: str | Path,
    *,
    instrument: Instrument | None = None,
    fit: SphereFitSettings | None = None,
    frames: list[int] | None = None,
    batch: BatchSettings | None = None,
    plot: bool = True,
    plot_frames: list[int] | None = None,
    override_instrument: bool = False,
    outlier_factor: float = 4.0,
    numerical_aperture: ApertureChoice = FROM_INSTRUMENT,
) -> PrefitResult:
    """Fit every crop of a crop folder; write ``OUT/prefit.csv`` (+ sidecar, + plot).

    Parameters
    ----------
    crop_dir : str or Path
        Output folder of ``holofit crop``.
    out_dir : str or Path
        Where ``prefit.csv``, ``prefit.csv.json`` and ``prefit.png`` go.
    instrument : Instrument, optional
        The instrument, if the crop stage recorded none; replacing a recorded one that differs
        in wavelength, medium, pixel size or polarisation needs ``override_instrument``.
    fit : SphereFitSettings, optional
        Fit settings.
    frames, batch
        Only these frames (default: all); parallel backend, resumption.
    plot : bool
        Write ``prefit.png`` (values against frame) and data / model / residual pictures of a
        few frames (``frames/frame_<n>.png``).
    plot_frames : list of int, optional
        The frames to draw (default: first ok, lowest-R^2 ok, first poor fit).
    override_instrument : bool
        Allow ``instrument`` to differ from the one the crops were made with.
    outlier_factor : float
        An ok frame whose reduced chi^2 exceeds this times the movie's median becomes
        ``poor_fit`` (:func:`holofit.holomodel.result.flag_outliers`).
    numerical_aperture : float, None or "instrument"
        The objective's NA the model is imaged with (:mod:`holofit.holomodel.aperture`): the
        instrument's (default), another value, or None for the ideal model (no lens). With
        ``fit.fit_na`` it is the start of the fitted NA.

    Returns
    -------
    PrefitResult

    Raises
    ------
    CropSetError
        If the crop folder is incomplete, no instrument is known, or ``instrument``
        contradicts the crops' own without ``override_instrument``.
    ConfigError
        If the NA is to be fitted with none to start from, the search's z range is one the
        model cannot describe (below the focal plane or into the sphere without a lens), or
        aberration coefficients are to be fitted (the table has no columns for them).
    holofit.batch.runner.BatchError
        If earlier results in ``out_dir`` came from other settings (see ``overwrite``).
    """
    out = Path(out_dir)
    fit = fit or SphereFitSettings()
    if fit.fit_aberration:
        raise ConfigError("prefit.csv has no columns for fitted aberration coefficients: fit "
                          "them with holofit.calibrate.calibrate_instrument (several heights), or "
                          "set spherical_aberration_rad in the instrument")
    with stage_inputs(crop_dir, frames, instrument, override_instrument, numerical_aperture,
                      fit.fit_na) as given:
        try:
            fit.search.check_heights(given.instrument.optics.numerical_aperture is not None)
        except ValueError as exc:
            raise ConfigError(f"prefit search range: {exc}") from None
        config = PrefitConfig(given.instrument, fit)
        table = _prefit_table(config, given.crops, out, outlier_factor)

        def pictures(table_path: Path) -> Path:
            """The summary plot and frame pictures (:func:`run_stage`'s ``complete``)."""
            return _pictures(table_path, given.crops, config, out, plot_frames)

        summary, png = run_stage(prefit_frame, config, given.frames,
                                 partial(_load, FrameLoader(given.crops)), table, batch=batch,
                                 complete=pictures if plot else None)
    return PrefitResult(table.path, summary, png)


def _prefit_table(config: PrefitConfig, crops: CropSet, out: Path,
                  outlier_factor: float) -> StageTable:
    """``prefit.csv``: its columns (:mod:`holofit.tables.prefit`), sidecar and fingerprint."""
    inst = config.instrument
    inputs = crops.fingerprint()
    # a seed (a non-spherical particle's start) is no sphere fit to judge by its chi^2
    probability = None if config.fit.seed_only else FLAG_PROBABILITY
    columns = keyed_columns(prefit_columns(config.fit.fit_na), crops.key_columns)
    meta = sidecar(
        kind="prefit table (Lorenz-Mie fit per frame)",
        units={c: PREFIT_UNITS.get(c, CROP_UNITS.get(c, "")) for c in columns},
        config=config.as_dict(),
        inputs=[crops.table_path, crops.stack_path],
        extra={"crop_shape": list(crops.crop_shape), "crops": inputs,
               "quality": outlier_sidecar(outlier_factor, probability),
               **({"frame_interval_s": 1.0 / inst.frame_rate_hz}
                  if inst.frame_rate_hz else {})},
    )
    return StageTable(out / "prefit.csv", columns, meta,
                      fingerprint_of(config, {**inputs, "outlier_factor": outlier_factor,
                                              "flag_probability": probability}),
                      "prefit", finish=outlier_rule(outlier_factor, probability),
                      key_columns=crops.key_columns)


def _pictures(table_path: Path, crops: CropSet, config: PrefitConfig, out: Path,
              plot_frames: list[int] | None) -> Path:
    """``prefit.png`` and the frame pictures of ``frames/``."""
    from holofit.prefit.plots import plot_prefit

    inst = config.instrument
    png = plot_prefit(table_path, out / "prefit.png")
    if crops.multi:  # frame pictures are drawn per track, from each track's own run
        return png
    write_frame_pictures(
        read_table(table_path), crops, Sphere(1.0, complex(1.5, config.fit.index_imag)),
        LorenzMie(), inst.optics, inst.pixel_size_um, out / "frames", "prefit", plot_frames)
    return png
