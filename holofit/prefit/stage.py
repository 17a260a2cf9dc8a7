"""``holofit prefit``: Lorenz-Mie fit of every crop (step 2 of the paper's procedure).

Reads a crop folder (:mod:`holofit.fitting.crops`), fits the exact Lorenz-Mie hologram of a
sphere to each crop from an automatic start (:func:`holofit.prefit.sphere.fit_sphere_crop`)
and writes one row per frame to ``prefit.csv`` (the fit-table schema, :mod:`holofit.fit_table`)
through the batch runner (:mod:`holofit.batch.runner`): in parallel, resumable, failures
recorded and skipped.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from holofit.batch.runner import BatchOptions, BatchSummary, Precomputed, run_batch
from holofit.config import ConfigError, Instrument
from holofit.fit_table import column_unit
from holofit.fitting.aperture import FROM_INSTRUMENT, ApertureChoice, fit_instrument
from holofit.fitting.crops import CropSet, CropSetError, resolve_instrument
from holofit.fitting.finish import outlier_rule, outlier_sidecar
from holofit.fitting.parameters import APERTURE
from holofit.fitting.pictures import write_frame_pictures
from holofit.fitting.result import result_columns, result_row
from holofit.io.tables import read_table
from holofit.models import Sphere
from holofit.prefit.sphere import SPHERE_COLUMNS, START_COLUMNS, FitOptions, fit_sphere_crop
from holofit.provenance import sidecar
from holofit.scattering.mie import LorenzMie
from holofit.status import FIT_STATUS_MEANINGS, FITTABLE_CROP_STATUSES, SKIPPED, describe

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


def prefit_columns(fit_na: bool = False) -> tuple[str, ...]:
    """Columns of ``prefit.csv``, in order (with ``numerical_aperture`` if it is fitted)."""
    fitted = (*SPHERE_COLUMNS, *((APERTURE.name,) if fit_na else ()))
    return result_columns(fitted, fitted,
                          ("crop_status", "n_masked", *START_COLUMNS, "setup_time_s"))


#: columns of ``prefit.csv``, in order (the NA held)
PREFIT_COLUMNS: tuple[str, ...] = prefit_columns()

_EXTRA_UNITS = {
    "time_s": "s (time of the frame: frame / the instrument's frame rate; NaN if unknown)",
    "status": describe(FIT_STATUS_MEANINGS),
    "crop_status": "status in the crop table",
    "n_masked": "count (pixels left out: NaN or saturated)",
    "n_starts": "count (candidate starts fitted)",
    "start_z_um": "um (automatic start)",
    "start_radius_um": "um (automatic start)",
    "start_n": "1 (automatic start)",
    "start_alpha": "1 (automatic start)",
    "setup_time_s": "s (one-time set-up paid by this frame in its worker: the estimator's table)",
    APERTURE.name: "1 (the objective's numerical aperture, fitted)",
    f"d_{APERTURE.name}": "1 (1-sigma uncertainty of numerical_aperture)",
}
#: unit of every column of ``prefit.csv``
PREFIT_UNITS: dict[str, str] = {c: _EXTRA_UNITS.get(c, column_unit(c))
                                for c in prefit_columns(fit_na=True)}


@dataclass(frozen=True)
class PrefitConfig:
    """Everything a worker needs to fit a frame (picklable).

    Attributes
    ----------
    instrument : Instrument
        Optics and pixel size.
    fit : FitOptions
        Fit settings.
    """

    instrument: Instrument
    fit: FitOptions = field(default_factory=FitOptions)

    def as_dict(self) -> dict[str, Any]:
        """Plain form for the sidecar and the fingerprint."""
        return {"instrument": self.instrument.as_dict(), "fit": dataclasses.asdict(self.fit)}


@dataclass(frozen=True)
class CropPayload:
    """What the driver sends a worker for one frame."""

    crop: NDArray[np.float32]
    row: dict[str, Any]


def _finite(value: Any) -> bool:
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False


def prefit_frame(config: PrefitConfig, frame: int, payload: CropPayload) -> dict[str, Any]:
    """Fit one crop; the frame function of the prefit batch.

    Parameters
    ----------
    config : PrefitConfig
        Settings.
    frame : int
        Frame number (also the seed of random pixel subsets).
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
    corner = (int(row["corner_row"]), int(row["corner_col"]))
    centre = (float(row["x_um"]), float(row["y_um"]))
    fit = fit_sphere_crop(payload.crop, corner, centre, inst.optics, inst.pixel_size_um,
                          config.fit, seed=frame)
    out = result_row(frame, frame / inst.frame_rate_hz if inst.frame_rate_hz else math.nan, fit)
    out["crop_status"] = row.get("status", "")
    return out


