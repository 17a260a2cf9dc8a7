"""``holofit calibrate``: a thin layer over :func:`holofit.calibrate.stage.run_calibrate`."""

from __future__ import annotations

from pathlib import Path

import click

from holofit.aberration import MAX_SPHERICAL_TERMS
from holofit.batch import BatchSettings
from holofit.calibrate.config import (
    DEFAULT_MAX_FRAMES,
    DEFAULT_MAX_PIXELS,
    CalibrateConfig,
    CalibrateError,
)
from holofit.calibrate.stage import run_calibrate
from holofit.cli.common import instrument_option, load_instrument_arg, out_dir_option
from holofit.cli.stage_options import frame_list

_POSITIVE = click.FloatRange(min=0, min_open=True)


@click.command()
@click.argument("crop_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--prefit", "prefit_dir", required=True,
              type=click.Path(exists=True, path_type=Path),
              help="The prefit of these crops: its folder or its prefit.csv.")
@out_dir_option()
@instrument_option(required=False)
@click.option("--frames", "frame_range", default=None, metavar="START:STOP",
              help="Choose among frames START <= frame < STOP only.")
@click.option("--max-frames", type=click.IntRange(min=1), default=DEFAULT_MAX_FRAMES,
              show_default=True,
              help="Most frames fitted jointly, chosen spread evenly over the heights.")
@click.option("--fit-na/--no-fit-na", default=True, show_default=True,
              help="Fit the objective's numerical aperture.")
@click.option("--numerical-aperture", type=_POSITIVE, default=None, metavar="NA",
              help="Start NA [default: the instrument's the prefit used].")
@click.option("--aberration-terms", type=click.IntRange(0, MAX_SPHERICAL_TERMS), default=2,
              show_default=True,
              help="Spherical-aberration coefficients fitted (sa4_rad, sa6_rad, ...).")
@click.option("--no-aberration", is_flag=True,
              help="Fit no aberration coefficient (the instrument's are held).")
@click.option("--fit-polarization", is_flag=True, help="Fit the polarisation angle too.")
@click.option("--index", type=_POSITIVE, default=None, metavar="N",
              help="The spheres' stated real index: held at N, or a prior with --index-sd "
                   "[default: free].")
@click.option("--index-sd", type=_POSITIVE, default=None, metavar="SD",
              help="Standard deviation of the --index prior.")
@click.option("--radius", "radius_um", type=_POSITIVE, default=None, metavar="UM",
              help="The spheres' stated radius, um: held, or a prior with --radius-sd "
                   "[default: free].")
@click.option("--radius-sd", "radius_sd_um", type=_POSITIVE, default=None, metavar="UM",
              help="Standard deviation of the --radius prior, um.")
@click.option("--fix-alpha", type=_POSITIVE, default=None, metavar="ALPHA",
              help="Hold every frame's alpha at ALPHA [default: fitted].")
@click.option("--max-pixels", type=click.IntRange(min=100), default=DEFAULT_MAX_PIXELS,
              show_default=True,
              help="Pixels fitted per frame (a seeded random subset of larger crops).")
@click.option("--plot/--no-plot", default=True, show_default=True,
              help="Write calibration.png.")
@click.option("--progress/--no-progress", default=None,
              help="Progress bars [default: when stderr is a terminal].")
def calibrate(crop_dir: Path, prefit_dir: Path, out: Path, instrument: str | None,
              frame_range: str | None, max_frames: int, fit_na: bool,
              numerical_aperture: float | None, aberration_terms: int, no_aberration: bool,
              fit_polarization: bool, index: float | None, index_sd: float | None,
              radius_um: float | None, radius_sd_um: float | None, fix_alpha: float | None,
              max_pixels: int, plot: bool, progress: bool | None) -> None:
    """Fit the instrument (NA, spherical aberration, optionally the polarisation) jointly to
    a movie of spheres at several heights, every sphere's size and index free.

    Reads CROP_DIR (`holofit crop`) and its prefit (`holofit prefit`), chooses up to
    --max-frames spheres with a converged prefit (ok, or poor by its chi^2 only: the
    uncalibrated instrument misfits most near focus) spread over their heights, and writes
    OUT/instrument.toml (the instrument with the fitted values; their errors and the fit's
    provenance in its [calibration] table; give it to `holofit init -i` or any stage),
    OUT/calibration.csv with its sidecar (per frame: the sphere and its chi^2 per pixel
    before and after) and OUT/calibration.png (against height).
    """
    inst = load_instrument_arg(instrument) if instrument else None
    frames = frame_list(crop_dir, frame_range)
    if frames is not None and not frames:
        raise click.BadParameter(f"no frame of {crop_dir} in {frame_range!r}",
                                 param_hint="--frames")
    try:
        config = CalibrateConfig(
            max_frames=max_frames, frames=None if frames is None else tuple(frames),
            fit_na=fit_na, aberration_terms=0 if no_aberration else aberration_terms,
            fit_polarization=fit_polarization, numerical_aperture=numerical_aperture,
            instrument=inst, index=index, index_sd=index_sd, radius_um=radius_um,
            radius_sd_um=radius_sd_um, fix_alpha=fix_alpha, max_pixels=max_pixels, plot=plot)
    except CalibrateError as exc:
        raise click.UsageError(str(exc)) from None
    run = run_calibrate(crop_dir, prefit_dir, out, config, batch=BatchSettings(progress=progress))
    for note in run.notes:
        click.echo(f"note: {note}", err=True)
    fit = run.fit
    values = ", ".join(f"{k} {v:.5g} +- {fit.errors[k]:.2g}" for k, v in fit.values.items())
    click.echo(f"calibrate: {len(run.keys)} frame(s), {fit.status}: {values}; edge phase "
               f"{fit.edge_phase_rad:.3g} +- {fit.edge_phase_error_rad:.2g} rad; chi^2/px "
               f"{run.chi2_before:.4g} -> {run.chi2_after:.4g}; {run.time_s:.1f} s -> "
               f"{run.instrument_toml}")
