"""Command-line options shared by the per-frame stages (prefit, library, fit): where frames run,
how a rerun treats earlier results, which frames, progress, and the quality thresholds."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click

from holofit.batch import BatchSettings
from holofit.batch.aperture import FROM_INSTRUMENT, ApertureChoice, parse_numerical_aperture

__all__ = [
    "aperture_choice",
    "aperture_options",
    "batch_options",
    "frame_list",
    "make_batch_options",
    "parse_frames",
    "parse_int_list",
    "quality_options",
]

F = TypeVar("F", bound=Callable[..., Any])

_OPTIONS = [
    click.option("--workers", "-j", type=click.IntRange(min=0), default=None,
                 help="Worker processes (default: all available CPUs; 0: run in this process)."
                      " With --dask-local: workers of the local Dask cluster."),
    click.option("--scheduler", metavar="ADDRESS", default=None,
                 help="Run on a Dask cluster: scheduler address (tcp://host:8786) or "
                      "scheduler-file path."),
    click.option("--dask-local", is_flag=True,
                 help="Run on a local Dask cluster (loopback only) instead of the process pool."),
    click.option("--frames", "frame_range", default=None, metavar="START:STOP",
                 help="Only frames START <= frame < STOP."),
    click.option("--retry-failed", is_flag=True,
                 help="Run again frames recorded as not_converged too (frames recorded as "
                      "error are always run again)."),
    click.option("--overwrite", is_flag=True,
                 help="Discard earlier results in OUT made with other settings."),
    click.option("--progress/--no-progress", default=None,
                 help="Progress bar [default: when stderr is a terminal]."),
]


_QUALITY = [
    click.option("--max-chi2-red", type=click.FloatRange(min=0, min_open=True), default=10.0,
                 show_default=True,
                 help="A converged fit with a larger reduced chi^2 and an R^2 below 0.8 is "
                      "poor_fit."),
    click.option("--min-r2", type=click.FloatRange(max=1, max_open=True), default=None,
                 hidden=True,
                 help="Deprecated, without effect: a low R^2 no longer makes a fit poor_fit "
                      "(a fit is judged by its chi^2 against the pixel noise)."),
    click.option("--outlier-factor", type=click.FloatRange(min=1), default=4.0,
                 show_default=True,
                 help="An ok frame whose reduced chi^2 exceeds this times the movie's median "
                      "becomes poor_fit."),
    click.option("--plot/--no-plot", default=True, show_default=True,
                 help="Write the summary plot and data/model/residual pictures."),
    click.option("--plot-frames", default=None, metavar="N,N,...",
                 help="Frames to draw as data/model/residual pictures [default: the first ok,"
                      " the worst ok and the first poor fit]."),
    click.option("--override-instrument", is_flag=True,
                 help="Allow --instrument to contradict the instrument the crops were made "
                      "with."),
]


_APERTURE = [
    click.option("--numerical-aperture", "numerical_aperture", default=None, metavar="NA|none",
                 help="The objective's NA the model is imaged with (the lens model), or 'none' "
                      "for the ideal model (the field in the focal plane) [default: the "
                      "instrument's numerical_aperture, the ideal model if it has none]."),
    click.option("--fit-na", is_flag=True,
                 help="Fit the numerical aperture too, starting from --numerical-aperture or "
                      "the instrument's (at most the medium's index: beyond it nothing "
                      "changes)."),
]


def aperture_options(func: F) -> F:
    """Add ``--numerical-aperture`` and ``--fit-na`` to a command."""
    for option in reversed(_APERTURE):
        func = option(func)
    return func


def aperture_choice(value: str | None) -> ApertureChoice:
    """``--numerical-aperture``: absent -> the instrument's, ``none`` -> None, else the NA."""
    if value is None:
        return FROM_INSTRUMENT
    try:
        return parse_numerical_aperture(value)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--numerical-aperture") from None


def quality_options(func: F) -> F:
    """Add the quality-threshold and picture options to a command."""
    for option in reversed(_QUALITY):
        func = option(func)
    return func


def batch_options(func: F) -> F:
    """Add the batch options to a command (they arrive as keyword arguments)."""
    for option in reversed(_OPTIONS):
        func = option(func)
    return func


def make_batch_options(workers: int | None, scheduler: str | None, dask_local: bool,
                       retry_failed: bool, overwrite: bool, progress: bool | None
                       ) -> BatchSettings:
    """:class:`BatchSettings` from the options, bad combinations as a usage error."""
    try:
        return BatchSettings(workers=workers, scheduler=scheduler, dask_local=dask_local,
                            retry_failed=retry_failed, overwrite=overwrite, progress=progress)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--scheduler / --dask-local") from None


def parse_frames(value: str | None) -> slice | None:
    """``START:STOP`` -> slice (either end may be empty)."""
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


def frame_list(crop_dir: Path, value: str | None) -> list[int] | None:
    """The crop folder's frames inside ``--frames`` (None: all)."""
    sel = parse_frames(value)
    if sel is None:
        return None
    from holofit.tables.cropset import CropSet

    with CropSet(crop_dir) as crops:
        frames = sorted(set(crops.frames)) if crops.multi else crops.frames
        return [f for f in frames if (sel.start is None or f >= sel.start)
                and (sel.stop is None or f < sel.stop)]


def parse_int_list(value: str | None, name: str) -> list[int] | None:
    """``3,17,40`` -> [3, 17, 40]."""
    if value is None:
        return None
    try:
        return [int(v) for v in value.split(",") if v.strip()]
    except ValueError:
        raise click.BadParameter(f"expected comma-separated frame numbers, got {value!r}",
                                 param_hint=name) from None

