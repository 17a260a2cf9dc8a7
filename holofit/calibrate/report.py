"""What ``holofit calibrate`` writes (:func:`holofit.calibrate.stage.run_calibrate`): the
calibrated instrument file, the per-frame table and its picture.

``instrument.toml`` (and its sidecar ``instrument.toml.json``: units, configuration, inputs,
versions, the command) holds the start instrument's ``[instrument]`` table with the fitted
``numerical_aperture``, ``spherical_aberration_rad`` and ``polarization_deg``, and a
``[calibration]`` table (which :func:`holofit.config.load_instrument` does not read) with

- ``fitted``, ``status``, ``message``, ``chi2_red``: what was fitted and how it ended;
- ``[calibration.values]`` and ``[calibration.errors]``: the fitted values and their
  1-sigma errors (``polarization_deg`` in degrees, the rest as in the fit);
- ``[calibration.covariance]``: ``names`` and ``matrix`` of the fitted quantities (the
  coefficients are strongly anticorrelated over a small pupil, so their errors alone
  overstate the pupil phase's: compare ``edge_phase_rad`` and its error);
- ``chi2_per_pixel_before`` / ``_after``: the frames' mean squared residual per pixel with the
  start instrument (the prefit) and with the calibrated one;
- ``[calibration.start]``: the start instrument's values; ``[calibration.material]``: the
  stated index and radius, if any;
- the provenance: ``frames``, ``particles``, ``z_range_um``, ``crops``, ``prefit``,
  ``command``, ``holofit_version``, ``created``.
"""

from __future__ import annotations

import datetime as _dt
import math
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import holofit
from holofit.calibrate.config import CalibrateConfig, CalibrationRun, FrameRecord
from holofit.calibrate.settings import InstrumentFit
from holofit.config import INSTRUMENT_SPECS, Instrument, instrument_toml, load_instrument
from holofit.io.atomic import atomic_path, atomic_write_text
from holofit.io.tables import sidecar_path, write_json, write_table
from holofit.prefit.sphere import SPHERE_COLUMNS
from holofit.provenance import command_line, sidecar
from holofit.status import FAILED

__all__ = ["CALIBRATION_UNITS", "calibration_table", "frame_rows", "plot_calibration",
           "write_outputs"]

_SPHERE_UNITS = {"x_um": "um", "y_um": "um", "z_um": "um", "radius_um": "um", "n": "1",
                 "alpha": "1"}
#: unit of every column of ``calibration.csv``
CALIBRATION_UNITS: dict[str, str] = {
    "particle": "track id", "frame": "index",
    **{f"{c}_{when}": f"{u} ({'prefit, start instrument' if when == 'before' else 'joint fit'})"
       for c, u in _SPHERE_UNITS.items() for when in ("before", "after")},
    **{f"d_{c}_after": f"{u} (1-sigma, joint covariance)" for c, u in _SPHERE_UNITS.items()},
    "chi2_per_px_before": "normalised intensity^2 (mean squared residual, all unmasked pixels, "
                          "start instrument)",
    "chi2_per_px_after": "normalised intensity^2 (mean squared residual, all unmasked pixels, "
                         "calibrated instrument)",
    "chi2_red_after": "1 (the joint fit's residuals of this frame over its pixel noise)",
    "noise_sd": "normalised intensity (pixel noise)",
    "n_pixels": "count (unmasked pixels of the crop)",
    "n_pixels_fitted": "count (pixels of the joint fit)",
    "status": "ok | not_converged (the joint fit's) | failed (left out of the fit: message)",
    "message": "why a failed frame was left out (empty for the fitted ones)",
}


def calibration_table(run: CalibrationRun, records: Sequence[FrameRecord]) -> pd.DataFrame:
    """``calibration.csv``'s rows (:data:`CALIBRATION_UNITS`)."""
    return pd.DataFrame(frame_rows(records, run.fit), columns=list(CALIBRATION_UNITS))


