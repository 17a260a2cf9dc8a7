"""``holofit prefit``: Lorenz-Mie fit of every crop, in parallel, resumable."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from holofit.cli.common import instrument_option, load_instrument_arg, out_dir_option
from holofit.cli.stage_options import (
    aperture_choice,
    aperture_options,
    batch_options,
    frame_list,
    make_batch_options,
    parse_int_list,
    quality_options,
)
from holofit.prefit.estimate import SearchSpace
from holofit.prefit.sphere import SphereFitSettings
from holofit.prefit.stage import run_prefit
from holofit.quality import QualityLimits


def _range(value: str | None, name: str) -> tuple[float, float] | None:
    if value is None:
        return None
    try:
        lo, hi = (float(v) for v in value.split(","))
    except ValueError:
        raise click.BadParameter(f"expected MIN,MAX, got {value!r}", param_hint=name) from None
    if not lo < hi:
        raise click.BadParameter(f"expected MIN < MAX, got {value!r}", param_hint=name)
    return lo, hi


@click.command()
@click.argument("crop_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@out_dir_option()
@instrument_option(required=False)
@click.option("--fix-alpha", type=float, default=None, metavar="ALPHA",
              help="Hold alpha at this value (e.g. 1) instead of fitting it.")
@click.option("--index-imag", type=click.FloatRange(min=0), default=0.0, show_default=True,
              help="Imaginary part of the particle index (held fixed).")
@click.option("--saturation", type=float, default=None, metavar="LEVEL",
              help="Leave out pixels whose normalised value is >= LEVEL [default: none; "
                   "pixels masked by crop (NaN) are always left out].")
@click.option("--pixel-fraction", type=click.FloatRange(min=0, max=1, min_open=True),
              default=1.0, show_default=True,
              help="Fit a random subset with this fraction of the pixels (seeded by frame).")
@click.option("--noise-sd", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Pixel noise for chi^2 (normalised units; default: estimated per crop).")
@click.option("--z-range", default=None, metavar="MIN,MAX",
              help="Heights searched by the automatic start, um [default: 2 um up to what the "
                   "crop can show, at least 50 um]. Not crossing the focal plane; with the "
                   "objective lens in the model, heights below it (e.g. --z-range=-10,-1) and "
                   "near it are allowed.")
@click.option("--radius-range", default=None, metavar="MIN,MAX",
              help="Radii searched by the automatic start, um [default: 0.2,1.6].")
@click.option("--index-range", default=None, metavar="MIN,MAX",
              help="Absolute indices searched [default: 1.02 to 1.30 times the medium's].")
@click.option("--seed-only", is_flag=True,
              help="Seed x, y, z and alpha only, at a sphere prefit's cost (a non-spherical "
                   "particle, whose sizes the DDA fit's initial pass finds; `holofit init` "
                   "sets it for one): radius and index stay at the radial profile's "
                   "estimate.")
@aperture_options
@quality_options
@batch_options
def prefit(
    crop_dir: Path,
    out: Path,
    instrument: str | None,
    fix_alpha: float | None,
    index_imag: float,
    saturation: float | None,
    pixel_fraction: float,
    noise_sd: float | None,
    z_range: str | None,
    radius_range: str | None,
    index_range: str | None,
    seed_only: bool,
    numerical_aperture: str | None,
    fit_na: bool,
    max_chi2_red: float,
    min_r2: float | None,
    outlier_factor: float,
    plot: bool,
    plot_frames: str | None,
    override_instrument: bool,
    workers: int | None,
    scheduler: str | None,
    dask_local: bool,
    frame_range: str | None,
    retry_failed: bool,
    overwrite: bool,
    progress: bool | None,
) -> None:
    """Lorenz-Mie fit of every crop (x, y, z, radius, n, alpha), no manual guess.

    Reads CROP_DIR (crops.tif, crops.csv and its sidecar, as written by `holofit crop`) and
    writes OUT/prefit.csv (one row per frame: values, 1-sigma uncertainties d_*, chi2, chi2_red,
    R^2, evaluations, time, status), its sidecar JSON, OUT/prefit.png and data/model/residual
    pictures in OUT/frames/. x, y start from the crop table; z, radius, index and alpha from the
    crop's radial profile. With an objective NA (the instrument's numerical_aperture, or
    --numerical-aperture) the model is the image through that lens; --fit-na fits the NA too.
    Frames run in parallel; an interrupted run resumes where it stopped when the same command
    is run again.
    """
    inst = load_instrument_arg(instrument) if instrument else None
    space_kw: dict[str, Any] = {}  # SearchSpace's keyword arguments by name
    for key, value, name in (
        ("z_range_um", z_range, "--z-range"),
        ("radius_range_um", radius_range, "--radius-range"),
        ("index_range", index_range, "--index-range"),
    ):
        rng = _range(value, name)
        if rng is not None:
            space_kw[key] = rng
    try:
        search = SearchSpace(**space_kw)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--z-range / --radius-range / "
                                 "--index-range") from None
    if min_r2 is not None:
        click.echo("note: --min-r2 is deprecated and has no effect: a fit is judged by its "
                   "chi^2 against the pixel noise, not by its R^2", err=True)
    try:
        fit = SphereFitSettings(fix_alpha=fix_alpha, index_imag=index_imag, saturation=saturation,
                         pixel_fraction=pixel_fraction, noise_sd=noise_sd, search=search,
                         quality=QualityLimits(max_chi2_red), fit_na=fit_na,
                         seed_only=seed_only)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--fix-alpha / --seed-only") from None
    batch = make_batch_options(workers, scheduler, dask_local, retry_failed, overwrite, progress)
    result = run_prefit(
        crop_dir, out, instrument=inst, fit=fit, frames=frame_list(crop_dir, frame_range),
        batch=batch, plot=plot, plot_frames=parse_int_list(plot_frames, "--plot-frames"),
        override_instrument=override_instrument, outlier_factor=outlier_factor,
        numerical_aperture=aperture_choice(numerical_aperture),
    )
    s = result.summary
    for note in s.notes:
        click.echo(f"note: {note}", err=True)
    counts = ", ".join(f"{k} {v}" for k, v in sorted(s.statuses.items()))
    click.echo(
        f"prefit: {s.n_frames} frame(s) [{counts}]; {s.n_run} fitted now, "
        f"{s.n_done_before} done before; {s.elapsed_s:.1f} s -> {result.table}"
    )
