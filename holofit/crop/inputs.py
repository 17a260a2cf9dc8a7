"""The crop stage's inputs: the instrument, the movie, the reference frames and the normaliser
made of them, each checked before any frame is searched, and the detection config a worker
rebuilds them from.

Input that makes the whole run meaningless (an unreadable movie, a background of another
shape or over the full scale, counts that exceed the instrument's bit depth) raises
:class:`~holofit.crop.errors.CropError` naming the file, before anything is written.
"""

from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from holofit.batch.stage import fingerprint
from holofit.config import ConfigError, Instrument, load_instrument, resolve_config
from holofit.crop.centerfind import CenterFinder
from holofit.crop.detect import DetectConfig
from holofit.crop.errors import CropError
from holofit.crop.normalize import Normalizer
from holofit.crop.reference import read_dark, read_reference_frame
from holofit.crop.saturation import find_pile_up
from holofit.crop.settings import CropConfig, check_crop_settings
from holofit.io.movie import Movie, MovieError, open_movie

__all__ = ["check_for_movie", "detect_config", "movie_info", "open_checked", "prepare_normalizer",
           "resolve_instrument", "saturation"]


def resolve_instrument(instrument: Instrument | str | Path) -> Instrument:
    """The instrument (object, file, or name in ``configs/instruments``); CropError if its
    config cannot be read."""
    if isinstance(instrument, Instrument):
        return instrument
    try:
        return load_instrument(resolve_config(instrument, "instruments"))
    except ConfigError as exc:
        raise CropError(str(exc)) from None


def open_checked(movie_path: str | Path) -> Movie:
    """The movie; CropError naming the file if it cannot be opened."""
    try:
        return open_movie(movie_path)
    except MovieError as exc:
        raise CropError(str(exc)) from None


def check_for_movie(movie: Movie, movie_path: str | Path, config: CropConfig) -> None:
    """:func:`~holofit.crop.settings.check_crop_settings` for the movie's frames; the message
    names the movie."""
    try:
        check_crop_settings(tuple(movie.frame_shape), config.size, config.follow, config.start)
    except CropError as exc:
        raise CropError(f"{movie_path}: {exc}") from None


def saturation(movie: Movie, instrument: Instrument) -> float | None:
    """Full-scale count of an integer movie (None for float data)."""
    if movie.dtype.kind not in "ui":
        return None
    type_max = np.iinfo(movie.dtype).max
    return float(min(2**instrument.bit_depth - 1, type_max))


def _check_full_scale(movie: Movie, full: float, instrument: Instrument) -> None:
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
        if peak > full:
            raise CropError(
                f"{movie.path}: frame {k} has counts up to {peak:g}, which exceed the full "
                f"scale {full:g} of instrument {instrument.path or instrument.name} "
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


def _prepare(movie: Movie, backgrounds: list[Path], config: CropConfig, full: float | None,
             level: float | None, instrument_label: str) -> tuple[Normalizer, dict[str, Any]]:
    """The normaliser of a raw movie from its background (and dark) files, and its record."""
    dark, min_background = config.dark, config.min_background
    background = read_reference_frame(backgrounds, "background")
    named = ", ".join(map(str, backgrounds))
    if background.shape != tuple(movie.frame_shape):
        raise CropError(
            f"{named}: background has shape {background.shape}, but the frames of "
            f"{movie.path} have shape {tuple(movie.frame_shape)}"
        )
    if full is not None and float(background.max()) > full:
        raise CropError(
            f"{named}: background counts up to {background.max():g} exceed the full "
            f"scale {full:g} of the bit depth of instrument {instrument_label}: correct "
            "bit_depth in the instrument config, or do not mask saturated pixels "
            "(--keep-saturated)"
        )
    dark_value = read_dark(dark)
    dark_files = config.dark_files()
    if isinstance(dark_value, np.ndarray) and dark_value.shape != background.shape:
        raise CropError(
            f"{', '.join(map(str, dark_files))}: dark frame has shape {dark_value.shape}, the "
            f"background {background.shape}"
        )
    try:
        normalizer = Normalizer(background, dark_value, min_background=min_background,
                                saturation=level, full_scale=full)
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
        "saturation_counts": level,
    }
    return normalizer, info


def prepare_normalizer(movie: Movie, backgrounds: list[Path], config: CropConfig,
                       full: float | None, inst: Instrument
                       ) -> tuple[Normalizer, dict[str, Any], list[str]]:
    """The frames' normaliser, its record (the sidecar's ``normalization``) and warnings;
    the movie's full scale checked, and a saturation below it found in the data
    (:mod:`holofit.crop.saturation`: the top count, where pixels pile up) masked too."""
    pile = find_pile_up(movie, full) if full is not None else None
    level = pile.level if pile is not None else full
    warnings = [pile.describe(full, inst.bit_depth)] if pile is not None and full else []
    if config.normalized:
        normalizer = Normalizer(np.ones(movie.frame_shape), saturation=level, full_scale=full)
        norm_info: dict[str, Any] = {
            "formula": "I / mean(I): the movie is background-divided already "
            "(--normalized; the paper's normalisation with a flat background)",
            "background": None,
            "dark": None,
            "saturation_counts": level,
        }
    else:
        normalizer, norm_info = _prepare(movie, backgrounds, config, full, level,
                                         inst.path or inst.name)
    norm_info["full_scale_counts"] = full
    norm_info["saturation_source"] = (
        None if level is None else
        f"data: {pile.pixels_per_frame:.0f} pixels a frame at count {pile.level:g} in "
        f"{pile.frames} frames looked at" if pile is not None else
        f"bit_depth {inst.bit_depth}")
    if full is not None:
        _check_full_scale(movie, full, inst)
    return normalizer, norm_info, warnings


def _file_identity(path: str | Path) -> list[Any]:
    """Name, size and modification time of a file or folder (what a rerun compares)."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError:
        return [str(p)]
    return [str(p), st.st_size, st.st_mtime_ns]


def detect_config(movie: Movie, movie_path: str | Path, backgrounds: list[Path],
                  config: CropConfig, normalizer: Normalizer,
                  finder: CenterFinder) -> DetectConfig:
    """What a worker needs to search frames, and its fingerprint (the movie's and the
    reference files' names, sizes and times with the settings): a rerun reuses the frames
    searched only if none of them changed."""
    dark = config.dark
    dark_files = tuple(str(p) for p in config.dark_files())
    dark_spec = float(dark) if isinstance(dark, int | float) else (dark_files or None)
    detect = DetectConfig(str(movie_path), tuple(str(p) for p in backgrounds), dark_spec,
                          config.min_background, normalizer.saturation, finder,
                          full_scale=normalizer.full_scale)
    key = fingerprint({
        "config": asdict(detect), "normalized": config.normalized,
        "movie": [*_file_identity(movie_path), len(movie), list(movie.frame_shape),
                  str(movie.dtype)],
        "references": [_file_identity(p) for p in (*detect.backgrounds, *dark_files)]})
    return replace(detect, key=key)


def movie_info(movie: Movie) -> dict[str, Any]:
    """What the sidecars record of the movie file."""
    return {
        "frames": len(movie),
        "frame_shape": list(movie.frame_shape),
        "dtype": str(movie.dtype),
        "problems": list(movie.problems),
        "reader_notes": list(movie.notes),
    }