def frame_rows(records: Sequence[FrameRecord], fit: InstrumentFit) -> list[dict[str, Any]]:
    """The rows of ``calibration.csv``: per chosen frame its sphere before and after and their
    chi^2 per pixel (:data:`CALIBRATION_UNITS`), by height; a frame left out of the fit
    (``rec.ok`` false) is a ``failed`` row with its reason and no "after"."""
    rows = []
    results = iter(fit.frames)
    for rec in records:
        row: dict[str, Any] = {"particle": rec.key[0], "frame": rec.key[1]}
        if not rec.ok:
            for c in SPHERE_COLUMNS:
                row[f"{c}_before"] = rec.before.get(c, math.nan)
            row.update(chi2_per_px_before=rec.chi2_before, noise_sd=rec.frame.noise_sd,
                       n_pixels=rec.n_pixels, n_pixels_fitted=0, status=FAILED,
                       message=rec.message)
            rows.append(row)
            continue
        res = next(results)
        for c in SPHERE_COLUMNS:
            row[f"{c}_before"] = rec.before[c]
            row[f"{c}_after"] = res.values[c]
            row[f"d_{c}_after"] = res.errors.get(c, math.nan)
        row.update(chi2_per_px_before=rec.chi2_before, chi2_per_px_after=rec.chi2_after,
                   chi2_red_after=res.chi2_red, noise_sd=res.noise_sd, n_pixels=rec.n_pixels,
                   n_pixels_fitted=res.n_pixels, status=res.status, message="")
        rows.append(row)
    if next(results, None) is not None:
        raise ValueError("more joint-fit frames than fitted records")
    return rows


def _errors(run: CalibrationRun) -> dict[str, float]:
    out = {}
    for name, err in run.fit.errors.items():
        if name == "polarization_rad":
            out["polarization_deg"] = math.degrees(err)
        else:
            out[name] = err
    return out


def _values(run: CalibrationRun) -> dict[str, float]:
    out = {}
    for name, value in run.fit.values.items():
        if name == "polarization_rad":
            out["polarization_deg"] = math.degrees(value)
        else:
            out[name] = value
    return out


def _calibration_table(run: CalibrationRun, records: Sequence[FrameRecord],
                       config: CalibrateConfig, inputs: Sequence[Path]) -> dict[str, Any]:
    """The ``[calibration]`` table of ``instrument.toml`` (module docstring)."""
    failed = [r for r in records if not r.ok]
    records = [r for r in records if r.ok]
    fit = run.fit
    k = len(fit.values)
    names = list(_values(run))
    scale = [180.0 / math.pi if n == "polarization_deg" else 1.0 for n in names]
    cov = np.asarray(fit.covariance[:k, :k]) * np.outer(scale, scale)
    zs = [r.before["z_um"] for r in records]
    start = run.start
    material: dict[str, Any] = {}
    for key, value, sd in (("index", config.index, config.index_sd),
                           ("radius_um", config.radius_um, config.radius_sd_um)):
        if value is not None:
            material[key] = value
            material[f"{key}_sd" if key == "index" else "radius_sd_um"] = (
                sd if sd is not None else 0.0)
    table: dict[str, Any] = {
        "method": "holofit calibrate: joint fit of sphere holograms at several heights "
                  "(holofit.calibrate.calibrate_instrument), every sphere's x, y, z, radius, "
                  "index and alpha free unless stated",
        "fitted": names,
        "status": fit.status,
        "message": fit.message,
        "chi2_red": fit.chi2_red,
        "chi2_per_pixel_before": run.chi2_before,
        "chi2_per_pixel_after": run.chi2_after,
        "edge_phase_rad": fit.edge_phase_rad,
        "edge_phase_error_rad": fit.edge_phase_error_rad,
        "n_frames": len(records),
        "frames": [int(r.key[1]) for r in records],
        "particles": [int(r.key[0]) for r in records],
        "failed_frames": [int(r.key[1]) for r in failed],
        "z_range_um": [float(min(zs)), float(max(zs))],
        "crops": str(Path(inputs[0]).parent.resolve()),
        "prefit": str(Path(inputs[-1]).resolve()),
        "command": command_line(),
        "holofit_version": holofit.__version__,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "time_s": run.time_s,
        "values": _values(run),
        "errors": _errors(run),
        "covariance": {"names": names, "matrix": [[float(v) for v in row] for row in cov]},
        "start": {"numerical_aperture": start.optics.numerical_aperture,
                  "spherical_aberration_rad": list(start.aberration.spherical),
                  "polarization_deg": math.degrees(start.polarization_rad)},
    }
    if material:
        table["material"] = material
    return table


