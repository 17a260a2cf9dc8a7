"""One run of the crop stage, its inputs checked: the search of every frame through the stage
skeleton, the sequential cropping step, and the outputs.

1. **The search** (:func:`search_frames`): every frame's candidates, a batch of the stage
   skeleton (:func:`holofit.batch.stage.run_stage`: parallel, resumable) into
   ``detections.csv``; a rerun with the same movie and settings searches only the frames not
   searched yet, one with others starts again (the table is derived: ``replace_stale``).
2. **The sequential step**, in frame order, one TIFF stack writer: the tracks mode's
   (:func:`holofit.crop.track_crops.crop_tracks`) or the single-particle modes'
   (:func:`holofit.crop.frame_crops.crop_frames`).
3. **The outputs**: ``candidates.csv``, ``crops.png``, the stack's sidecar, and the crop table
   ``crops.csv`` published last by the runner's publish step
   (:func:`holofit.batch.layout.publish_table`, with the fingerprint of the detections and
   the settings), so its presence means the stage completed. ``detections.csv`` is removed
   once the crop folder is complete (or failed as a whole).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.batch.errors import BatchError
from holofit.batch.layout import StageTable, discard_outputs, publish_table
from holofit.batch.options import BatchSettings
from holofit.batch.stage import fingerprint, run_stage
from holofit.config import Instrument
from holofit.crop.detect import (
    DETECTION_COLUMNS,
    FOUND_COLUMNS,
    DetectConfig,
    detect_frame,
    no_payload,
    release,
)
from holofit.crop.errors import CropError
from holofit.crop.follow import Follower
from holofit.crop.frame_crops import crop_frames, mark_off_track
from holofit.crop.inputs import movie_info
from holofit.crop.normalize import Normalizer
from holofit.crop.settings import TRACKS, CropConfig
from holofit.crop.track_crops import crop_tracks, link_detections, one_per_frame
from holofit.crop.tracks import LinkSettings
from holofit.io.lock import output_lock
from holofit.io.movie import Movie
from holofit.io.tables import read_table, sidecar_path, write_json
from holofit.io.tiffstack import TiffStackWriter
from holofit.provenance import sidecar
from holofit.status import CROP_ERROR, CROP_STATUSES
from holofit.tables.crop import CROP_COLUMNS, CROP_UNITS, crop_extra, stack_header, write_candidates

__all__ = ["DETECTIONS", "CropInputs", "CropJob", "CropResult", "search_frames"]

#: the candidates of every frame searched so far (removed when the crop folder is complete)
DETECTIONS = "detections.csv"


@dataclass
class CropResult:
    """What :func:`holofit.crop.run_crop` wrote.

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


def search_frames(path: Path, config: DetectConfig, n_frames: int, movie_path: str | Path,
                  batch: BatchSettings | None) -> dict[int, dict[str, Any]]:
    """Every frame's row of ``detections.csv`` (``path``): the frames not searched yet by an
    earlier run with the same movie and settings are searched (another run's results are
    discarded), through the stage skeleton.

    Raises
    ------
    CropError
        The search failed as a whole (every frame in error, the backend would not start); the
        detections are removed.
    """
    opts = batch or BatchSettings(workers=0, progress=False)
    meta = {"kind": "crop detections (candidate centres of every frame searched; "
                    "removed when the crop folder is complete)",
            "candidates": f"JSON list of [{', '.join(FOUND_COLUMNS)}] per candidate"}
    table = StageTable(path, DETECTION_COLUMNS, meta, config.key, "crop", replace_stale=True)
    try:
        run_stage(detect_frame, config, range(n_frames), no_payload, table, batch=opts)
    except BatchError as exc:
        discard_outputs(path)
        raise CropError(f"{movie_path}: {exc}") from None
    finally:
        release()
    rows = read_table(path)
    return {int(r["frame"]): r for r in rows.to_dict(orient="records")}


class _CropPaths:
    """The files of a crop folder."""

    def __init__(self, out: Path) -> None:
        self.stack = out / "crops.tif"
        self.table = out / "crops.csv"
        self.candidates = out / "candidates.csv"
        self.plot = out / "crops.png"

    def remove_stale(self) -> None:
        """Remove the outputs of an earlier run but the stack (being written)."""
        discard_outputs(self.table)
        discard_outputs(self.candidates)
        for path in (sidecar_path(self.stack), self.plot):
            path.unlink(missing_ok=True)


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


