"""``holofit crop``: a thin layer over :func:`holofit.crop.run_crop`."""

from __future__ import annotations

from pathlib import Path

import click

from holofit.batch.options import BatchSettings
from holofit.cli.common import instrument_option, load_instrument_arg, out_dir_option
from holofit.crop import CenterFinder, CropConfig, CropResult, run_crop
from holofit.crop.centerfind import MIN_RADIUS_PX
from holofit.crop.settings import (
    AUTO_VOTE_RADIUS,
    CROP_MODES,
    DEFAULT_CROP_SIZE,
    MIN_CROP_SIZE,
    TRACKS,
)
from holofit.crop.tracks import LinkSettings, TrackError
from holofit.status import CROP_ERROR


def _parse_start(value: str | None) -> tuple[float, float] | None:
    if value is None:
        return None
    try:
        parts = [float(v) for v in value.split(",")]
    except ValueError:
        parts = []
    if len(parts) != 2:
        raise click.BadParameter(
            f"expected X,Y in pixels (x = column, y = row), got {value!r}", param_hint="--start"
        )
    return parts[0], parts[1]


@click.command()
@click.argument("movie", type=click.Path(path_type=Path))
@click.option(
    "--background",
    "-b",
    "backgrounds",
    multiple=True,
    type=click.Path(path_type=Path),
    help="Background: one frame, or a stack / folder; repeat for several files. The "
    "per-pixel median of all their frames is used.",
)
@click.option(
    "--normalized",
    is_flag=True,
    help="MOVIE is background-divided already (as many public data sets are, also as scaled "
    "integers): no background; each frame is divided by its mean.",
)
@click.option(
    "--dark",
    "darks",
    multiple=True,
    type=click.Path(path_type=Path),
    help="Dark frame (or stack) to subtract from movie and background; repeat for several "
    "files (per-pixel median).",
)
@click.option(
    "--dark-count",
    type=click.FloatRange(min=0),
    default=None,
    help="Dark level in counts, the same for every pixel (instead of --dark).",
)
@instrument_option()
@out_dir_option()
@click.option(
    "--size",
    type=click.IntRange(min=MIN_CROP_SIZE),
    default=None,
    help="Crop side N, pixels [default: 140, the paper's, or 4 zone radii sqrt(wavelength in "
    "the medium x height) of the movie's holograms where that is larger: measured on a few "
    "frames].",
)
@click.option(
    "--follow",
    type=click.Choice(CROP_MODES),
    default=TRACKS,
    show_default=True,
    help="tracks: every hologram in view, linked into tracks (column particle), one crop per "
    "(particle, frame); or one hologram per frame (single-particle): the strongest, or the one "
    "nearest the last position (start at --start).",
)
@click.option("--particle", type=click.IntRange(min=0), default=None,
              help="With tracks: keep only this track (its id in a run without --particle).")
@click.option("--search-range-um", type=click.FloatRange(min=0, min_open=True),
              default=LinkSettings.search_range_um, show_default=True,
              help="With tracks: farthest a hologram centre moves between frames, um.")
@click.option("--memory", type=click.IntRange(min=0), default=LinkSettings.memory,
              show_default=True,
              help="With tracks: frames a hologram may go undetected and keep its track.")
@click.option("--min-track-length", type=click.IntRange(min=1),
              default=LinkSettings.min_track_length, show_default=True,
              help="With tracks: shorter tracks (frames detected; at most half the movie) are "
              "reported and left out.")
@click.option(
    "--start",
    default=None,
    metavar="X,Y",
    help="Particle position in the first frame, pixels (x = column, y = row); with "
    "--follow nearest.",
)
@click.option(
    "--max-jump",
    type=click.FloatRange(min=0, min_open=True),
    default=None,
    help="Largest move between frames, pixels [default: size/4]: with --follow nearest, a "
    "farther candidate is no particle; with strongest, frames off the main track (another "
    "particle) are marked off_track.",
)
@click.option(
    "--vote-radius",
    "--radius",
    "radius",
    type=click.FloatRange(min=MIN_RADIUS_PX),
    default=None,
    help="Vote radius of the centre finder, pixels [default: half the crop side] (--radius: "
    "the old "
    "name, deprecated). Close holograms are resolved whatever it is: two centres merge only "
    "within half a hologram's measured zone radius, sqrt(wavelength in the medium x height).",
)
@click.option(
    "--min-score",
    type=click.FloatRange(min=0),
    default=CenterFinder.min_score,
    show_default=True,
    help="Smallest accepted detection score (transform peak over its rms for pure noise; "
    "noise alone reaches ~5).",
)
@click.option(
    "--min-symmetry",
    type=click.FloatRange(-1, 1),
    default=CenterFinder.min_symmetry,
    show_default=True,
    help="Smallest accepted point symmetry (1 = perfect); lower it for strongly asymmetric "
    "holograms.",
)
@click.option(
    "--max-particles",
    type=click.IntRange(min=1),
    default=None,
    help="With tracks: keep the N longest tracks [default: all]; with strongest or nearest: "
    "the most candidates kept per frame [default: 10].",
)
@click.option(
    "--mask-saturated/--keep-saturated",
    default=True,
    show_default=True,
    help="Mask (NaN) pixels at the camera's full-scale count.",
)
@click.option("--plot/--no-plot", default=True, show_default=True, help="Write crops.png.")
@click.option("--workers", "-j", type=click.IntRange(min=0), default=None,
              help="Worker processes searching frames (default: all available CPUs; 0: in "
                   "this process).")
