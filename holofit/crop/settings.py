"""The crop stage's settings (:class:`CropConfig`) and the rules they must obey.

The rules are checked before any frame is read (:func:`check_crop_settings` also by
``holofit init`` before a run folder is written), so that a run that cannot work stops at once
with a message naming the option to change.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from holofit.config import Instrument
from holofit.crop.centerfind import CenterFinder
from holofit.crop.detect import detect
from holofit.crop.errors import CropError, FrameError
from holofit.crop.follow import FOLLOW_MODES, Follower
from holofit.crop.normalize import DEFAULT_MIN_BACKGROUND, Normalizer
from holofit.crop.profile import FringeOptics
from holofit.crop.tracks import LinkSettings

__all__ = [
    "AUTO_VOTE_RADIUS",
    "CROP_MODES",
    "CROP_ZONE_RADII",
    "DEFAULT_CROP_SIZE",
    "MIN_CROP_SIZE",
    "SIZE_PREVIEW_FRAMES",
    "TRACKS",
    "CropConfig",
    "DefaultRadius",
    "DefaultSize",
    "References",
    "check_crop_settings",
    "crop_size_for_zone",
    "hologram_zones",
    "is_automatic",
    "reference_paths",
    "sized_for_movie",
]

#: smallest crop side, pixels
MIN_CROP_SIZE = 8


class DefaultSize(int):
    """A crop side in pixels that was not given: the crop stage may enlarge it to the movie's
    holograms (:func:`sized_for_movie`). Compares and computes as the plain ``int``."""


class DefaultRadius(float):
    """A vote radius in pixels that was not given: half the crop side the crop stage
    chooses (:func:`sized_for_movie`). Compares and computes as the plain ``float``."""


#: the paper's crop side, pixels: the smallest default side (a :class:`DefaultSize`: a
#: ``CropConfig`` without a ``size`` grows it with the movie's holograms)
DEFAULT_CROP_SIZE: int = DefaultSize(140)
#: the vote radius of a centre finder whose radius was not given (``holofit crop`` without
#: ``--vote-radius``): half the crop side, chosen with it
AUTO_VOTE_RADIUS: float = DefaultRadius(DEFAULT_CROP_SIZE / 2.0)
#: The default crop side spans this many zone radii ``sqrt(lambda_m z)`` of the movie's
#: typical hologram (the vote radius, half the side, two): a vote disc that holds little more
#: than the central spot of a hologram at the movie's height merges close pairs and lets the
#: rings between them pass as centres; four keeps the paper's 140 px on the paper's
#: instruments at their heights (docs: validation, "field of view").
CROP_ZONE_RADII = 4.0
#: frames of the movie (evenly spread) whose holograms' zone radii set the default crop side
SIZE_PREVIEW_FRAMES = 5
#: a preview candidate counts if it scores at least this share of its frame's strongest
#: (holograms score hundreds, fringes cut by the frame's edge tens)
PREVIEW_SCORE_SHARE = 0.25
#: every hologram linked into tracks (:mod:`holofit.crop.track_crops`; the default)
TRACKS = "tracks"
#: what ``follow`` may be: tracks, or one hologram per frame (:mod:`holofit.crop.follow`)
CROP_MODES = (*FOLLOW_MODES, TRACKS)

#: reference files: one path, or several (their frames are reduced by the per-pixel median)
References = str | Path | Sequence[str | Path]


def reference_paths(refs: References | None) -> list[Path]:
    """The files of a reference (background or dark) argument."""
    if refs is None:
        return []
    return [Path(refs)] if isinstance(refs, str | Path) else [Path(r) for r in refs]


@dataclass(frozen=True)
class CropConfig:
    """How the crop stage normalises, searches and crops (:func:`holofit.crop.run_crop`).

    Attributes
    ----------
    size : int
        Crop side N, pixels. Default :data:`DEFAULT_CROP_SIZE`: the larger of the paper's
        140 px and :data:`CROP_ZONE_RADII` zone radii of the movie's typical hologram
        (:func:`sized_for_movie`); a side given stays as given.
    follow : str
        Which holograms to crop: ``"tracks"`` (the default) every one, linked into tracks
        (:mod:`holofit.crop.track_crops`), or one per frame, ``"strongest"`` or ``"nearest"``
        (:mod:`holofit.crop.follow`).
    start : tuple of float, optional
        ``(x_px, y_px)`` of the particle in the first frame, for ``"nearest"``.
    max_jump_px : float, optional
        The largest move between frames (default ``size / 4``).
    finder : CenterFinder, optional
        Centre-finder settings (default: vote radius ``size / 2``; a finder whose radius is
        :data:`AUTO_VOTE_RADIUS` gets half the side chosen).
    link : LinkSettings, optional
        ``"tracks"`` only: how holograms are linked (:class:`holofit.crop.tracks.LinkSettings`).
    particle : int, optional
        ``"tracks"`` only: the one track to keep (its rows get ``particle`` 0).
    normalized : bool
        The movie is background-divided already (as many public data sets are, often stored
        as scaled integers): each frame is only divided by its mean (the paper's
        normalisation with a flat background); saturated pixels are still masked.
    dark : str, Path, sequence of them, or float, optional
        Dark level: counts (``--dark-count``) or dark frame / stack files (their median).
    min_background : float
        Background pixels at or below this fraction of the median background are masked.
    mask_saturated : bool
        Mask (NaN) pixels at the camera's full-scale count.
    plot : bool
        Write ``crops.png``.
    """

    size: int = DEFAULT_CROP_SIZE
    follow: str = TRACKS
    start: tuple[float, float] | None = None
    max_jump_px: float | None = None
    finder: CenterFinder | None = None
    link: LinkSettings | None = None
    particle: int | None = None
    normalized: bool = False
    dark: References | float | None = None
    min_background: float = DEFAULT_MIN_BACKGROUND
    mask_saturated: bool = True
    plot: bool = True

    def finder_for_size(self, instrument: Instrument | None = None) -> CenterFinder:
        """The centre finder: the one given, else the default with vote radius ``size / 2``;
        with the instrument's fringe limits (:class:`holofit.crop.profile.FringeOptics`)
        where it has none."""
        finder = self.finder or CenterFinder(radius_px=self.size / 2.0)
        if instrument is None or finder.optics is not None:
            return finder
        o = instrument.optics
        return replace(finder, optics=FringeOptics.of(
            o.wavelength_um, o.n_medium, instrument.pixel_size_um, o.numerical_aperture))

    def dark_files(self) -> list[Path]:
        """The dark frame files (none for a dark level in counts)."""
        return [] if isinstance(self.dark, int | float) else reference_paths(self.dark)


def is_automatic(config: CropConfig) -> bool:
    """The crop side was not given (:class:`DefaultSize`): the movie's holograms choose it."""
    return isinstance(config.size, DefaultSize)