@dataclass
class CropInputs:
    """The crop's inputs, checked (:mod:`holofit.crop.inputs`).

    Attributes
    ----------
    movie, movie_path
        The open movie and its file.
    normalizer : Normalizer
        The frames' normaliser.
    detect : DetectConfig
        What a worker searches frames with, and its fingerprint.
    inst : Instrument
        The instrument.
    settings : dict
        The settings as the sidecars record them.
    inputs : list
        The input files (movie, backgrounds, dark frames).
    warnings : list of str
        What the inputs' checks found doubtful (saturation found in the data).
    """

    movie: Movie
    movie_path: str | Path
    normalizer: Normalizer
    detect: DetectConfig
    inst: Instrument
    settings: dict[str, Any]
    inputs: list[str | Path]
    warnings: list[str] = field(default_factory=list)


@dataclass
class CropJob:
    """One run of the crop stage: crop every frame, write the folder."""

    given: CropInputs
    config: CropConfig
    follower: Follower
    link: LinkSettings
    out: Path
    batch: BatchSettings | None = None
    progress: Callable[[int], Any] | None = None

    def run(self) -> CropResult:
        """Search every frame (a batch: parallel, resumable), then crop in frame order; the
        detections are removed once the crop folder is complete (or failed as a whole)."""
        detections = self.out / DETECTIONS
        with output_lock(self.out, stage="crop"):
            try:
                result = self.crop(detections)
            except CropError:
                discard_outputs(detections)
                raise
            discard_outputs(detections)
        return result

    def crop(self, detections_path: Path) -> CropResult:
        """The search, the sequential step and the outputs (:mod:`holofit.tables.crop`); the
        stack's temporary file is there from the start (a killed run leaves only it, and
        its next writer removes it)."""
        g, cfg = self.given, self.config
        movie, size, paths, settings = g.movie, cfg.size, _CropPaths(self.out), g.settings
        px = g.inst.pixel_size_um
        with TiffStackWriter(paths.stack, stack_header(size, len(movie))) as writer:
            detections = search_frames(detections_path, g.detect, len(movie), g.movie_path,
                                       self.batch)
            linking = cfg.follow == TRACKS and (
                cfg.particle not in (None, 0) or not one_per_frame(detections))
            if cfg.follow == TRACKS:
                settings["tracks"]["linked"] = linking
            if linking:
                plan = link_detections(detections, len(movie), px, self.link, size,
                                       cfg.particle, tuple(movie.frame_shape))
                rows, candidates, preview = crop_tracks(movie, g.normalizer, detections, plan,
                                                        size, px, writer, self.progress)
                warnings = list(plan.warnings)
                losses = plan.losses
            else:
                losses = []
                rows, candidates, preview = crop_frames(movie, g.normalizer, detections,
                                                        self.follower, size, px, writer,
                                                        self.progress)
                warnings = (mark_off_track(rows, self.follower.max_jump_px)
                            if cfg.follow != "nearest" else [])
                if cfg.follow == TRACKS and not any(
                        int(d.get("n_found") or 0) for d in detections.values()):
                    settings["tracks"]["note"] = (
                        "no hologram found in any frame: no track, every frame no_particle (is "
                        "it the right movie and background? --min-score and --vote-radius set "
                        "what is found)")
            frames = _frame_table(rows, g.movie_path)
            paths.remove_stale()  # a rerun must not leave an old table beside the new stack
        counts = {s: int((frames["status"] == s).sum()) for s in CROP_STATUSES}
        cand_table = write_candidates(paths.candidates, candidates, g.inst.as_dict(), g.inputs,
                                      settings)
        made_plot = None
        if cfg.plot and preview is not None:
            from holofit.crop.plot import plot_overview

            made_plot = plot_overview(paths.plot, preview, frames, cand_table, size)
        warnings = [*g.warnings, *warnings]
        extra = crop_extra(settings, movie_info(movie), paths.stack, paths.table, len(frames),
                           size, counts, warnings, losses)
        self.publish(paths, frames, extra)
        note = settings.get("tracks", {}).get("note")
        return CropResult(self.out, paths.stack, paths.table, paths.candidates, made_plot,
                          frames, counts, list(movie.problems), warnings,
                          [note] if note else [])

    def publish(self, paths: _CropPaths, frames: pd.DataFrame, extra: dict[str, Any]) -> None:
        """The stack's sidecar, then the crop table, published last (the runner's publish
        step): its presence marks a complete run; its fingerprint is that of the detections
        and the settings."""
        g = self.given
        config = {"instrument": g.inst.as_dict()}
        write_json(sidecar_path(paths.stack),
                   sidecar(kind="crop stack", units={"pixel value": "1 (background = 1)"},
                           config=config, inputs=g.inputs, extra=extra))
        meta = sidecar(kind="crop table", units=CROP_UNITS, config=config, inputs=g.inputs,
                       extra=extra)
        key = fingerprint({"detections": g.detect.key, "settings": g.settings,
                           "instrument": config["instrument"]})
        publish_table(paths.table, frames, meta, key)
