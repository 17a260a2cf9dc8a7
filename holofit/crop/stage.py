"""The crop stage: normalise every frame, find its hologram centre, write an N x N crop.

The movie is streamed: one raw frame, its normalised copy and one crop are in memory at a time,
whatever the movie's length. Outputs (in ``out_dir``):

``crops.tif`` (+ ``crops.tif.json``)
    float32 crops, one page per frame in frame order; normalised (background ~1); NaN where a
    pixel is masked; an all-NaN page for a frame without a particle or that failed.
``candidates.csv`` (+ ``.json``)
    every accepted candidate centre of every frame, ranked.
``crops.png``
    an overview plot (first frame with a particle, its crop, the track, the scores).
``crops.csv`` (+ ``crops.csv.json``)
    one row per frame (columns in :data:`holofit.tables.crop.CROP_UNITS`); written last, so
    its presence means the stage completed.

The tables and sidecars are written through :mod:`holofit.tables.crop`.

A frame that cannot be read or normalised gets status ``error`` and the run goes on: every
frame the movie file claims has a row, so a truncated movie's lost frames are ``error`` rows
naming the frame (and the sidecar's ``movie.problems`` says what is wrong with the file). Input
that makes the whole run meaningless (unreadable movie, background of another shape, a background
that is zero everywhere, an empty movie, every frame failing) raises :class:`CropError` and
leaves no output behind.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from holofit.batch.errors import BatchError
from holofit.batch.mainguard import refuse_while_worker_starts
from holofit.batch.runner import (
    BatchOptions,
    earlier_fingerprint,
    journal_path,
    partial_path,
    run_batch,
)
from holofit.batch.stage import fingerprint
from holofit.config import ConfigError, Instrument, load_instrument, resolve_config
from holofit.crop.centerfind import CenterFinder
from holofit.crop.cropping import crop_corner, extract_crop
from holofit.crop.detect import (
    DETECTED,
    DETECTION_COLUMNS,
    FOUND_COLUMNS,
    DetectConfig,
    detect_frame,
    found_from_json,
    no_payload,
    read_normalised,
    release,
)
from holofit.crop.errors import CropError
from holofit.crop.follow import FOLLOW_MODES, Follower, off_track
from holofit.crop.normalize import DEFAULT_MIN_BACKGROUND, Normalizer
from holofit.crop.reference import read_dark, read_reference_frame
from holofit.crop.track_crops import TrackPlan, link_detections, one_per_frame, track_rows
from holofit.crop.tracks import LinkOptions
from holofit.io.lock import output_lock
from holofit.io.movie import Movie, MovieError, open_movie
from holofit.io.tables import read_table, sidecar_path
from holofit.io.tiffstack import TiffStackWriter
from holofit.status import (
    CROP_EDGE,
    CROP_ERROR,
    CROP_NO_PARTICLE,
    CROP_OFF_TRACK,
    CROP_OK,
    CROP_STATUSES,
    FITTABLE_CROP_STATUSES,
)
from holofit.tables.crop import (
    CROP_COLUMNS,
    crop_extra,
    stack_header,
    write_candidates,
    write_crop_table,
)

__all__ = ["DEFAULT_CROP_SIZE", "MIN_CROP_SIZE", "CropResult", "check_crop_settings",
           "run_crop"]

#: smallest crop side, pixels
MIN_CROP_SIZE = 8
#: the paper's crop side, pixels
DEFAULT_CROP_SIZE = 140
#: every hologram linked into tracks (:mod:`holofit.crop.track_crops`; the default)
TRACKS = "tracks"
#: what ``follow`` may be: tracks, or one hologram per frame (:mod:`holofit.crop.follow`)
CROP_MODES = (*FOLLOW_MODES, TRACKS)


def check_crop_settings(
    frame_shape: tuple[int, int],
    size: int = DEFAULT_CROP_SIZE,
    follow: str = TRACKS,
    start: tuple[float, float] | None = None,
) -> None:
    """Refuse crop settings that cannot work on frames of ``frame_shape`` (rows, cols).

    The rules of :func:`run_crop`, also checked by ``holofit init`` before a run folder is
    written. Messages name the crop's options (``--size``, ``--follow``, ``--start``).

    Raises
    ------
    CropError
        A crop side below :data:`MIN_CROP_SIZE` or larger than the frame, an unknown follow
        mode, a start point without ``follow="nearest"`` or outside the frame.
    """
    rows, cols = int(frame_shape[0]), int(frame_shape[1])
    if size < MIN_CROP_SIZE:
        raise CropError(f"crop size (--size) must be at least {MIN_CROP_SIZE} pixels, got {size}")
    if size > min(rows, cols):
        raise CropError(f"crop size {size} does not fit in frames of {rows} x {cols} pixels: "
                        f"give a smaller --size (at most {min(rows, cols)})")
    if follow not in CROP_MODES:
        raise CropError(f"--follow {follow!r}: expected one of {', '.join(CROP_MODES)} "
                        "(tracks, the default: every particle in view, one track each)")
    if start is not None:
        if follow != "nearest":
            raise CropError("--start X,Y needs --follow nearest (the default, tracks, crops "
                            "every particle in view; strongest the strongest hologram of "
                            "every frame)")
        x, y = float(start[0]), float(start[1])
        if not (0 <= x < cols and 0 <= y < rows):
            raise CropError(f"--start {x:g},{y:g} lies outside the frames ({cols} columns x, "
                            f"{rows} rows y, pixels)")


@dataclass
class CropResult:
    """What :func:`run_crop` wrote.

    Attributes
    ----------
    out_dir : Path
        Output folder.
    crops : Path
        The crop stack (``crops.tif``).
    table : Path
        The per-frame table (``crops.csv``; sidecar ``crops.csv.json``).
    candidates : Path
        All candidates (``candidates.csv``).
    plot : Path or None
        Overview figure (``crops.png``), if made.
    frames : pandas.DataFrame
        The per-frame table.
    counts : dict
        Frames per status.
    problems : list of str
        What is wrong with the movie file as a whole (e.g. truncation), also in the sidecars.
    warnings : list of str
        What is doubtful about the result as a whole (e.g. the strongest hologram jumping to
        another particle), also in the sidecars.
    notes : list of str
        Why the result is empty (no hologram in any frame), also in the sidecars' settings.
    """

    out_dir: Path
    crops: Path
    table: Path
    candidates: Path
    plot: Path | None
    frames: pd.DataFrame
    counts: dict[str, int] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def _resolve_instrument(instrument: Instrument | str | Path) -> Instrument:
    if isinstance(instrument, Instrument):
        return instrument
    try:
        return load_instrument(resolve_config(instrument, "instruments"))
    except ConfigError as exc:
        raise CropError(str(exc)) from None


def _saturation(movie: Movie, instrument: Instrument) -> float | None:
    """Full-scale count of an integer movie (None for float data)."""
    if movie.dtype.kind not in "ui":
        return None
    type_max = np.iinfo(movie.dtype).max
    return float(min(2**instrument.bit_depth - 1, type_max))


def _check_full_scale(movie: Movie, saturation: float, instrument: Instrument) -> None:
    """The movie's first readable frame within the instrument's full scale, else CropError.

    Counts above ``2**bit_depth - 1`` mean the instrument's ``bit_depth`` is not the camera's
    (a 16-bit movie with an 8-bit instrument): masking them as saturated would leave nothing
    of the hologram, every frame ``no_particle``. Later frames are checked as they are read
    (:func:`holofit.crop.detect.detect`).
    """
    for k in range(min(len(movie), 5)):
        try:
            frame = movie[k]
        except MovieError:
            continue
        peak = float(np.max(frame))
        if peak > saturation:
            raise CropError(
                f"{movie.path}: frame {k} has counts up to {peak:g}, which exceed the full "
                f"scale {saturation:g} of instrument {instrument.path or instrument.name} "
                f"({_bit_depth_advice(movie, peak, instrument)})"
            )
        return


def _bit_depth_advice(movie: Movie, peak: float, instrument: Instrument) -> str:
    """Why counts exceed the full scale, and what to set."""
    bits = movie.dtype.itemsize * 8
    fits = next((b for b in (10, 12, 14, 16, 32) if b <= bits and 2**b - 1 >= peak), bits)
    return (
        f"bit_depth = {instrument.bit_depth}, full scale 2^{instrument.bit_depth} - 1; the "
        f"movie's pixels are {bits}-bit integers ({movie.dtype}): set bit_depth in the "
        f"instrument config to the camera's ({fits} or more holds these counts), or do not "
        "mask saturated pixels (--keep-saturated)"
    )


References = str | Path | Sequence[str | Path]


def _paths(refs: References | None) -> list[Path]:
    if refs is None:
        return []
    return [Path(refs)] if isinstance(refs, str | Path) else [Path(r) for r in refs]


def _prepare(
    movie: Movie,
    backgrounds: list[Path],
    dark: References | float | None,
    min_background: float,
    saturation: float | None,
    instrument_label: str,
) -> tuple[Normalizer, dict[str, Any]]:
    background = read_reference_frame(backgrounds, "background")
    named = ", ".join(map(str, backgrounds))
    if background.shape != tuple(movie.frame_shape):
        raise CropError(
            f"{named}: background has shape {background.shape}, but the frames of "
            f"{movie.path} have shape {tuple(movie.frame_shape)}"
        )
    if saturation is not None and float(background.max()) > saturation:
        raise CropError(
            f"{named}: background counts up to {background.max():g} exceed the full "
            f"scale {saturation:g} of the bit depth of instrument {instrument_label}: correct "
            "bit_depth in the instrument config, or do not mask saturated pixels "
            "(--keep-saturated)"
        )
    dark_value = read_dark(dark)
    dark_files = [] if isinstance(dark, int | float) else _paths(dark)
    if isinstance(dark_value, np.ndarray) and dark_value.shape != background.shape:
        raise CropError(
            f"{', '.join(map(str, dark_files))}: dark frame has shape {dark_value.shape}, the "
            f"background {background.shape}"
        )
    try:
        normalizer = Normalizer(
            background, dark_value, min_background=min_background, saturation=saturation
        )
    except ValueError as exc:
        where = ", ".join(map(str, dark_files)) if "dark" in str(exc) and dark_files else named
        raise CropError(f"{where}: {exc}") from None
    info = {
        "formula": "(I - dark) / (I_bg - dark) * mean(I_bg - dark) / mean(I - dark)",
        "background": [str(p) for p in backgrounds],
        "background_combined": "per-pixel median of all frames of all background files"
        if len(backgrounds) > 1
        else "the frame, or the per-pixel median of the stack",
        "dark": None
        if dark is None
        else (float(dark) if isinstance(dark, int | float) else [str(p) for p in dark_files]),
        "min_background_fraction": min_background,
        "background_mean_counts": normalizer.background_mean,
        "n_masked_background_pixels": normalizer.n_masked_background,
        "saturation_counts": saturation,
    }
    return normalizer, info


def _remove_stale(paths: list[Path]) -> None:
    for p in paths:
        with contextlib.suppress(FileNotFoundError):
            p.unlink()


def _follower(follow: str, start: tuple[float, float] | None, max_jump_px: float | None,
              size: int) -> Follower:
    """The single-particle follower (tracks mode: the strongest hologram of the preview)."""
    return Follower(follow if follow != TRACKS else "strongest", start,
                    max_jump_px if max_jump_px is not None else size / 4.0)


def _link_options(follow: str, link: LinkOptions | None, particle: int | None) -> LinkOptions:
    """The linking options; refused with a single-particle ``follow``."""
    if follow != TRACKS and (link is not None or particle is not None):
        raise CropError("--particle and the linking options (--search-range-um, --memory, "
                        "--min-track-length, --max-particles) need --follow tracks")
    return link or LinkOptions()


def _settings(size: int, follow: str, start: tuple[float, float] | None, follower: Follower,
              finder: CenterFinder, norm_info: dict[str, Any], mask_saturated: bool,
              link: LinkOptions, particle: int | None) -> dict[str, Any]:
    """The crop's settings as its sidecar records them."""
    settings = {"size_px": size, "follow": follow,
                "start_px": list(start) if start is not None else None,
                "max_jump_px": follower.max_jump_px, "finder": finder.as_dict(),
                "normalization": {**norm_info, "mask_saturated": mask_saturated}}
    if follow == TRACKS:
        settings["tracks"] = {**link.as_dict(), "particle": particle}
    return settings


