"""The fit passes' pictures: each pass's parameters against frame, and a few frames' data /
model / residual images (:mod:`holofit.holomodel.pictures`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from holofit.holomodel.parameters import static_parameters
from holofit.holomodel.pictures import write_frame_pictures
from holofit.holomodel.plots import plot_table
from holofit.io.tables import read_table

__all__ = ["pass_pictures", "picture_prefix"]


def picture_prefix(particle: int, n_tracks: int) -> str:
    """The frame pictures' file prefix of a track: ``p<id>_`` in a run of several tracks,
    none for a single one (the file names say whose frame it is)."""
    return f"p{particle}_" if n_tracks > 1 else ""


def pass_pictures(path: Path, given: Any, cfg: Any, out: Path, name: str, stem: str,
                  config: Any) -> None:
    """``<stem>.png`` (the table's columns against frame) and ``frames_<name>/`` (data /
    model / residual of a few frames of each track) for the pass table at ``path``."""
    model = cfg.particle.model
    panels = [("x_um", "x (um)"), ("y_um", "y (um)"), ("z_um", "z (um)")]
    if model.anisotropic:
        panels += [("theta_rad", "theta (rad)"), ("psi_rad", "psi (rad)")]
    panels += [("alpha", "alpha")]
    panels += [(p.name, f"{p.name} ({p.unit})") for p in static_parameters(model)]
    panels += [("r2", "R^2"), ("delta_chi2", "runner-up delta chi^2"),
               ("fit_time_s", "fit time (s)")]
    plot_table(path, out / f"{stem}.png", panels, f"holofit fit ({name} pass)", f"{stem}.csv")
    table = read_table(path)
    inst = given.instrument
    tracks = sorted(int(v) for v in table["particle"].unique())
    for p in tracks:
        track = cfg.for_track(p)
        theory = track.particle.theory(config.engine)
        write_frame_pictures(table[table["particle"] == p], given.crops, track.particle.model,
                             theory, inst.optics, inst.pixel_size_um, out / f"frames_{name}",
                             f"fit ({name} pass)",
                             None if config.plot_frames is None else list(config.plot_frames),
                             config.frame.far_field, picture_prefix(p, len(tracks)))