def _comments(run: CalibrationRun) -> list[str]:
    fit = run.fit
    lines = [f"Calibrated by `holofit calibrate` (holofit {holofit.__version__}) on "
             f"{len(run.keys)} sphere frame(s); the fit's errors, provenance and chi^2 are in",
             "[calibration] below (holofit reads [instrument] only). Fitted (1 sigma):"]
    for name, value in _values(run).items():
        lines.append(f"  {name} = {value:.6g} +- {_errors(run)[name]:.2g}")
    lines.append(f"  pupil phase at the aperture's edge {fit.edge_phase_rad:.4g} +- "
                 f"{fit.edge_phase_error_rad:.2g} rad")
    lines.append(f"chi^2 per pixel {run.chi2_before:.4g} (start instrument) -> "
                 f"{run.chi2_after:.4g} (calibrated); status {fit.status}")
    return lines


def plot_calibration(table: pd.DataFrame, png_path: Path, title: str) -> Path:
    """chi^2 per pixel, index and radius against height, before and after (``calibration.png``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4))
    panels = (("chi2_per_px", "chi^2 per pixel"), ("n", "index n"), ("radius_um", "radius (um)"))
    for ax, (col, label) in zip(axes, panels, strict=True):
        before = f"{col}_before"
        after = f"{col}_after" if col != "chi2_per_px" else "chi2_per_px_after"
        ax.plot(table["z_um_before"], table[before], "o", mfc="none", color="C3",
                label="before (prefit)")
        ax.plot(table["z_um_after"], table[after], ".", color="C0", label="after (calibrated)")
        ax.set_xlabel("z (um)")
        ax.set_ylabel(label)
    axes[0].legend(fontsize=8)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    with atomic_path(png_path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
    return png_path


def write_outputs(run: CalibrationRun, records: Sequence[FrameRecord],
                  config: CalibrateConfig, before: Instrument, inputs: Sequence[Path]) -> None:
    """Write ``instrument.toml``, ``calibration.csv`` (+ sidecar) and ``calibration.png``
    into the folder of ``run.instrument_toml``; ``run.instrument`` becomes the file's."""
    out = run.instrument_toml.parent
    inst = run.instrument
    n_fitted = sum(r.ok for r in records)
    source = (f"holofit calibrate on {n_fitted} sphere frame(s) of "
              f"{Path(inputs[0]).parent.resolve()} ([calibration])")
    extra = {**inst.extra, "source": source}
    inst = replace(inst, extra=extra, path=str(run.instrument_toml))
    text = instrument_toml(inst, comments=_comments(run),
                           tables={"calibration": _calibration_table(run, records, config,
                                                                     inputs)})
    table = calibration_table(run, records)
    fit = run.fit
    meta = sidecar(kind="calibration table (the instrument's joint fit, per frame)",
                   units=CALIBRATION_UNITS, config=config.as_dict(), inputs=list(inputs),
                   extra={"instrument": inst.as_dict(), "start_instrument": run.start.as_dict(),
                          "before_instrument": before.as_dict(), "values": fit.values,
                          "errors": fit.errors, "names": list(fit.names[:len(fit.values)]),
                          "chi2_red": fit.chi2_red, "status": fit.status,
                          "message": fit.message, "edge_phase_rad": fit.edge_phase_rad,
                          "edge_phase_error_rad": fit.edge_phase_error_rad,
                          "chi2_per_pixel_before": run.chi2_before,
                          "chi2_per_pixel_after": run.chi2_after, "trials": fit.trials,
                          "n_eval": fit.n_eval, "time_s": run.time_s, "notes": run.notes,
                          "failed": {f"{k[0]},{k[1]}": m for k, m in run.failed.items()}})
    write_table(run.table, table, meta)
    # the instrument file's sidecar first (a complete file always has one), then the file
    write_json(sidecar_path(run.instrument_toml), sidecar(
        kind="instrument file (calibrated by holofit calibrate; its [calibration] table has "
             "the fit's values, errors and provenance)",
        units={k: spec.expected for k, spec in INSTRUMENT_SPECS.items()},
        config=config.as_dict(), inputs=list(inputs),
        extra={"instrument": inst.as_dict(), "start_instrument": run.start.as_dict(),
               "values": fit.values, "errors": fit.errors, "status": fit.status,
               "chi2_per_pixel_before": run.chi2_before,
               "chi2_per_pixel_after": run.chi2_after, "table": str(run.table)}))
    atomic_write_text(run.instrument_toml, text)
    run.instrument = load_instrument(run.instrument_toml)
    if config.plot:
        title = (f"holofit calibrate: {n_fitted} frame(s); chi^2/px "
                 f"{run.chi2_before:.3g} -> {run.chi2_after:.3g} (calibration.csv)")
        run.plot = plot_calibration(table, out / "calibration.png", title)