def crop_size_for_zone(zone_px: float, frame_shape: tuple[int, int]) -> int:
    """The default crop side for holograms of zone radius ``zone_px`` (pixels).

    :data:`CROP_ZONE_RADII` zone radii, rounded up to an even side, never below the paper's
    140 px nor above the frame's shorter side: the crop and the vote disc follow the
    hologram's reach in micrometres (the zone radius grows with the height and shrinks with
    the pixel), not a fixed count of pixels.
    """
    side = int(DEFAULT_CROP_SIZE)
    if math.isfinite(zone_px) and zone_px > 0:
        side = max(side, 2 * math.ceil(CROP_ZONE_RADII * zone_px / 2.0))
    return min(side, int(min(frame_shape)))


def hologram_zones(found: pd.DataFrame) -> list[float]:
    """The zone radii of a frame's holograms (its candidates): its refined candidates' that
    score at least :data:`PREVIEW_SCORE_SHARE` of its strongest (the rest are fringes cut by
    the frame's edge, whose zone is that of the cut, or junk beside a hologram)."""
    if "zone_px" not in found.columns or not len(found):
        return []
    score = found["score"].to_numpy(float)
    keep = score >= PREVIEW_SCORE_SHARE * np.nanmax(score)
    if "refinement" in found.columns:
        keep &= found["refinement"].astype(str).to_numpy() != "none"
    z = found["zone_px"].to_numpy(float)[keep]
    return [float(v) for v in z[np.isfinite(z) & (z > 0)]]