def run_crop(
    movie_path: str | Path, background_path: References | None,
    instrument: Instrument | str | Path, out_dir: str | Path, *, normalized: bool = False,
    dark: References | float | None = None, size: int = DEFAULT_CROP_SIZE,
    follow: str = TRACKS, start: tuple[float, float] | None = None,
    max_jump_px: float | None = None, finder: CenterFinder | None = None,
    link: LinkOptions | None = None, particle: int | None = None,
    min_background: float = DEFAULT_MIN_BACKGROUND, mask_saturated: bool = True,
    plot: bool = True, progress: Callable[[int], Any] | None = None,
    batch: BatchOptions | None = None,
) -> CropResult:
    """Normalise a raw movie, find the hologram centre of every frame and crop around it.

    Parameters
    ----------
    movie_path : str or Path
        Raw movie: multi-page (or OME-) TIFF, or a folder of TIFF frames; 8 or 16 bit; or a
        video, a folder of PNG frames, an HDF5 dataset (:class:`holofit.io.movie.Movie`).
    background_path : str, Path, a sequence of them, or None
        Background: one frame, or a stack / folder, or several of these; all their frames are
        reduced by the per-pixel median. None with ``normalized``.
    instrument : Instrument, str or Path
        Instrument config (object, file, or name in ``configs/instruments``); its pixel size
        converts centres to um, its bit depth gives the saturation level.
    out_dir : str or Path
        Output folder (created).
    normalized : bool
        The movie is background-divided already (as many public data sets are, often stored as
        scaled integers): each frame is only divided by its mean (the paper's normalisation
        with a flat background); saturated pixels are still masked.
    dark : str, Path, sequence of them, or float, optional
        Dark level: counts (``--dark-count``) or dark frame / stack files (their median).
    size : int
        Crop side N, pixels (default 140, the paper's).
    follow, start, max_jump_px
        Which holograms to crop: ``"tracks"`` (the default) every one, linked into tracks
        (:mod:`holofit.crop.track_crops`), or one per frame, ``"strongest"`` or ``"nearest"``
        (:mod:`holofit.crop.follow`); ``(x_px, y_px)`` of the particle in the first frame and
        the largest move between frames (default ``size / 4``) for ``"nearest"``.
    link, particle
        ``"tracks"`` only: how holograms are linked (:class:`holofit.crop.tracks.LinkOptions`),
        and the one track to keep (its rows get ``particle`` 0).
    finder, min_background
        Centre-finder settings (default: vote radius ``size / 2``); background pixels at or
        below this fraction of the median background are masked.
    mask_saturated, plot, progress
        Mask (NaN) pixels at the camera's full-scale count; write ``crops.png``; called with
        1 after each frame is cropped.
    batch : BatchOptions, optional
        Where frames are searched (:mod:`holofit.crop.detect`; default: in this process).

    Returns
    -------
    CropResult

    Raises
    ------
    CropError
        Unusable input (the message names the file, and the frame where one is at fault).
    """
    refuse_while_worker_starts("run_crop")
    inst, size = _resolve_instrument(instrument), int(size)
    backgrounds = _check_arguments(size, background_path, normalized, dark)
    finder = finder or CenterFinder(radius_px=size / 2.0)
    follower = _follower(follow, start, max_jump_px, size)
    link = _link_options(follow, link, particle)
    with _open(movie_path) as movie:
        _check_for_movie(movie, movie_path, size, follow, start)
        saturation = _saturation(movie, inst) if mask_saturated else None
        normalizer, norm_info = _normalizer(movie, normalized, backgrounds, dark,
                                            min_background, saturation, inst)
        settings = _settings(size, follow, start, follower, finder, norm_info, mask_saturated,
                             link, particle)
        inputs = [movie_path, *backgrounds, *([] if isinstance(dark, int | float)
                                             else _paths(dark))]
        detect = _detect_config(movie, movie_path, backgrounds, dark, normalized,
                                min_background, saturation, finder)
        job = _CropJob(movie, movie_path, Path(out_dir), normalizer, detect, follower, size,
                       inst, settings, inputs, plot, progress, batch, link, particle)
        return job.run()


