"""The crop stage's settings (:class:`CropConfig`) and the rules they must obey.

The rules are checked before any frame is read (:func:`check_crop_settings` also by
``holofit init`` before a run folder is written), so that a run that cannot work stops at once
with a message naming the option to change.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from holofit.config import Instrument
from holofit.crop.centerfind import CenterFinder
from holofit.crop.errors import CropError
from holofit.crop.follow import FOLLOW_MODES, Follower
from holofit.crop.normalize import DEFAULT_MIN_BACKGROUND
from holofit.crop.profile import FringeOptics
from holofit.crop.tracks import LinkSettings

__all__ = [
    "CROP_MODES",
    "DEFAULT_CROP_SIZE",
    "MIN_CROP_SIZE",
    "TRACKS",
    "CropConfig",
    "References",
    "check_crop_settings",
    "reference_paths",
]

#: smallest crop side, pixels
MIN_CROP_SIZE = 8
#: the paper's crop side, pixels
DEFAULT_CROP_SIZE = 140
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
        Crop side N, pixels (default 140, the paper's).
    follow : str
        Which holograms to crop: ``"tracks"`` (the default) every one, linked into tracks
        (:mod:`holofit.crop.track_crops`), or one per frame, ``"strongest"`` or ``"nearest"``
        (:mod:`holofit.crop.follow`).
    start : tuple of float, optional
        ``(x_px, y_px)`` of the particle in the first frame, for ``"nearest"``.
    max_jump_px : float, optional
        The largest move between frames (default ``size / 4``).
    finder : CenterFinder, optional
        Centre-finder settings (default: vote radius ``size / 2``).
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
    settings = {"size_px": config.size, "follow": config.follow,
                "start_px": list(start) if start is not None else None,
                "max_jump_px": chosen.max_jump_px, "finder": finder.as_dict(),
                "normalization": {**norm_info, "mask_saturated": config.mask_saturated}}
    if config.follow == TRACKS:
        settings["tracks"] = {**link.as_dict(), "particle": config.particle}
    return settings