def _loader(crops: CropSet):
    def load(frame: int) -> CropPayload | Precomputed:
        row = crops.row(frame)
        status = str(row.get("status", ""))
        if status not in FITTABLE_CROP_STATUSES:
            msg = str(row.get("message") or "")
            return Precomputed(
                {
                    "status": SKIPPED,
                    "message": f"crop stage: {status}" + (f": {msg}" if msg else ""),
                    "crop_status": status,
                }
            )
        needed = ("x_um", "y_um", "corner_row", "corner_col")
        bad = [k for k in needed if not _finite(row.get(k))]
        if bad:
            return Precomputed(
                {
                    "status": SKIPPED,
                    "message": f"crop table has no {', '.join(bad)} for this frame",
                    "crop_status": status,
                }
            )
        return CropPayload(crops.crop(frame), row)

    return load


@dataclass
class PrefitResult:
    """What :func:`run_prefit` wrote."""

    table: Path
    summary: BatchSummary
    plot: Path | None


def fingerprint_of(config: PrefitConfig, inputs: dict[str, Any]) -> str:
    """Hash of the settings and inputs that determine the prefit table."""
    doc = json.dumps({"config": config.as_dict(), "inputs": inputs}, sort_keys=True, default=str)
    return hashlib.sha256(doc.encode()).hexdigest()[:16]


def run_prefit(
    crop_dir: str | Path,
    out_dir: str | Path,
    *,
    instrument: Instrument | None = None,
    fit: FitOptions | None = None,
    frames: list[int] | None = None,
    batch: BatchOptions | None = None,
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
    fit : FitOptions, optional
        Fit settings.
    frames : list of int, optional
        Only these frames (default: all).
    batch : BatchOptions, optional
        Parallel backend, resumption.
    plot : bool
        Write ``prefit.png`` (values against frame) and data / model / residual pictures of a
        few frames (``frames/frame_<n>.png``).
    plot_frames : list of int, optional
        The frames to draw (default: the first ok frame, the ok frame with the lowest R^2 and
        the first poor fit).
    override_instrument : bool
        Allow ``instrument`` to differ from the one the crops were made with.
    outlier_factor : float
        An ok frame whose reduced chi^2 exceeds this times the movie's median becomes
        ``poor_fit`` (:func:`holofit.fitting.result.flag_outliers`).
    numerical_aperture : float, None or "instrument"
        The objective's NA the model is imaged with (:mod:`holofit.fitting.aperture`): the
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
        If the NA is to be fitted with none to start from, or the search's z range is one the
        model cannot describe (below the focal plane or into the sphere without a lens).
    holofit.batch.runner.BatchError
        If earlier results in ``out_dir`` came from other settings (see ``overwrite``).
    """
    out = Path(out_dir)
    with CropSet(crop_dir) as crops:
        fit = fit or FitOptions()
        inst = fit_instrument(resolve_instrument(crops, instrument, override_instrument),
                              numerical_aperture, fit.fit_na)
        try:
            fit.search.check_heights(inst.optics.numerical_aperture is not None)
        except ValueError as exc:
            raise ConfigError(f"prefit search range: {exc}") from None
        config = PrefitConfig(inst, fit)
        todo = crops.frames if frames is None else [int(f) for f in frames]
        unknown = sorted(set(todo) - set(crops.frames))
        if unknown:
            raise CropSetError(f"{crops.table_path}: no frame(s) {unknown[:5]}")
        inputs = crops.fingerprint()
        columns = prefit_columns(fit.fit_na)
        meta = sidecar(
            kind="prefit table (Lorenz-Mie fit per frame)",
            units={c: PREFIT_UNITS[c] for c in columns},
            config=config.as_dict(),
            inputs=[crops.table_path, crops.stack_path],
            extra={"crop_shape": list(crops.crop_shape), "crops": inputs,
                   "quality": outlier_sidecar(outlier_factor),
                   **({"frame_interval_s": 1.0 / inst.frame_rate_hz}
                      if inst.frame_rate_hz else {})},
        )
        drawn: list[Path] = []

        def pictures(table_path: Path) -> None:
            """The summary plot and frame pictures, drawn before the table is published
            (``prefit.csv`` is the last file written: make waits for it)."""
            from holofit.prefit.plots import plot_prefit

            png = plot_prefit(table_path, out / "prefit.png")
            write_frame_pictures(
                read_table(table_path), crops, Sphere(1.0, complex(1.5, config.fit.index_imag)),
                LorenzMie(), inst.optics, inst.pixel_size_um, out / "frames", "prefit",
                plot_frames)
            drawn.append(png)

        summary = run_batch(
            prefit_frame,
            config,
            todo,
            _loader(crops),
            out / "prefit.csv",
            columns,
            fingerprint=fingerprint_of(config, {**inputs, "outlier_factor": outlier_factor}),
            meta=meta,
            options=batch,
            desc="prefit",
            finish=outlier_rule(outlier_factor),
            before_publish=pictures if plot else None,
        )
        if plot and not drawn:  # the table was complete before this run: draw from it
            pictures(out / "prefit.csv")
    return PrefitResult(out / "prefit.csv", summary, drawn[0] if drawn else None)
