"""The crop stage's tracks mode: every hologram of every frame, linked into tracks, cropped per
(particle, frame).

The per-frame search (:mod:`holofit.crop.detect`) keeps every accepted candidate centre of a
frame. :func:`link_detections` links them across frames into tracks
(:func:`holofit.crop.tracks.link_tracks`: trackpy, ``particle`` ids by first appearance) and marks
each (particle, frame) with its nearest other track (:func:`holofit.crop.tracks.mark_neighbours`).
:func:`track_rows` then says which (particle, frame) rows the crop table holds, and
:func:`crop_tracks` crops them in frame order (each frame read once):

- each kept track has rows from its first to its last detected frame (a track that leaves the
  frame ends, one that enters starts); frames within that span where it was not detected (within
  the linker's ``memory``) are ``no_particle`` rows, unreadable frames ``error`` rows;
- a movie with at most one hologram found in any frame has one particle in view: it is not
  linked (the holograms of a set of unrelated images need not form a track), and its crops
  are those of ``follow="strongest"`` (:func:`one_per_frame`);
- with one track kept (or none), that track, ``particle`` 0, has a row for every frame of the
  movie, as the single-particle modes give: the crops of a one-particle movie are the same in
  every mode.

Tracks that are fringes of a stronger hologram (rings cut by the frame edge, or crossing, that
the centre finder takes for centres) are left out and reported (:func:`drop_ghosts`).

Where another track's hologram reaches into a crop (its centre closer to the crop's square
than its reach, the radius within which its fringes stand above the noise:
:mod:`holofit.crop.profile`), the row's ``overlap`` is true and ``n_overlapping`` counts such
tracks; ``neighbour`` names the nearest other track and ``neighbour_px`` its distance. A
track that is lost, or undetected for a while, next to another hologram is reported
(:mod:`holofit.crop.losses`): in the warnings and, in full, in the sidecar.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from holofit.crop.cropping import blank_row, crop_chosen
from holofit.crop.detect import DETECTED, found_from_json, read_normalised
from holofit.crop.errors import CropError
from holofit.crop.losses import describe_losses, track_losses
from holofit.crop.normalize import Normalizer
from holofit.crop.tracks import (
    LinkSettings,
    TrackError,
    link_tracks,
    mark_neighbours,
    track_reach,
)
from holofit.io.movie import Movie
from holofit.io.tiffstack import TiffStackWriter
from holofit.status import CROP_ERROR, CROP_NO_PARTICLE

__all__ = ["GHOST_SCORE_RATIO", "TrackPlan", "crop_tracks", "drop_ghosts",
           "effective_link_options", "link_detections", "one_per_frame", "track_rows"]


def one_per_frame(detections: dict[int, dict[str, Any]]) -> bool:
    """No frame has more than one hologram found: one particle in view, nothing to link."""
    return all(int(d.get("n_found") or 0) <= 1 for d in detections.values()
               if d["status"] == DETECTED)


def effective_link_options(options: LinkSettings, n_frames: int) -> LinkSettings:
    """``options`` with ``min_track_length`` at most half the movie (rounded up): a movie of
    five frames keeps a particle seen in three of them."""
    cap = max(1, math.ceil(n_frames / 2))
    if options.min_track_length <= cap:
        return options
    return LinkSettings(options.search_range_um, options.memory, cap, options.max_particles)


@dataclass
class TrackPlan:
    """The linked tracks of a movie and the (particle, frame) rows the crop table holds.

    Attributes
    ----------
    linked : pandas.DataFrame
        One row per kept (particle, frame) detection: ``particle``, ``frame``, the candidate's
        columns, ``rank`` (its rank among the frame's candidates), ``neighbour``,
        ``neighbour_px``.
    summary : pandas.DataFrame
        Every track found, kept or not (:data:`holofit.crop.tracks.TRACK_SUMMARY_UNITS`).
    spans : dict
        particle -> (first frame, last frame) of its rows.
    warnings : list of str
        What the user should know (tracks left out, tracks lost next to another hologram,
        no hologram at all).
    losses : list of dict
        Where a track was lost, started late or went undetected next to another hologram
        (:func:`holofit.crop.losses.track_losses`).
    """

    linked: pd.DataFrame
    summary: pd.DataFrame
    spans: dict[int, tuple[int, int]]
    warnings: list[str] = field(default_factory=list)
    losses: list[dict[str, Any]] = field(default_factory=list)

    def particles_in(self, frame: int) -> list[int]:
        """The tracks with a row in ``frame``, in id order."""
        return [p for p, (a, b) in self.spans.items() if a <= frame <= b]


def _candidates_table(detections: dict[int, dict[str, Any]]) -> pd.DataFrame:
    parts = []
    for k in sorted(detections):
        det = detections[k]
        if det["status"] != DETECTED:
            continue
        found = found_from_json(det["candidates"])
        if len(found):
            parts.append(found.assign(frame=k, rank=np.arange(len(found))))
    if not parts:
        return pd.DataFrame(columns=["frame", "rank", "x_px", "y_px", "score"])
    return pd.concat(parts, ignore_index=True)


def link_detections(detections: dict[int, dict[str, Any]], n_frames: int, pixel_size_um: float,
                    options: LinkSettings, size: int, particle: int | None = None,
                    frame_shape: tuple[int, int] | None = None) -> TrackPlan:
    """Link every frame's candidates into tracks; the rows to crop.

    Parameters
    ----------
    detections : dict
        frame -> the search's row (:mod:`holofit.crop.detect`).
    n_frames : int
        Frames in the movie.
    pixel_size_um : float
        Camera pixel in the sample plane, um.
    options : LinkSettings
        Linking settings (``min_track_length`` capped: :func:`effective_link_options`).
    size : int
        Crop side, pixels (a hologram whose reach comes into a track's ``size`` square
        overlaps its crop).
    particle : int, optional
        Keep only this track (``--particle``).
    frame_shape : tuple of int, optional
        ``(rows, cols)`` of the frames: a track that ends or starts at the edge has left or
        entered the field of view (not reported as lost; without it, none is at the edge).

    Raises
    ------
    CropError
        Linking failed, or ``particle`` is not one of the tracks found.
    """
    opts = effective_link_options(options, n_frames)
    try:
        tracks = link_tracks(_candidates_table(detections), pixel_size_um, opts)
        linked = mark_neighbours(tracks.candidates, size)
        linked, ghosts = drop_ghosts(linked, tracks.summary, size)
    except TrackError as exc:
        raise CropError(f"linking tracks: {exc}") from None
    warnings = []
    if ghosts:
        warnings.append(f"{len(ghosts)} track(s) left out as fringes of a stronger hologram "
                        f"(within {GHOST_REACH:g} crop of a track at least"
                        f" {GHOST_SCORE_RATIO:g} times "
                        f"as strong in most of their frames): " + "; ".join(ghosts[:5]))
    summary = tracks.summary
    dropped = (summary[~summary["kept"].astype(bool) & (summary["reason"] != GHOST_REASON)]
               if len(summary) else summary)
    if len(dropped):
        shown = "; ".join(f"frames {int(r.first_frame)}-{int(r.last_frame)} at "
                          f"({r.x_px_start:.0f}, {r.y_px_start:.0f}) px: {r.reason}"
                          for r in dropped.head(5).itertuples())
        more = f" (and {len(dropped) - 5} more)" if len(dropped) > 5 else ""
        warnings.append(f"{len(dropped)} track(s) left out: {shown}{more}")
    losses = track_losses(linked, n_frames, frame_shape or (10**9, 10**9), pixel_size_um)
    if particle is not None:
        losses = [e for e in losses if e["particle"] == particle]
    line = describe_losses(losses)
    if line:
        warnings.append(line)
    kept = tracks.particles
    if particle is not None:
        if particle not in kept:
            have = ", ".join(map(str, kept)) if kept else "none"
            raise CropError(f"--particle {particle}: no such track (tracks found: {have})")
        linked = linked[linked["particle"] == particle].copy()
        linked["particle"] = 0
        linked["neighbour"] = -1
        linked["neighbour_px"] = np.inf
        kept = [0]
    if not kept:
        warnings.append("no hologram found in any frame: no track to crop"
                        if linked.empty and not len(tracks.summary)
                        else "no track long enough to keep: every frame is no_particle")
    spans: dict[int, tuple[int, int]] = {}
    if len(kept) <= 1:
        spans[0] = (0, n_frames - 1)
    else:
        for p, track in linked.groupby("particle"):
            spans[int(p)] = (int(track["frame"].min()), int(track["frame"].max()))
    return TrackPlan(linked, tracks.summary, spans, warnings, losses)


#: a track this many times weaker than a neighbour within half a crop is that one's fringes
GHOST_SCORE_RATIO = 2.0
#: the summary's reason for such a track
GHOST_REASON = "fringes of a stronger hologram"
#: ... in at least this fraction of its frames
GHOST_FRACTION = 0.8
#: ... within this fraction of a crop's side (a hologram's fringes reach past its crop's half)
GHOST_REACH = 0.75


def drop_ghosts(linked: pd.DataFrame, summary: pd.DataFrame, size: int
                ) -> tuple[pd.DataFrame, list[str]]:
    """Leave out tracks that are fringes of a stronger hologram, not particles.

    The centre finder also finds points where a hologram's rings are cut by the frame edge
    or cross: near a strong hologram they form steady tracks. A track whose nearest other
    track lies within :data:`GHOST_REACH` of a crop's side (or, for a detection neither
    refinement placed, within that track's reach) and scores at least
    :data:`GHOST_SCORE_RATIO` times
    higher in at least :data:`GHOST_FRACTION` of its frames (frames where it was found with
    the neighbour's rings subtracted, ``refinement`` ``peeled``, do not count: a fringe goes
    with its rings) is left out (reported), the ids
    renumbered in order of first appearance, the neighbours marked again. The price: a real
    particle much weaker than a neighbour that close is left out too unless the finder
    found it by peeling (:mod:`holofit.crop.peel`: within ~2 vote radii of the neighbour).

    Returns
    -------
    linked : pandas.DataFrame
        Without the ghosts' rows.
    reasons : list of str
        One line per track left out.
    """
    if linked.empty or linked["particle"].nunique() < 2:
        return linked, []
    score = linked.set_index(["particle", "frame"])["score"]
    near = np.array(linked["neighbour_px"] < GHOST_REACH * size, dtype=bool)
    if "refinement" in linked.columns:
        # a candidate neither refinement placed (no point symmetry, no circular rings about
        # it: a frame corner cutting a strong hologram's rings) is that hologram's fringes
        # anywhere within its reach (holofit.crop.profile), not only within the crop
        reach = track_reach(linked)
        theirs = np.array([reach.get(int(q), 0.0) for q in linked["neighbour"]])
        near |= ((linked["refinement"].to_numpy() == "none")
                 & (linked["neighbour_px"].to_numpy(dtype=float) < theirs))
    keys = list(zip(linked["neighbour"], linked["frame"], strict=True))
    other = np.array([score.get(k, np.nan) if n else np.nan
                      for k, n in zip(keys, near, strict=True)], dtype=float)
    weak = other >= GHOST_SCORE_RATIO * linked["score"].to_numpy(dtype=float)
    if "refinement" in linked.columns:
        # found with the neighbour's rings subtracted (holofit.crop.peel): not its fringes
        weak &= linked["refinement"].to_numpy() != "peeled"
    share = pd.Series(weak, index=linked.index).groupby(linked["particle"]).mean()
    ghosts = sorted(int(p) for p in share.index[share >= GHOST_FRACTION])
    if not ghosts or len(ghosts) == linked["particle"].nunique():
        return linked, []
    reasons = []
    for p in ghosts:
        t = linked[linked["particle"] == p]
        reasons.append(f"frames {int(t['frame'].min())}-{int(t['frame'].max())} at "
                       f"({t['x_px'].median():.0f}, {t['y_px'].median():.0f}) px")
    kept = linked[~linked["particle"].isin(ghosts)]
    ids = {old: new for new, old in enumerate(sorted(kept["particle"].unique()))}
    kept = kept.assign(particle=kept["particle"].map(ids)).drop(
        columns=["neighbour", "neighbour_px"])
    summary_ids = summary["particle"].isin(ghosts)
    summary.loc[summary_ids, "kept"] = False
    summary.loc[summary_ids, "reason"] = GHOST_REASON
    summary["particle"] = [ids.get(p, -1) for p in summary["particle"]]
    return mark_neighbours(kept.reset_index(drop=True), size), reasons


def track_rows(plan: TrackPlan, frame: int, size: int | None = None
               ) -> list[tuple[int, dict[str, Any] | None]]:
    """``(particle, its detection in frame or None)`` for every track with a row in ``frame``;
    a detection holds the candidate's columns, ``rank``, ``neighbour``, ``neighbour_px``,
    ``overlap`` and ``n_overlapping`` (:func:`holofit.crop.tracks.mark_neighbours`, with the
    plan's crop side; ``size`` is not used)."""
    here = plan.linked[plan.linked["frame"] == frame]
    by_particle = {int(r["particle"]): r for r in here.to_dict(orient="records")}
    return [(p, by_particle.get(p)) for p in plan.particles_in(frame)]


def crop_tracks(
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
        here = track_rows(plan, k)
        chosen = {int(d["rank"]): p for p, d in here if d is not None}
        for rank, cand in enumerate(found.itertuples(index=False)):
            candidates.append((k, rank, cand.x_px, cand.y_px, cand.score, cand.alignment,
                               cand.symmetry, cand.refinement, cand.zone_px, cand.reach_px,
                               rank in chosen, chosen.get(rank, -1)))
        image: NDArray | None = None
        mask: NDArray | None = None
        for p, linked in here:
            row = blank_row(k)
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
                assert mask is not None  # read together with the image
                page = crop_chosen(row, found.iloc[int(linked["rank"])], image, mask, size,
                                    pixel_size_um)
                row.update(neighbour=int(linked["neighbour"]),
                           neighbour_px=float(linked["neighbour_px"]),
                           overlap=bool(linked["overlap"]),
                           n_overlapping=int(linked["n_overlapping"]))
                if row["overlap"]:
                    row["message"] = (f"overlaps {row['n_overlapping']} other track(s)' "
                                      f"hologram(s); nearest track {row['neighbour']} "
                                      f"({row['neighbour_px']:.0f} px away)")
                if preview is None:
                    preview = {"frame": k, "image": image,
                               "corner": (row["corner_row"], row["corner_col"])}
            writer.write(page)
            rows.append(row)
        if progress is not None:
            progress(1)
    return rows, candidates, preview
