"""``holofit library``: best starting orientations of every frame."""

from __future__ import annotations

from pathlib import Path

import click

from holofit.cli.common import (
    instrument_option,
    load_instrument_arg,
    load_particle_arg,
    out_dir_option,
    particle_option,
)
from holofit.cli.stage_options import batch_options, frame_list, make_batch_options
from holofit.engines.select import ENGINE_CHOICES
from holofit.library.stage import LibrarySettings, run_library


@click.command()
@click.argument("crop_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--prefit", "prefit_dir", required=True,
              type=click.Path(exists=True, path_type=Path),
              help="Output of `holofit prefit` for these crops (positions, heights, alpha).")
@particle_option()
@out_dir_option()
@instrument_option(required=False)
@click.option("--engine", type=click.Choice(ENGINE_CHOICES), default=None,
              help="Scattering engine [default: the particle config's].")
@click.option("--tilt-step", type=click.FloatRange(0.5, 45), default=10.0, show_default=True,
              help="Grid step of the tilt (and spin), deg.")
@click.option("--n-phi", type=click.IntRange(min=16), default=128, show_default=True,
              help="Azimuths of the polar grid (psi resolution 360/N deg).")
@click.option("--candidates", "n_candidates", type=click.IntRange(min=1), default=4,
              show_default=True, help="Candidates kept per frame.")
@click.option("--override-instrument", is_flag=True,
              help="Allow --instrument to contradict the crops' instrument.")
@click.option("--plot/--no-plot", default=True, show_default=True, help="Write library.png.")
@batch_options
def library(
    crop_dir: Path,
    prefit_dir: Path,
    particle: str,
    out: Path,
    instrument: str | None,
    engine: str | None,
    tilt_step: float,
    n_phi: int,
    n_candidates: int,
    override_instrument: bool,
    plot: bool,
    workers: int | None,
    scheduler: str | None,
    dask_local: bool,
    frame_range: str | None,
    retry_failed: bool,
    overwrite: bool,
    progress: bool | None,
) -> None:
    """DDA holograms over a grid of orientations; the best starting orientations per frame.

    For every frame of CROP_DIR, compares the crop (on a polar grid about the prefit position)
    with the particle's holograms at the prefit height over tilts every --tilt-step degrees and
    every azimuth, and writes the best --candidates orientations with their R^2 to
    OUT/library.csv (+ sidecar, + library.png). Parallel and resumable like `holofit prefit`.
    """
    cfg = load_particle_arg(particle)
    inst = load_instrument_arg(instrument) if instrument else None
    settings = LibrarySettings(tilt_step_deg=tilt_step, n_phi=n_phi, n_candidates=n_candidates)
    batch = make_batch_options(workers, scheduler, dask_local, retry_failed, overwrite, progress)
    result = run_library(crop_dir, prefit_dir, cfg, out, instrument=inst,
                         override_instrument=override_instrument, settings=settings,
                         engine=engine, frames=frame_list(crop_dir, frame_range), batch=batch,
                         plot=plot)
    s = result.summary
    for note in s.notes:
        click.echo(f"note: {note}", err=True)
    counts = ", ".join(f"{k} {v}" for k, v in sorted(s.statuses.items()))
    click.echo(f"library: {s.n_frames} frame(s) [{counts}]; {s.n_run} searched now, "
               f"{s.n_done_before} done before; {s.elapsed_s:.1f} s -> {result.table}")
