"""The crop stage's per-frame step: read, normalise and search one frame for hologram centres.

Frames are independent here (which candidate to crop, when a frame has several, may depend
on the previous frame's choice: that cheap step runs afterwards in frame order, in
:mod:`holofit.crop.stage`), so they run through the batch runner (:mod:`holofit.batch`):
in parallel, and resumably: the candidates of every frame done are kept in
``detections.csv`` (+ journal while running) in the crop folder, and a rerun with the same
movie and settings searches only the frames not done yet.

A worker opens the movie and prepares the normaliser once (from :class:`DetectConfig`: file
names and settings, not arrays) and keeps them for all its frames, as the skeleton's per-worker
resource (:func:`holofit.batch.worker.worker_resource`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from holofit.batch.worker import release_worker_resources, worker_resource
from holofit.crop.centerfind import CENTER_COLUMNS, CenterFinder
from holofit.crop.errors import FrameError
from holofit.crop.normalize import Normalizer
from holofit.crop.reference import read_dark, read_reference_frame
from holofit.io.movie import Movie, MovieError, open_movie

__all__ = ["DETECTED", "DETECTION_COLUMNS", "FOUND_COLUMNS", "DetectConfig", "detect",
           "detect_frame", "found_from_json", "no_payload", "read_normalised", "release"]

#: columns of a frame's candidates, in the order the finder gives them
FOUND_COLUMNS = CENTER_COLUMNS
#: columns of ``detections.csv``
DETECTION_COLUMNS = ("frame", "status", "message", "n_found", "candidates", "fit_time_s")
#: the detection ran (``candidates`` may be empty) / the frame could not be read or searched
DETECTED, UNREADABLE = "ok", "failed"


@dataclass(frozen=True)
class DetectConfig:
    """What a worker needs to detect candidates in any frame (picklable, small).

    Attributes
    ----------
    movie : str
        The movie file or folder.
    backgrounds : tuple of str
        Background files (empty with a movie normalised already: a flat background).
    dark : float, tuple of str or None
        Dark level: counts or files.
    min_background, saturation, full_scale
        As for :class:`~holofit.crop.normalize.Normalizer`.
    finder : CenterFinder
        Centre-finder settings.
    key : str
        Fingerprint of all of the above and the movie's identity (workers' cache key).
    """

    movie: str
    backgrounds: tuple[str, ...]
    dark: float | tuple[str, ...] | None
    min_background: float
    saturation: float | None
    finder: CenterFinder
    key: str = ""
    full_scale: float | None = None


#: the per-worker resource of a detection config: its open movie and its normaliser
DETECT_RESOURCE = "crop detection"


def _open_state(config: DetectConfig) -> tuple[Movie, Normalizer]:
    """The movie, opened, and the normaliser prepared from the reference files."""
    movie = open_movie(config.movie)
    if config.backgrounds:
        background = read_reference_frame([Path(p) for p in config.backgrounds], "background")
        dark = config.dark if not isinstance(config.dark, tuple) else list(config.dark)
        normalizer = Normalizer(background, read_dark(dark), min_background=config.min_background,
                                saturation=config.saturation, full_scale=config.full_scale)
    else:
        normalizer = Normalizer(np.ones(movie.frame_shape), saturation=config.saturation,
                                full_scale=config.full_scale)
    return movie, normalizer


def _state(config: DetectConfig) -> tuple[Movie, Normalizer]:
    """This worker's movie and normaliser of ``config`` (one at a time: a worker searches one
    movie; :func:`holofit.batch.worker.worker_resource`)."""
    return worker_resource(DETECT_RESOURCE, config.key, lambda: _open_state(config), size=1,
                           close=lambda state: state[0].close())


def release() -> None:
    """Close the movie this process keeps open (if any)."""
    release_worker_resources(DETECT_RESOURCE)


def detect(
    movie: Movie, k: int, normalizer: Normalizer, finder: CenterFinder
) -> tuple[NDArray, NDArray, pd.DataFrame]:
    """Read, normalise and search frame ``k``; any failure becomes a :class:`FrameError`."""
    image, mask = read_normalised(movie, k, normalizer)
    try:
        found = finder.find(image, mask)
    except Exception as exc:  # a bug must not lose the rest of a long movie
        raise FrameError(
            f"{movie.frame_source(k)}: frame {k}: centre finder failed "
            f"({type(exc).__name__}: {exc})"
        ) from None
    return image, mask, found


def read_normalised(movie: Movie, k: int, normalizer: Normalizer) -> tuple[NDArray, NDArray]:
    """Read and normalise frame ``k`` (image, mask); any failure becomes a
    :class:`FrameError`."""
    source = movie.frame_source(k)
    try:
        raw = movie[k]
    except MovieError as exc:
        raise FrameError(str(exc)) from None
    full = normalizer.full_scale
    if full is not None and raw.size and float(np.max(raw)) > full:
        raise FrameError(
            f"{source}: frame {k}: counts up to {float(np.max(raw)):g} exceed the full scale "
            f"{full:g} of the instrument's bit_depth: correct bit_depth in the instrument "
            "config, or do not mask saturated pixels (--keep-saturated)"
        )
    try:
        image, mask = normalizer(raw)
    except ValueError as exc:
        raise FrameError(f"{source}: frame {k}: {exc}") from None
    return image, mask


def detect_frame(config: DetectConfig, frame: int, payload: Any = None) -> dict[str, Any]:
    """The candidates of one frame as a row of ``detections.csv``; the batch's frame
    function (the worker reads the frame itself: ``payload`` is unused)."""
    movie, normalizer = _state(config)
    try:
        _, _, found = detect(movie, frame, normalizer, config.finder)
    except FrameError as exc:
        return {"status": UNREADABLE, "message": str(exc), "n_found": 0, "candidates": "[]"}
    values = [[_plain(v) for v in rec] for rec in
              found[list(FOUND_COLUMNS)].itertuples(index=False, name=None)]
    return {"status": DETECTED, "message": "", "n_found": len(values),
            "candidates": json.dumps(values)}


def _plain(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    return value


def found_from_json(text: Any) -> pd.DataFrame:
    """A frame's candidates (the finder's columns :data:`FOUND_COLUMNS`) from its row."""
    values = json.loads(text) if isinstance(text, str) and text else []
    n = len(FOUND_COLUMNS)
    # rows written before a column existed (zone_px, reach_px) get NaN for it
    values = [list(v) + [float("nan")] * (n - len(v)) for v in values]
    return pd.DataFrame(values, columns=list(FOUND_COLUMNS))


def no_payload(frame: int) -> None:
    """The batch's loader: a worker reads its frame itself."""
    return None
