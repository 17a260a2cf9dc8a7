"""``holofit prefit``: Lorenz-Mie fit of every crop, in parallel, resumable."""

from __future__ import annotations

from pathlib import Path

import click

from holofit.batch.errors import BatchError
from holofit.batch.runner import BatchOptions
from holofit.cli.common import instrument_option, load_instrument_arg, out_dir_option
from holofit.fitting.crops import CropSetError
from holofit.fitting.estimate import SearchSpace
from holofit.fitting.prefit import run_prefit
from holofit.fitting.sphere_fit import FitOptions
from holofit.io.lock import OutputLocked


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


def _frames(value: str | None) -> slice | None:
    if value is None:
        return None
    try:
        start, stop = value.split(":")
        return slice(int(start) if start else None, int(stop) if stop else None)
    except ValueError:
        raise click.BadParameter(
            f"expected START:STOP (frame numbers, STOP excluded), got {value!r}",
            param_hint="--frames",
        ) from None


@click.command()
@click.argument("crop_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@out_dir_option()
@instrument_option(required=False)
@click.option(
    "--workers",
    "-j",
    type=click.IntRange(min=0),
    default=None,
    help="Worker processes (default: all available CPUs; 0: run in this process). With "
    "--dask-local: workers of the local Dask cluster.",
)
@click.option(
    "--scheduler",
    metavar="ADDRESS",
    default=None,
    help="Run on a Dask cluster: scheduler address (tcp://host:8786) or scheduler-file path.",
)
@click.option(
    "--dask-local",
    is_flag=True,
    help="Run on a local Dask cluster (loopback only) instead of the process pool.",
)
@click.option(
    "--fix-alpha",
    type=float,
    default=None,
    metavar="ALPHA",
    help="Hold alpha at this value (e.g. 1) instead of fitting it.",
)
@click.option(
    "--index-imag",
    type=click.FloatRange(min=0),
    default=0.0,
    show_default=True,
    help="Imaginary part of the particle index (held fixed).",
)
@click.option(
    "--saturation",
    type=float,
    default=None,
    metavar="LEVEL",
    help="Leave out pixels whose normalised value is >= LEVEL (NaN pixels always are).",
)
@click.option(
    "--pixel-fraction",
    type=click.FloatRange(min=0, max=1, min_open=True),
    default=1.0,
    show_default=True,
    help="Fit a random subset with this fraction of the pixels (seeded by frame).",
)
@click.option(
    "--noise-sd",
    type=click.FloatRange(min=0, min_open=True),
    default=None,
    help="Pixel noise for chi^2 (normalised units; default: estimated per crop).",
)
@click.option(
    "--z-range",
    default=None,
    metavar="MIN,MAX",
    help="Heights searched by the automatic start, um [default: 2,50].",
)
@click.option(
    "--radius-range",
    default=None,
    metavar="MIN,MAX",
    help="Radii searched by the automatic start, um [default: 0.2,1.6].",
)
@click.option(
    "--index-range",
    default=None,
    metavar="MIN,MAX",
    help="Absolute indices searched [default: 1.02 to 1.30 times the medium's].",
)
@click.option(
    "--frames",
    default=None,
    metavar="START:STOP",
    help="Only frames START <= frame < STOP.",
)
@click.option(
    "--retry-failed", is_flag=True, help="Run again frames recorded as error / not_converged."
)
@click.option(
    "--overwrite", is_flag=True, help="Discard earlier results in OUT made with other settings."
)
@click.option("--plot/--no-plot", default=True, show_default=True, help="Write prefit.png.")
@click.option(
    "--progress/--no-progress",
    default=None,
    help="Progress bar [default: when stderr is a terminal].",
)
def prefit(
    crop_dir: Path,
    out: Path,
    instrument: str | None,
    workers: int | None,
    scheduler: str | None,
    dask_local: bool,
    fix_alpha: float | None,
    index_imag: float,
    saturation: float | None,
    pixel_fraction: float,
    noise_sd: float | None,
    z_range: str | None,
    radius_range: str | None,
    index_range: str | None,
    frames: str | None,
    retry_failed: bool,
    overwrite: bool,
    plot: bool,
    progress: bool | None,
) -> None:
    """Lorenz-Mie fit of every crop (x, y, z, radius, index, alpha), no manual guess.

    Reads CROP_DIR (crops.tif, crops.csv and its sidecar, as written by `holofit crop`) and
    writes OUT/prefit.csv (one row per frame: values, 1-sigma uncertainties, chi^2, R^2,
    evaluations, time, status), its sidecar JSON and OUT/prefit.png. x, y start from the crop
    table; z, radius, index and alpha from the crop's radial profile. Frames run in parallel;
    an interrupted run resumes where it stopped when the same command is run again.
    """
    inst = load_instrument_arg(instrument) if instrument else None
    space_kw = {}
    for key, value, name in (
        ("z_range_um", z_range, "--z-range"),
        ("radius_range_um", radius_range, "--radius-range"),
        ("index_range", index_range, "--index-range"),
    ):
        rng = _range(value, name)
        if rng is not None:
            space_kw[key] = rng
    try:
        fit = FitOptions(
            fix_alpha=fix_alpha,
            index_imag=index_imag,
            saturation=saturation,
            pixel_fraction=pixel_fraction,
            noise_sd=noise_sd,
            search=SearchSpace(**space_kw),
        )
        batch = BatchOptions(
            workers=workers,
            scheduler=scheduler,
            dask_local=dask_local,
            retry_failed=retry_failed,
            overwrite=overwrite,
            progress=progress,
        )
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None
    sel = _frames(frames)
    frame_list = None
    if sel is not None:
        from holofit.fitting.crops import CropSet

        try:
            with CropSet(crop_dir) as crops:
                frame_list = [
                    f
                    for f in crops.frames
                    if (sel.start is None or f >= sel.start) and (sel.stop is None or f < sel.stop)
                ]
        except CropSetError as exc:
            raise click.ClickException(str(exc)) from None
    try:
        result = run_prefit(
            crop_dir, out, instrument=inst, fit=fit, frames=frame_list, batch=batch, plot=plot
        )
    except (CropSetError, BatchError, OutputLocked) as exc:
        raise click.ClickException(str(exc)) from None
    s = result.summary
    for note in s.notes:
        click.echo(f"note: {note}", err=True)
    counts = ", ".join(f"{k} {v}" for k, v in sorted(s.statuses.items()))
    click.echo(
        f"prefit: {s.n_frames} frame(s) [{counts}]; {s.n_run} fitted now, "
        f"{s.n_done_before} done before; {s.elapsed_s:.1f} s -> {result.table}"
    )