def sized_for_movie(config: CropConfig, movie: Any, normalizer: Normalizer,
                    instrument: Instrument | None = None) -> tuple[CropConfig, dict[str, Any]]:
    """``config`` with its crop side and vote radius chosen for ``movie`` where not given.

    The default finder searches :data:`SIZE_PREVIEW_FRAMES` frames spread over the movie;
    the median zone radius of their holograms (:func:`hologram_zones`, each candidate's from
    :mod:`holofit.crop.profile`) gives the side (:func:`crop_size_for_zone`), and the vote
    radius is half of it where it was not given either (the default finder, or
    :data:`AUTO_VOTE_RADIUS`). A side given stays as given; so does a finder's radius given.
    A movie whose preview frames show no hologram the default finder finds (every one in a
    pair closer than its vote disc) keeps 140 px.

    Returns
    -------
    CropConfig, dict
        The config (plain ``int`` side) and what the sidecar records of the choice
        (``rule``, ``zone_px``: None where no hologram was found, ``frames``, ``size_px``).
    """
    if not is_automatic(config):
        return replace(config, size=int(config.size)), {"rule": "given"}
    finder = config.finder_for_size(instrument)
    n = len(movie)
    frames = sorted({int(k) for k in np.linspace(0, n - 1, min(SIZE_PREVIEW_FRAMES, n))})
    zones: list[float] = []
    for k in frames:
        try:
            _, _, found = detect(movie, k, normalizer, finder)
        except FrameError:
            continue
        zones += hologram_zones(found)
    zone = float(np.median(zones)) if zones else math.nan
    side = crop_size_for_zone(zone, tuple(movie.frame_shape))
    out = replace(config, size=side)
    if config.finder is not None and isinstance(config.finder.radius_px, DefaultRadius):
        out = replace(out, finder=replace(config.finder, radius_px=side / 2.0))
    record = {"rule": f"max(140 px, {CROP_ZONE_RADII:g} zone radii of the movie's holograms)",
              "zone_px": zone if math.isfinite(zone) else None, "frames": frames,
              "size_px": side}
    return out, record


def check_crop_settings(
    frame_shape: tuple[int, int],
    size: int = DEFAULT_CROP_SIZE,
    follow: str = TRACKS,
    start: tuple[float, float] | None = None,
) -> None:
    """Refuse crop settings that cannot work on frames of ``frame_shape`` (rows, cols).

    The rules of :func:`holofit.crop.run_crop`, also checked by ``holofit init`` before a run
    folder is written. Messages name the crop's options (``--size``, ``--follow``,
    ``--start``).

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


def check_arguments(config: CropConfig, background_path: References | None) -> list[Path]:
    """Refuse a crop too small and a background given or missing against ``normalized``;
    the background files."""
    if config.size < MIN_CROP_SIZE:
        raise CropError(f"crop size must be at least {MIN_CROP_SIZE} pixels, got {config.size}")
    backgrounds = reference_paths(background_path)
    if config.normalized and (backgrounds or config.dark is not None):
        raise CropError(
            "a normalised movie takes no background and no dark level: give either a "
            "background or normalized=True (--normalized)"
        )
    if not config.normalized and not backgrounds:
        raise CropError(
            "no background given: crop needs the background of the raw movie, or "
            "normalized=True (--normalized) for a movie that is normalised already"
        )
    return backgrounds


def follower(config: CropConfig) -> Follower:
    """The single-particle follower (tracks mode: the strongest hologram of the preview)."""
    follow = config.follow
    return Follower(follow if follow != TRACKS else "strongest", config.start,
                    config.max_jump_px if config.max_jump_px is not None else config.size / 4.0)


def link_options(config: CropConfig) -> LinkSettings:
    """The linking options; refused with a single-particle ``follow``."""
    if config.follow != TRACKS and (config.link is not None or config.particle is not None):
        raise CropError("--particle and the linking options (--search-range-um, --memory, "
                        "--min-track-length, --max-particles) need --follow tracks")
    return config.link or LinkSettings()


def settings_record(config: CropConfig, chosen: Follower, finder: CenterFinder,
                    norm_info: dict[str, Any], link: LinkSettings) -> dict[str, Any]:
    """The crop's settings as its sidecar records them."""
    start = config.start
    settings = {"size_px": int(config.size), "follow": config.follow,
                "start_px": list(start) if start is not None else None,
                "max_jump_px": chosen.max_jump_px, "finder": finder.as_dict(),
                "normalization": {**norm_info, "mask_saturated": config.mask_saturated}}
    if config.follow == TRACKS:
        settings["tracks"] = {**link.as_dict(), "particle": config.particle}
    return settings
