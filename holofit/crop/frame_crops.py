"""The single-particle modes' sequential step (``follow="strongest"`` or ``"nearest"``, and
a movie with one hologram per frame in tracks mode): in frame order, choose each frame's
candidate (:class:`holofit.crop.follow.Follower`: the choice may depend on the previous
frame's), crop it and write its page; then mark the frames off the main track.

It runs after the parallel search (:mod:`holofit.crop.detect`), reading each frame again: one
frame in memory at a time, whatever the movie's length.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from holofit.crop.cropping import blank_row, crop_chosen
from holofit.crop.detect import DETECTED, found_from_json, read_normalised
from holofit.crop.follow import Follower, off_track
from holofit.crop.normalize import Normalizer
from holofit.io.movie import Movie
from holofit.io.tiffstack import TiffStackWriter
from holofit.status import CROP_ERROR, CROP_NO_PARTICLE, CROP_OFF_TRACK, FITTABLE_CROP_STATUSES

__all__ = ["crop_frames", "mark_off_track"]


def crop_frames(
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
        row = blank_row(k)
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
                     cand.symmetry, cand.refinement, cand.zone_px, cand.reach_px,
                     rank == choice.index,
                     0 if rank == choice.index else -1)
                )  # fmt: skip
            if choice.index is None:
                row["status"], row["message"] = CROP_NO_PARTICLE, choice.message
            else:
                image, mask = read_normalised(movie, k, normalizer)
                page = crop_chosen(row, found.iloc[choice.index], image, mask, size,
                                    pixel_size_um)
                if preview is None:
                    preview = {"frame": k, "image": image,
                               "corner": (row["corner_row"], row["corner_col"])}
        writer.write(page)
        rows.append(row)
        if progress is not None:
            progress(1)
    return rows, candidates, preview


def _frame_list(frames: list[int], most: int = 8) -> str:
    shown = ", ".join(map(str, frames[:most]))
    return shown + (f", ... ({len(frames)} in all)" if len(frames) > most else "")


def mark_off_track(rows: list[dict[str, Any]], max_jump_px: float) -> list[str]:
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
