"""``holofit calibrate``: the instrument from a movie of spheres (the library function).

Reads a crop folder (:class:`holofit.tables.cropset.CropSet`) and its prefit table
(:func:`holofit.tables.inputs.read_stage_table`), chooses up to ``max_frames`` spheres with a
converged prefit (:func:`_usable`) spread evenly over the heights the prefit found
(:func:`choose_frames`), fits the objective's numerical aperture, its spherical-aberration
coefficients and optionally the polarisation jointly over them, every sphere's position, size,
index and alpha free
(:func:`holofit.calibrate.joint.calibrate_instrument`, started from the prefit's rows), and
writes (:mod:`holofit.calibrate.report`)

- ``OUT/instrument.toml``: the crops' instrument with the fitted values, their errors and the
  fit's provenance in a ``[calibration]`` table (``holofit init -i`` and every stage read it);
- ``OUT/calibration.csv`` (+ sidecar): per frame the sphere and its chi^2 per pixel before
  (the prefit, the start instrument) and after (the joint fit);
- ``OUT/calibration.png``: chi^2 per pixel, index and radius against height, before and after.

Rule: spheres at several heights, because one hologram cannot tell the pupil's phase from a
height shift (:mod:`holofit.calibrate.joint`); the frames of a movie at nearly one height add
precision but no leverage, so the choice spreads them over the heights first.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from holofit.batch import BatchSettings
from holofit.batch.stage import crop_skip
from holofit.calibrate.config import (
    CalibrateConfig,
    CalibrateError,
    CalibrationRun,
    FrameRecord,
)
from holofit.calibrate.joint import calibrate_instrument
from holofit.calibrate.report import write_outputs
from holofit.calibrate.settings import InstrumentFit, JointFitSettings, SphereFrame
from holofit.config import Instrument, instrument_from_dict
from holofit.conventions import DetectorGrid
from holofit.hologram import calc_hologram
from holofit.holomodel.statistics import estimate_noise_sd
from holofit.io.lock import output_lock
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.prefit.sphere import SPHERE_COLUMNS
from holofit.progress import progress_bar
from holofit.quality import CONVERGED
from holofit.scattering.mie import MieWave
from holofit.tables.cropset import CropSet, resolve_instrument
from holofit.tables.inputs import read_stage_table

__all__ = [
    "CalibrateConfig",
    "CalibrateError",
    "CalibrationRun",
    "calibrated_instrument",
    "chi2_per_pixel",
    "choose_frames",
    "run_calibrate",
]


def choose_frames(heights: Sequence[tuple[Any, float]], n: int) -> list[Any]:
    """Up to ``n`` keys whose heights spread evenly over the range (``(key, z_um)`` pairs).

    The rule: targets evenly spaced from the lowest to the highest height, each taking the
    nearest key not yet taken; returned by height. Why: the calibration's leverage is the
    range of defocus, not the count of frames at one height.
    """
    items = sorted(heights, key=lambda kz: kz[1])
    if len(items) <= n:
        return [k for k, _ in items]
    zs = np.array([z for _, z in items])
    free = np.ones(zs.size, dtype=bool)
    chosen = []
    for target in np.linspace(zs[0], zs[-1], n):
        i = int(np.argmin(np.where(free, np.abs(zs - target), np.inf)))
        free[i] = False
        chosen.append(i)
    return [items[i][0] for i in sorted(chosen)]


def chi2_per_pixel(frame: SphereFrame, values: dict[str, float], optics: Optics,
                   pixel_size_um: float, index_imag: float = 0.0) -> tuple[float, int]:
    """Mean squared residual over a crop's unmasked pixels of the sphere ``values`` (``x_um,
    y_um, z_um, radius_um, n, alpha``) imaged through ``optics``, and the pixels.

    Before and after are judged on the same (all) pixels, whatever subset a fit used."""
    crop = np.asarray(frame.crop, dtype=float)
    ok = np.isfinite(crop)
    grid = DetectorGrid(crop.shape, pixel_size_um, frame.corner_rc)
    wave = MieWave(Sphere(values["radius_um"], complex(values["n"], index_imag)), optics)
    holo = calc_hologram(wave, (values["x_um"], values["y_um"], values["z_um"]), grid,
                         values["alpha"])
    r = holo[ok] - crop[ok]
    return float(r @ r / max(r.size, 1)), int(r.size)


def _instrument_of(crops: CropSet, meta: dict[str, Any], config: CalibrateConfig
                   ) -> tuple[Instrument, Instrument]:
    """The instrument of the "before" fits (the prefit's, else the crops') and the joint fit's
    start (``config``'s instrument and NA where given; an instrument that contradicts the
    crops' is refused: :func:`~holofit.tables.cropset.resolve_instrument`)."""
    recorded = (meta.get("config") or {}).get("instrument")
    before = (instrument_from_dict(recorded, "prefit sidecar") if isinstance(recorded, dict)
              else crops.instrument)
    if before is None:
        raise CalibrateError(f"{crops.table_path}: neither the prefit's sidecar nor the crops' "
                             "names an instrument; give one with --instrument")
    start = before if config.instrument is None else resolve_instrument(crops, config.instrument)
    if config.numerical_aperture is not None:
        start = start.with_numerical_aperture(config.numerical_aperture)
    if start.optics.numerical_aperture is None:
        raise CalibrateError(f"instrument {start.name!r} ({start.path or 'recorded'}) has no "
                             "numerical_aperture: a calibration starts from one (give "
                             "--numerical-aperture)")
    return before, start


#: what a prefit's message says of a fit that found no particle (:func:`holofit.quality.judge_fit`)
NO_PARTICLE = "no particle"


def _usable(row: dict[str, Any] | None, crop_row: dict[str, Any]) -> bool:
    """A frame to calibrate on: a fittable crop and a converged prefit of a particle.

    The rule keeps the prefit's ``poor_fit`` frames whose only fault is their chi^2. Why: the
    start instrument lacks the aberration being calibrated, and the frames nearest focus,
    whose wide fringes fix it best, misfit most (a 100-frame movie through the 60x objective
    had every frame below 10 um poor_fit); the joint fit judges them with the aberration.
    """
    if row is None or crop_skip(crop_row) is not None or row.get("status") not in CONVERGED:
        return False
    if NO_PARTICLE in str(row.get("message") or ""):
        return False
    return all(np.isfinite(float(row.get(c, np.nan))) for c in SPHERE_COLUMNS)


def _candidates(crops: CropSet, table: pd.DataFrame, config: CalibrateConfig,
                notes: list[str]) -> list[tuple[tuple[int, int], float]]:
    """``(key, z_um)`` of every frame to calibrate on (:func:`_usable`)."""
    keys = list(crops.keys)
    if config.frames is not None:
        wanted = set(config.frames)
        keys = [k for k in keys if k[1] in wanted]
        if not keys:
            raise CalibrateError(f"{crops.table_path}: no frame in --frames "
                                 f"({min(wanted)}..{max(wanted)})")
    out, left = [], 0
    for key in keys:
        row = table.loc[key].to_dict() if key in table.index else None
        if _usable(row, crops.row(key)):
            assert row is not None
            out.append((key, float(row["z_um"])))
        else:
            left += 1
    if left:
        notes.append(f"{left} of {len(keys)} frame(s) left out: crop not fittable, or prefit "
                     "not converged or without a particle")
    if not out:
        raise CalibrateError(f"{crops.table_path}: no frame with a fittable crop and a "
                             "converged prefit of a particle to calibrate on")
    return out


#: fewest valid pixels of a crop to calibrate on (the joint fit's per-frame minimum)
MIN_PIXELS = 100


def _frame_fault(frame: SphereFrame) -> str:
    """Why a chosen frame cannot enter the joint fit ("" if it can): too few valid pixels,
    or no pixel noise (given by the prefit, or estimated from the crop)."""
    crop = np.asarray(frame.crop, dtype=float)
    n_valid = int(np.isfinite(crop).sum())
    if n_valid < MIN_PIXELS:
        return f"{n_valid} valid pixel(s), fewer than {MIN_PIXELS}"
    if frame.noise_sd is None and not estimate_noise_sd(crop, np.isfinite(crop)) > 0:
        return "no pixel noise estimate (the prefit gave none and the crop gives none)"
    return ""


def _load_one(crops: CropSet, table: pd.DataFrame, key: tuple[int, int],
              before_optics: Optics, px: float, index_imag: float) -> FrameRecord:
    """One chosen frame, its prefit start and its chi^2 per pixel before; a frame that cannot
    be used comes back with the reason in ``message`` (the batch goes on)."""
    crow = crops.row(key)
    prow = table.loc[key].to_dict()
    start = {c: float(prow[c]) for c in SPHERE_COLUMNS}
    noise = prow.get("noise_sd")
    noise = float(noise) if noise is not None and float(noise) > 0 else None
    frame = SphereFrame(crops.crop(key), (int(crow["corner_row"]), int(crow["corner_col"])),
                        (float(crow["x_um"]), float(crow["y_um"])), noise, start)
    fault = _frame_fault(frame)
    if fault:
        return FrameRecord(key, frame, start, math.nan, 0, message=fault)
    optics = before_optics
    na = prow.get("numerical_aperture")
    if na is not None and np.isfinite(float(na)):
        optics = replace(optics, numerical_aperture=float(na))
    try:
        chi2, n_px = chi2_per_pixel(frame, start, optics, px, index_imag)
    except (ValueError, ArithmeticError) as exc:  # InvalidParameters is a ValueError
        return FrameRecord(key, frame, start, math.nan, 0,
                           message=f"no hologram for its prefit values: {exc}")
    if not np.isfinite(chi2):
        return FrameRecord(key, frame, start, chi2, n_px,
                           message="its prefit values give a non-finite hologram")
    return FrameRecord(key, frame, start, chi2, n_px)


def _load(crops: CropSet, table: pd.DataFrame, keys: Sequence[tuple[int, int]],
          before_optics: Optics, px: float, index_imag: float, show: bool | None
          ) -> list[FrameRecord]:
    """The chosen frames (:func:`_load_one`), on a progress bar."""
    records = []
    with progress_bar(len(keys), "calibrate: frames", disable=None if show is None
                      else not show) as bar:
        for key in keys:
            records.append(_load_one(crops, table, key, before_optics, px, index_imag))
            bar.update(1)
    return records


def _joint(records: list[FrameRecord], start: Instrument, settings: JointFitSettings,
           show: bool | None) -> InstrumentFit:
    """The joint fit, its steps on a progress bar."""
    with progress_bar(1, "calibrate: joint fit", unit="step",
                      disable=None if show is None else not show) as bar:
        def step(label: str, begun: int, planned: int) -> None:
            bar.total = planned
            bar.n = begun - 1
            bar.set_postfix_str(label, refresh=False)
            bar.refresh()

        try:
            fit = calibrate_instrument([r.frame for r in records], start.optics,
                                       start.pixel_size_um, settings, progress=step)
        except ValueError as exc:
            raise CalibrateError(f"joint fit: {exc}") from None
        bar.n = bar.total
        bar.refresh()
    return fit


def calibrated_instrument(start: Instrument, fit: InstrumentFit) -> Instrument:
    """``start`` with the fitted NA, aberration and polarisation."""
    inst = start.with_numerical_aperture(fit.optics.numerical_aperture)
    inst = inst.with_aberration(fit.optics.aberration)
    return replace(inst, polarization_rad=float(fit.optics.polarization_rad))


def run_calibrate(crop_dir: str | Path, prefit_dir: str | Path, out_dir: str | Path,
                  config: CalibrateConfig | None = None, *,
                  batch: BatchSettings | None = None) -> CalibrationRun:
    """Calibrate the instrument on a sphere movie's crops; write ``OUT/instrument.toml``,
    ``OUT/calibration.csv`` (+ sidecar) and ``OUT/calibration.png`` (module docstring).

    Parameters
    ----------
    crop_dir : str or Path
        Output folder of ``holofit crop``.
    prefit_dir : str or Path
        Output folder of ``holofit prefit`` on those crops, or its ``prefit.csv``.
    out_dir : str or Path
        Where the outputs go (created; locked while written).
    config : CalibrateConfig, optional
        What is fitted on which frames (default: NA and two coefficients, up to 20 frames).
    batch : BatchSettings, optional
        Only its ``progress`` is used: the frames are fitted jointly, in this process.

    Returns
    -------
    CalibrationRun

    Raises
    ------
    CropSetError
        An incomplete crop folder, or a prefit table missing or made from other crops
        (:class:`~holofit.tables.inputs.StageInputError`).
    CalibrateError
        No instrument NA to start from, no usable frame, or settings with nothing to fit.
    OutputLocked
        If another run is writing ``out_dir``.
    """
    t0 = time.perf_counter()
    cfg = config or CalibrateConfig()
    show = batch.progress if batch is not None else None
    notes: list[str] = []
    with CropSet(crop_dir) as crops:
        table, meta = read_stage_table(prefit_dir, crops, "prefit")
        before_inst, start = _instrument_of(crops, meta, cfg)
        fit_meta = (meta.get("config") or {}).get("fit") or {}
        index_imag = float(fit_meta.get("index_imag") or 0.0)
        keys = choose_frames(_candidates(crops, table, cfg, notes), cfg.max_frames)
        if len(keys) < 2:
            notes.append("one frame only: its coefficients trade against its height; "
                         "calibrate on spheres at several heights")
        n_px = int(np.prod(crops.crop_shape))
        settings = cfg.joint_settings(min(1.0, cfg.max_pixels / n_px), index_imag)
        loaded = _load(crops, table, keys, before_inst.optics, start.pixel_size_um,
                       index_imag, show)
        failed = {r.key: r.message for r in loaded if not r.ok}
        records = [r for r in loaded if r.ok]
        if failed:
            notes.append(f"{len(failed)} of {len(loaded)} chosen frame(s) failed and were left "
                         "out (calibration.csv, status failed): " + "; ".join(
                             f"frame {k[1]} (particle {k[0]}): {m}" for k, m in failed.items()))
        if not records:
            raise CalibrateError(f"{crops.table_path}: every chosen frame failed: "
                                 + "; ".join(f"frame {k[1]}: {m}" for k, m in failed.items()))
        prefit_path = (Path(prefit_dir) / "prefit.csv" if Path(prefit_dir).is_dir()
                       else Path(prefit_dir))
        inputs = [crops.table_path, crops.stack_path, prefit_path]
    fit = _joint(records, start, settings, show)
    for rec, res in zip(records, fit.frames, strict=True):
        rec.chi2_after = chi2_per_pixel(rec.frame, res.values, fit.optics, start.pixel_size_um,
                                        index_imag)[0]
    inst = calibrated_instrument(start, fit)
    out = Path(out_dir)
    chi2_before = float(np.mean([r.chi2_before for r in records]))
    chi2_after = float(np.mean([r.chi2_after for r in records]))
    run = CalibrationRun(out / "instrument.toml", out / "calibration.csv", None, inst, start,
                         fit, [r.key for r in records], chi2_before, chi2_after, notes,
                         failed=failed)
    with output_lock(out, stage="calibrate"):
        run.time_s = time.perf_counter() - t0
        write_outputs(run, loaded, cfg, before_inst, inputs)
    return run