@dataclass
class _CropJob:
    """One run of the crop stage, its inputs checked: crop every frame, write the folder."""

    movie: Movie
    movie_path: str | Path
    out: Path
    normalizer: Normalizer
    detect: DetectConfig
    follower: Follower
    size: int
    inst: Instrument
    settings: dict[str, Any]
    inputs: list[str | Path]
    plot: bool
    progress: Callable[[int], Any] | None
    batch: BatchOptions | None
    link: LinkOptions
    particle: int | None

    def run(self) -> CropResult:
        """Search every frame (a batch: parallel, resumable), then crop in frame order; the
        detections are removed once the crop folder is complete (or failed as a whole)."""
        with output_lock(self.out, stage="crop"):
            files = _DetectionFiles(self.out / DETECTIONS)
            try:
                result = self.crop(files)
            except CropError:
                files.remove()
                raise
            files.remove()
        return result

    def crop(self, files: _DetectionFiles) -> CropResult:
        """The search, the sequential step and the outputs (:mod:`holofit.tables.crop`); the
        stack's temporary file is there from the start (a killed run leaves only it, and
        its next writer removes it)."""
        movie, size, paths = self.movie, self.size, _CropPaths(self.out)
        with TiffStackWriter(paths.stack, stack_header(size, len(movie))) as writer:
            detections = files.run(self.detect, len(movie), self.movie_path, self.batch)
            linking = self.settings["follow"] == TRACKS and (
                self.particle not in (None, 0) or not one_per_frame(detections))
            if self.settings["follow"] == TRACKS:
                self.settings["tracks"]["linked"] = linking
            if linking:
                plan = link_detections(detections, len(movie), self.inst.pixel_size_um,
                                       self.link, size, self.particle)
                rows, candidates, preview = _crop_tracks(
                    movie, self.normalizer, detections, plan, size, self.inst.pixel_size_um,
                    writer, self.progress)
                warnings = list(plan.warnings)
            else:
                rows, candidates, preview = _crop_frames(
                    movie, self.normalizer, detections, self.follower, size,
                    self.inst.pixel_size_um, writer, self.progress)
                warnings = (_mark_off_track(rows, self.follower.max_jump_px)
                            if self.settings["follow"] != "nearest" else [])
                if self.settings["follow"] == TRACKS and not any(
                        int(d.get("n_found") or 0) for d in detections.values()):
                    self.settings["tracks"]["note"] = (
                        "no hologram found in any frame: no track, every frame no_particle (is "
                        "it the right movie and background? --min-score and --vote-radius set "
                        "what is found)")
            frames = _frame_table(rows, self.movie_path)
            paths.remove_stale()  # a rerun must not leave an old table beside the new stack
        counts = {s: int((frames["status"] == s).sum()) for s in CROP_STATUSES}
        cand_table = write_candidates(paths.candidates, candidates, self.inst.as_dict(),
                                      self.inputs, self.settings)
        made_plot = None
        if self.plot and preview is not None:
            from holofit.crop.plot import plot_overview

            made_plot = plot_overview(paths.plot, preview, frames, cand_table, size)
        extra = crop_extra(self.settings, _movie_info(movie), paths.stack, paths.table,
                           len(frames), size, counts, warnings)
        write_crop_table(paths.table, paths.stack, frames, self.inst.as_dict(), self.inputs,
                         extra)
        note = self.settings.get("tracks", {}).get("note")
        return CropResult(self.out, paths.stack, paths.table, paths.candidates, made_plot,
                          frames, counts, list(movie.problems), warnings,
                          [note] if note else [])


