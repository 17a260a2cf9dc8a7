"""Data / model / residual pictures of fitted frames, for any fit table (prefit or DDA fit).

A fit row holds everything the model needs (position, angles, alpha, static parameters), so a
picture re-renders the model hologram on the crop's pixels from the row, and puts it beside the
crop. By default a stage draws the first ``ok`` frame, the ``ok`` frame with the lowest R^2
and the first converged frame that is not ``ok`` (``poor_fit``), or the frames asked for.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from holofit.aberration import SPHERICAL_NAMES, Aberration
from holofit.conventions import DetectorGrid
from holofit.hologram import hologram
from holofit.holomodel.crops import CropSource
from holofit.holomodel.parameters import APERTURE, particle_with, static_parameters
from holofit.holomodel.plots import plot_frame_fit
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.theory import Orientation, ScatteringEngine
from holofit.status import NOT_CONVERGED, OK, POOR_FIT

__all__ = ["choose_frames", "model_image", "write_frame_pictures"]


def choose_frames(table: pd.DataFrame, requested: Iterable[int] | None = None) -> list[int]:
    """Frames to draw: ``requested`` (those in the table), else the defaults above."""
    frames = set(int(f) for f in table["frame"])
    if requested is not None:
        return [int(f) for f in requested if int(f) in frames]
    out: list[int] = []
    ok = table[table["status"] == OK]
    if len(ok):
        out.append(int(ok["frame"].iloc[0]))
        worst = int(ok.loc[ok["r2"].astype(float).idxmin(), "frame"])
        if worst not in out:
            out.append(worst)
    bad = table[table["status"].isin([POOR_FIT, NOT_CONVERGED])]
    if len(bad):
        out.append(int(bad["frame"].iloc[0]))
    return out


def model_image(
    row: Mapping[str, Any], model: ParticleModel, theory: ScatteringEngine, optics: Optics,
    shape: tuple[int, int], corner_rc: tuple[int, int], pixel_size_um: float,
    far_field: bool = False,
) -> NDArray[np.float64]:
    """The model hologram of a fit row on a crop's pixels.

    Static parameters missing from the row keep ``model``'s values; orientation comes from
    ``psi_rad, theta_rad[, phi_rad]`` when the row has them; a fitted ``numerical_aperture``
    and fitted spherical-aberration coefficients (``sa4_rad``, ...) replace the optics' (the
    model is then imaged through that objective).
    """
    na = float(row.get(APERTURE.name, math.nan))
    if math.isfinite(na):
        optics = dataclasses.replace(optics, numerical_aperture=na)
    fitted = {n: float(row[n]) for n in SPHERICAL_NAMES
              if n in row and math.isfinite(float(row[n]))}
    if fitted:
        optics = dataclasses.replace(
            optics, aberration=Aberration.from_values(fitted, optics.aberration))
    statics = {p.name: float(row[p.name]) for p in static_parameters(model)
               if p.name in row and math.isfinite(float(row[p.name]))}
    particle = particle_with(model, statics)
    orientation = None
    if model.anisotropic and "theta_rad" in row:
        phi = float(row.get("phi_rad", 0.0))
        orientation = Orientation(float(row["psi_rad"]), float(row["theta_rad"]),
                                  0.0 if not math.isfinite(phi) else phi)
    grid = DetectorGrid(shape, pixel_size_um, corner_rc)
    position = (float(row["x_um"]), float(row["y_um"]), float(row["z_um"]))
    return hologram(particle, position, grid, optics, orientation, float(row["alpha"]), theory,
                    far_field)


def write_frame_pictures(
    table: pd.DataFrame, crops: CropSource, model: ParticleModel, theory: ScatteringEngine,
    optics: Optics, pixel_size_um: float, out_dir: str | Path, stage: str,
    frames: Iterable[int] | None = None, far_field: bool = False, prefix: str = "",
) -> list[Path]:
    """Draw data, model and residual of chosen frames of one track into
    ``out_dir/<prefix>frame_<n>.png`` (a run of several tracks passes ``p<particle>_``, so
    that every track's pictures are named alike).

    Frames whose model cannot be rendered (no values) are skipped.
    """
    out = Path(out_dir)
    written: list[Path] = []
    by_frame = table.set_index("frame")
    particle = int(table["particle"].iloc[0]) if "particle" in table and len(table) else None
    for frame in choose_frames(table, frames):
        row = by_frame.loc[frame].to_dict()
        if not all(math.isfinite(float(row.get(c, math.nan))) for c in
                   ("x_um", "y_um", "z_um", "alpha")):
            continue
        key: Any = frame if particle is None else (particle, frame)
        crop_row = crops.row(key)
        corner = (int(crop_row["corner_row"]), int(crop_row["corner_col"]))
        data = crops.crop(key).astype(float)
        try:
            image = model_image(row, model, theory, optics, data.shape, corner, pixel_size_um,
                                far_field)
        except ValueError:
            continue
        image = np.where(np.isfinite(data), image, np.nan)
        notes = [
            f"status {row['status']}" + (f": {row['message']}" if row.get("message") and
                                         isinstance(row["message"], str) else ""),
            f"R^2 {float(row['r2']):.4f}, reduced chi^2 {float(row['chi2_red']):.3g}, "
            f"z {float(row['z_um']):.3f} um, alpha {float(row['alpha']):.3f}, "
            + _aperture_note(row, optics),
        ]
        who = "" if not particle else f"particle {particle}, "
        written.append(plot_frame_fit(data, image, out / f"{prefix}frame_{frame:06d}.png",
                                      f"holofit {stage}: {who}frame {frame}", notes))
    return written


def _aperture_note(row: Mapping[str, Any], optics: Optics) -> str:
    """How the model was imaged: the fitted NA, the optics' NA, or the ideal model."""
    na = float(row.get(APERTURE.name, math.nan))
    if math.isfinite(na):
        return f"NA {na:.3f} (fitted)"
    if optics.numerical_aperture is not None:
        return f"NA {optics.numerical_aperture:g}"
    return "ideal model (no lens)"