@click.option("--progress/--no-progress", default=None,
              help="Progress bar [default: when stderr is a terminal].")
def crop(
    movie: Path,
    backgrounds: tuple[Path, ...],
    normalized: bool,
    darks: tuple[Path, ...],
    dark_count: float | None,
    instrument: str,
    out: Path,
    size: int | None,
    follow: str,
    particle: int | None,
    search_range_um: float,
    memory: int,
    min_track_length: int,
    start: str | None,
    max_jump: float | None,
    radius: float | None,
    min_score: float,
    min_symmetry: float,
    max_particles: int | None,
    mask_saturated: bool,
    plot: bool,
    workers: int | None,
    progress: bool | None,
) -> None:
    """Normalise a raw MOVIE by its background, find hologram centres, crop N x N around them.

    Frames are searched in parallel (-j); an interrupted run, run again, keeps the frames it
    had searched (OUT/detections.csv while it runs).

    MOVIE is a multi-page (or OME-) TIFF or a folder of TIFF frames, 8 or 16 bit (or float);
    LZW- and deflate-compressed TIFFs are read too; with holofit[movies] installed also a video
    (AVI, MP4, MOV, MKV), a folder of PNG frames or an HDF5 file (FILE.h5:DATASET).
    Writes OUT/crops.tif (float32 normalised crops, one page per frame; NaN = masked or no
    particle), OUT/crops.csv (+ crops.csv.json: per-frame centre in pixels and um, crop corner,
    score, status), OUT/candidates.csv and OUT/crops.png. Every frame the movie file claims
    gets a row: one that cannot be read (a truncated file) has status error.
    """
    _check_references(backgrounds, normalized, darks, dark_count)
    start_xy = _parse_start(start)
    if start_xy is not None and follow != "nearest":
        raise click.UsageError("--start needs --follow nearest")
    inst = load_instrument_arg(instrument)
    try:
        finder = CenterFinder(
            radius_px=(radius if radius is not None else
                       AUTO_VOTE_RADIUS if size is None else size / 2.0),
            min_score=min_score,
            min_symmetry=min_symmetry,
            max_centers=_max_centers(follow, max_particles),
        )
        link = (LinkSettings(search_range_um, memory, min_track_length, max_particles)
                if follow == TRACKS else None)
    except (ValueError, TrackError) as exc:
        raise click.UsageError(str(exc)) from None
    if follow != TRACKS and particle is not None:
        raise click.UsageError("--particle needs --follow tracks (the default)")
    config = CropConfig(size=DEFAULT_CROP_SIZE if size is None else size, follow=follow,
                        start=start_xy, max_jump_px=max_jump,
                        finder=finder, link=link, particle=particle, normalized=normalized,
                        dark=list(darks) or dark_count, mask_saturated=mask_saturated, plot=plot)
    result = run_crop(movie, list(backgrounds) or None, inst, out, config,
                      batch=BatchSettings(workers=workers, progress=progress))
    _report(result)


def _max_centers(follow: str, max_particles: int | None) -> int:
    """Candidates the finder keeps per frame: ``--max-particles`` in the single-particle
    modes; in tracks mode at least the default, and room for every track kept."""
    default = CenterFinder.max_centers
    if max_particles is None:
        return default
    return max_particles if follow != TRACKS else max(default, 2 * max_particles)


def _check_references(backgrounds: tuple[Path, ...], normalized: bool, darks: tuple[Path, ...],
                      dark_count: float | None) -> None:
    """Refuse a background or dark level given, or missing, against ``--normalized``."""
    if darks and dark_count is not None:
        raise click.UsageError("give either --dark or --dark-count, not both")
    if normalized and (backgrounds or darks or dark_count is not None):
        raise click.UsageError(
            "--normalized takes no --background, --dark or --dark-count: the movie is "
            "normalised already"
        )
    if not normalized and not backgrounds:
        raise click.UsageError(
            "give the background of the raw movie (--background, repeat for several files), "
            "or --normalized for a movie that is normalised already"
        )


def _report(result: CropResult) -> None:
    """What the crop wrote, its warnings and its first frame errors."""
    counts = ", ".join(f"{v} {k}" for k, v in result.counts.items() if v)
    n_tracks = (result.frames["particle"].nunique() if "particle" in result.frames.columns
                else 1)
    rows = (f"{n_tracks} tracks, {len(result.frames)} (particle, frame) rows" if n_tracks > 1
            else f"{len(result.frames)} frames")
    click.echo(f"wrote {result.crops} and {result.table} ({rows}: {counts})")
    for problem in [*result.problems, *result.warnings]:
        click.echo(f"holofit crop: warning: {problem}", err=True)
    errors = result.frames[result.frames["status"] == CROP_ERROR]
    for message in errors["message"].head(5):
        click.echo(f"  error: {message}", err=True)
    if len(errors) > 5:
        click.echo(f"  ... {len(errors) - 5} more frame errors in {result.table}", err=True)
    for note in result.notes:
        click.echo(f"holofit crop: note: {note}", err=True)