#: the candidates of every frame searched so far (removed when the crop folder is complete)
DETECTIONS = "detections.csv"


class _DetectionFiles:
    """``detections.csv`` (+ sidecar, journal, partial table): the resumable search."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def run(self, config: DetectConfig, n_frames: int, movie_path: str | Path,
            batch: BatchOptions | None) -> dict[int, dict[str, Any]]:
        """Search the frames not searched yet by an earlier run with the same movie and
        settings (another run's results are discarded); every frame's row."""
        opts = batch or BatchOptions(workers=0, progress=False)
        if earlier_fingerprint(self.path) not in (None, config.key):
            opts = replace(opts, overwrite=True)
        meta = {"kind": "crop detections (candidate centres of every frame searched; "
                        "removed when the crop folder is complete)",
                "candidates": f"JSON list of [{', '.join(FOUND_COLUMNS)}] per candidate"}
        try:
            run_batch(detect_frame, config, range(n_frames), no_payload, self.path,
                      DETECTION_COLUMNS, fingerprint=config.key, meta=meta, options=opts,
                      desc="crop")
        except BatchError as exc:
            self.remove()
            raise CropError(f"{movie_path}: {exc}") from None
        finally:
            release()
        table = read_table(self.path)
        return {int(r["frame"]): r for r in table.to_dict(orient="records")}

    def remove(self) -> None:
        _remove_stale([self.path, sidecar_path(self.path), journal_path(self.path),
                       partial_path(self.path), sidecar_path(partial_path(self.path))])


def _file_identity(path: str | Path) -> list[Any]:
    """Name, size and modification time of a file or folder (what a rerun compares)."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError:
        return [str(p)]
    return [str(p), st.st_size, st.st_mtime_ns]


def _detect_config(movie: Movie, movie_path: str | Path, backgrounds: list[Path],
                   dark: References | float | None, normalized: bool, min_background: float,
                   saturation: float | None, finder: CenterFinder) -> DetectConfig:
    """What a worker needs to search frames, and its fingerprint (the movie's and the
    reference files' names, sizes and times with the settings)."""
    dark_files = () if dark is None or isinstance(dark, int | float) else tuple(
        str(p) for p in _paths(dark))
    dark_spec = float(dark) if isinstance(dark, int | float) else (dark_files or None)
    config = DetectConfig(str(movie_path), tuple(str(p) for p in backgrounds), dark_spec,
                          min_background, saturation, finder)
    key = fingerprint({
        "config": asdict(config), "normalized": normalized,
        "movie": [*_file_identity(movie_path), len(movie), list(movie.frame_shape),
                  str(movie.dtype)],
        "references": [_file_identity(p) for p in (*config.backgrounds, *dark_files)]})
    return replace(config, key=key)


def _open(movie_path: str | Path) -> Movie:
    """The movie; CropError naming the file if it cannot be opened."""
    try:
        return open_movie(movie_path)
    except MovieError as exc:
        raise CropError(str(exc)) from None


def _check_for_movie(movie: Movie, movie_path: str | Path, size: int, follow: str,
                     start: tuple[float, float] | None) -> None:
    """:func:`check_crop_settings` for the movie's frames; the message names the movie."""
    try:
        check_crop_settings(tuple(movie.frame_shape), size, follow, start)
    except CropError as exc:
        raise CropError(f"{movie_path}: {exc}") from None


def _check_arguments(size: int, background_path: References | None, normalized: bool,
                     dark: References | float | None) -> list[Path]:
    """Refuse a crop too small and a background given or missing against ``normalized``;
    the background files."""
    if size < MIN_CROP_SIZE:
        raise CropError(f"crop size must be at least {MIN_CROP_SIZE} pixels, got {size}")
    backgrounds = _paths(background_path)
    if normalized and (backgrounds or dark is not None):
        raise CropError(
            "a normalised movie takes no background and no dark level: give either a "
            "background or normalized=True (--normalized)"
        )
    if not normalized and not backgrounds:
        raise CropError(
            "no background given: crop needs the background of the raw movie, or "
            "normalized=True (--normalized) for a movie that is normalised already"
        )
    return backgrounds


def _normalizer(movie: Movie, normalized: bool, backgrounds: list[Path],
                dark: References | float | None, min_background: float,
                saturation: float | None, inst: Instrument) -> tuple[Normalizer, dict[str, Any]]:
    """The frames' normaliser and its record; the movie's full scale checked."""
    if normalized:
        normalizer = Normalizer(np.ones(movie.frame_shape), saturation=saturation)
        norm_info: dict[str, Any] = {
            "formula": "I / mean(I): the movie is background-divided already "
            "(--normalized; the paper's normalisation with a flat background)",
            "background": None,
            "dark": None,
            "saturation_counts": saturation,
        }
    else:
        normalizer, norm_info = _prepare(
            movie, backgrounds, dark, min_background, saturation, inst.path or inst.name
        )
    if saturation is not None:
        _check_full_scale(movie, saturation, inst)
    return normalizer, norm_info


class _CropPaths:
    """The files of a crop folder."""

    def __init__(self, out: Path) -> None:
        self.stack = out / "crops.tif"
        self.table = out / "crops.csv"
        self.candidates = out / "candidates.csv"
        self.plot = out / "crops.png"

    def remove_stale(self) -> None:
        """Remove the outputs of an earlier run but the stack (being written)."""
        stale = (self.table, self.candidates, self.stack)
        _remove_stale([*stale[:2], *map(sidecar_path, stale), self.plot])


def _frame_table(rows: list[dict[str, Any]], movie_path: str | Path) -> pd.DataFrame:
    """The crop table of ``rows``; CropError if every frame failed."""
    frames = pd.DataFrame(rows, columns=list(CROP_COLUMNS))
    for column in ("corner_row", "corner_col"):
        frames[column] = frames[column].astype("Int64")
    n_error = int((frames["status"] == CROP_ERROR).sum())
    if n_error == len(frames):
        raise CropError(
            f"{movie_path}: every frame failed; first error: {frames['message'].iat[0]}"
        )
    return frames


def _movie_info(movie: Movie) -> dict[str, Any]:
    """What the sidecars record of the movie file."""
    return {
        "frames": len(movie),
        "frame_shape": list(movie.frame_shape),
        "dtype": str(movie.dtype),
        "problems": list(movie.problems),
        "reader_notes": list(movie.notes),
    }


def _frame_list(frames: list[int], most: int = 8) -> str:
    shown = ", ".join(map(str, frames[:most]))
    return shown + (f", ... ({len(frames)} in all)" if len(frames) > most else "")


def _mark_off_track(rows: list[dict[str, Any]], max_jump_px: float) -> list[str]:
    """``follow="strongest"``: mark the frames whose centre left the main track
    (:func:`holofit.crop.follow.off_track`) while another hologram was in view ``off_track``,
    in place; the warning, if any.

    A frame off the main track with a single hologram found is kept as it is (a set of
    unrelated holograms, one particle per image, jumps too; so does a movie with false
    detections), but the warning names it."""
    fitted = [r["status"] in FITTABLE_CROP_STATUSES for r in rows]
    x = [r["x_px"] if f else math.nan for r, f in zip(rows, fitted, strict=True)]
    y = [r["y_px"] if f else math.nan for r, f in zip(rows, fitted, strict=True)]
    tracks = off_track(x, y, max_jump_px)
    if not tracks.jumps:
        return []
    away = [int(k) for k in np.flatnonzero(tracks.off)]
    off = [k for k in away if int(rows[k]["n_candidates"]) >= 2]
    alone = [k for k in away if k not in off]
    for k in off:
        row = rows[k]
        row["status"] = CROP_OFF_TRACK
        row["message"] = (f"centre ({row['x_px']:.0f}, {row['y_px']:.0f}) px is off the movie's "
                          f"main track (a jump of more than {max_jump_px:g} px) while another "
                          "hologram is in view: likely another particle; not fitted")
    main = int(np.flatnonzero(tracks.label == 0)[0])
    r0 = rows[main]
    text = (f"the strongest hologram jumped by more than {max_jump_px:g} px (the max jump) in "
            f"frame(s) {_frame_list(tracks.jumps)}: {tracks.n_tracks} tracks")
    if off:
        text += (f", likely another particle in view; {len(off)} frame(s) off the main track "
                 f"with another hologram in view are marked off_track and not fitted "
                 f"({_frame_list(off)})")
    if alone:
        text += (f"; {len(alone)} frame(s) off the main track with a single hologram found are "
                 f"kept ({_frame_list(alone)}): one particle cannot move that far between "
                 "frames, so in a movie these are false detections or another particle")
    text += (f". To follow the main track's particle: --follow nearest --start "
             f"{r0['x_px']:.0f},{r0['y_px']:.0f} (where it is in frame {main})")
    return [text]


def _blank_row(k: int) -> dict[str, Any]:
    """Frame ``k``'s row before anything is known of it (status ``error``)."""
    return {
        "particle": 0,
        "frame": k,
        "status": CROP_ERROR,
        "message": "",
        "x_px": math.nan,
        "y_px": math.nan,
        "x_um": math.nan,
        "y_um": math.nan,
        "corner_row": pd.NA,
        "corner_col": pd.NA,
        "score": math.nan,
        "alignment": math.nan,
        "symmetry": math.nan,
        "refinement": "",
        "n_candidates": 0,
        "n_masked": 0,
        "neighbour": -1,
        "neighbour_px": math.inf,
        "overlap": False,
    }


def _crop_frames(
    movie: Movie,
    normalizer: Normalizer,
    detections: dict[int, dict[str, Any]],
    follower: Follower,
    size: int,
    pixel_size_um: float,
    writer: TiffStackWriter,
    progress: Callable[[int], Any] | None,
) -> tuple[list[dict[str, Any]], list[tuple[Any, ...]], dict[str, Any] | None]:
    """The sequential step, in frame order: choose each frame's candidate (``follow``), crop
    it (the frame read again) and write the page; one frame in memory at a time."""
    blank = np.full((size, size), np.nan, dtype=np.float32)
    rows: list[dict[str, Any]] = []
    candidates: list[tuple[Any, ...]] = []
    preview: dict[str, Any] | None = None
    for k in range(len(movie)):
        row = _blank_row(k)
        page: NDArray = blank
        det = detections.get(k, {"status": CROP_ERROR, "message": "not searched"})
        if det["status"] != DETECTED:
            row["message"] = str(det.get("message") or "")
        else:
            found = found_from_json(det["candidates"])
            choice = follower.choose(found)
            row["n_candidates"] = len(found)
            for rank, cand in enumerate(found.itertuples(index=False)):
                candidates.append(
                    (k, rank, cand.x_px, cand.y_px, cand.score, cand.alignment,
                     cand.symmetry, cand.refinement, rank == choice.index,
                     0 if rank == choice.index else -1)
                )  # fmt: skip
            if choice.index is None:
                row["status"], row["message"] = CROP_NO_PARTICLE, choice.message
            else:
                image, mask = read_normalised(movie, k, normalizer)
                page = _crop_chosen(row, found.iloc[choice.index], image, mask, size,
                                    pixel_size_um)
                if preview is None:
                    preview = {"frame": k, "image": image,
                               "corner": (row["corner_row"], row["corner_col"])}
        writer.write(page)
        rows.append(row)
        if progress is not None:
            progress(1)
    return rows, candidates, preview


def _crop_tracks(
    movie: Movie,
    normalizer: Normalizer,
    detections: dict[int, dict[str, Any]],
    plan: TrackPlan,
    size: int,
    pixel_size_um: float,
    writer: TiffStackWriter,
    progress: Callable[[int], Any] | None,
) -> tuple[list[dict[str, Any]], list[tuple[Any, ...]], dict[str, Any] | None]:
    """The tracks mode's sequential step, in frame order: each frame read once, one crop per
    track with a row in it (:func:`holofit.crop.track_crops.track_rows`), pages in the table's
    order (frame, then particle)."""
    blank = np.full((size, size), np.nan, dtype=np.float32)
    rows: list[dict[str, Any]] = []
    candidates: list[tuple[Any, ...]] = []
    preview: dict[str, Any] | None = None
    for k in range(len(movie)):
        det = detections.get(k, {"status": CROP_ERROR, "message": "not searched"})
        found = (found_from_json(det["candidates"]) if det["status"] == DETECTED
                 else pd.DataFrame())
        here = track_rows(plan, k, size)
        chosen = {int(d["rank"]): p for p, d in here if d is not None}
        for rank, cand in enumerate(found.itertuples(index=False)):
            candidates.append((k, rank, cand.x_px, cand.y_px, cand.score, cand.alignment,
                               cand.symmetry, cand.refinement, rank in chosen,
                               chosen.get(rank, -1)))
        image = mask = None
        for p, linked in here:
            row = _blank_row(k)
            row["particle"] = p
            page: NDArray = blank
            row["n_candidates"] = len(found)
            if det["status"] != DETECTED:
                row["message"] = str(det.get("message") or "")
            elif linked is None:
                row["status"] = CROP_NO_PARTICLE
                row["message"] = (f"track {p}: no hologram found in this frame"
                                  if len(plan.spans) > 1 or len(plan.linked)
                                  else "no hologram found")
            else:
                if image is None:
                    image, mask = read_normalised(movie, k, normalizer)
                page = _crop_chosen(row, found.iloc[int(linked["rank"])], image, mask, size,
                                    pixel_size_um)
                row.update(neighbour=int(linked["neighbour"]),
                           neighbour_px=float(linked["neighbour_px"]),
                           overlap=bool(linked["overlap"]))
                if row["overlap"]:
                    row["message"] = (f"overlaps track {row['neighbour']} "
                                      f"({row['neighbour_px']:.0f} px away)")
                if preview is None:
                    preview = {"frame": k, "image": image,
                               "corner": (row["corner_row"], row["corner_col"])}
            writer.write(page)
            rows.append(row)
        if progress is not None:
            progress(1)
    return rows, candidates, preview


def _crop_chosen(row: dict[str, Any], best: pd.Series, image: NDArray, mask: NDArray,
                 size: int, pixel_size_um: float) -> NDArray:
    """Crop around the chosen candidate ``best``: fill in ``row``; the crop."""
    x, y = float(best["x_px"]), float(best["y_px"])
    corner_row, corner_col, shifted = crop_corner(x, y, size, image.shape)
    row.update(
        status=CROP_EDGE if shifted else CROP_OK,
        message="particle near the frame edge: crop shifted inside the frame"
        if shifted
        else "",
        x_px=x,
        y_px=y,
        x_um=x * pixel_size_um,
        y_um=y * pixel_size_um,
        corner_row=corner_row,
        corner_col=corner_col,
        score=float(best["score"]),
        alignment=float(best["alignment"]),
        symmetry=float(best["symmetry"]),
        refinement=str(best["refinement"]),
        n_masked=int(
            mask[corner_row : corner_row + size, corner_col : corner_col + size].sum()
        ),
    )
    return extract_crop(image, (corner_row, corner_col), size)
