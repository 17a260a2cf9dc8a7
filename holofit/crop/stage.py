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

The tables and sidecars are written through :mod:`holofit.tables.crop`; the search runs
through the stage skeleton and the crop table is published by the runner's publish step
(:mod:`holofit.crop.job`). The settings are a :class:`~holofit.crop.settings.CropConfig`
(:mod:`holofit.crop.settings`), the inputs are checked in :mod:`holofit.crop.inputs`.

A frame that cannot be read or normalised gets status ``error`` and the run goes on: every
frame the movie file claims has a row, so a truncated movie's lost frames are ``error`` rows
naming the frame (and the sidecar's ``movie.problems`` says what is wrong with the file). Input
that makes the whole run meaningless (unreadable movie, background of another shape, a background
that is zero everywhere, an empty movie, every frame failing) raises :class:`CropError` and
leaves no output behind.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from holofit.batch.mainguard import refuse_while_worker_starts
from holofit.batch.options import BatchSettings
from holofit.config import Instrument
from holofit.crop.inputs import (
    check_for_movie,
    detect_config,
    open_checked,
    prepare_normalizer,
    resolve_instrument,
    saturation,
)
from holofit.crop.job import CropInputs, CropJob, CropResult
from holofit.crop.settings import (
    CROP_MODES,
    DEFAULT_CROP_SIZE,
    MIN_CROP_SIZE,
    TRACKS,
    CropConfig,
    References,
    check_arguments,
    check_crop_settings,
    follower,
    link_options,
    settings_record,
    sized_for_movie,
)

__all__ = ["CROP_MODES", "DEFAULT_CROP_SIZE", "MIN_CROP_SIZE", "TRACKS", "CropConfig",
           "CropResult", "check_crop_settings", "run_crop"]


def run_crop(
    movie_path: str | Path,
    background_path: References | None,
    instrument: Instrument | str | Path,
    out_dir: str | Path,
    config: CropConfig | None = None,
    *,
    batch: BatchSettings | None = None,
    progress: Callable[[int], Any] | None = None,
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
        converts centres to um, its bit depth gives the saturation level (or the data do: a
        pile-up of pixels at the movie's top count below it, :mod:`holofit.crop.saturation`),
        its optics the fringe limits of the centre finder (:mod:`holofit.crop.profile`).
    out_dir : str or Path
        Output folder (created).
    config : CropConfig, optional
        How to normalise, search and crop (:class:`~holofit.crop.settings.CropConfig`: crop
        side, which holograms to follow, the centre finder, the dark level, ...; default:
        its defaults).
    batch : BatchSettings, optional
        Where frames are searched (:mod:`holofit.crop.detect`; default: in this process).
    progress : callable, optional
        Called with 1 after each frame is cropped.

    Returns
    -------
    CropResult

    Raises
    ------
    CropError
        Unusable input (the message names the file, and the frame where one is at fault).
    """
    cfg = config or CropConfig()
    refuse_while_worker_starts("run_crop")
    inst = resolve_instrument(instrument)
    backgrounds = check_arguments(cfg, background_path)
    cfg.finder_for_size(inst)
    follower(cfg)  # the finder's and follower's own checks, before the movie is opened
    link = link_options(cfg)
    with open_checked(movie_path) as movie:
        check_for_movie(movie, movie_path, cfg)
        full = saturation(movie, inst) if cfg.mask_saturated else None
        normalizer, norm_info, warnings = prepare_normalizer(movie, backgrounds, cfg, full, inst)
        # the crop side and vote radius not given follow the movie's holograms
        cfg, size_choice = sized_for_movie(cfg, movie, normalizer, inst)
        finder = cfg.finder_for_size(inst)
        chosen = follower(cfg)
        record = {**settings_record(cfg, chosen, finder, norm_info, link),
                  "size_choice": size_choice}
        given = CropInputs(movie, movie_path, normalizer,
                           detect_config(movie, movie_path, backgrounds, cfg, normalizer, finder),
                           inst, record, [movie_path, *backgrounds, *cfg.dark_files()], warnings)
        return CropJob(given, cfg, chosen, link, Path(out_dir), batch, progress).run()
