"""Linking every frame's hologram centres into tracks: one ``particle`` id per hologram.

The crop stage's candidate table (:data:`holofit.tables.crop.CANDIDATE_UNITS`) holds every
accepted hologram centre of every frame. :func:`link_tracks` links them across frames with
trackpy's linker (``trackpy.link``; Crocker & Grier's nearest-neighbour assignment with
subnetwork resolution and a memory for briefly lost holograms), the field's standard, and
names each track with trackpy's column name, ``particle``.

Track ids are renumbered 0, 1, 2 ... in order of first appearance (then of ``x_px``), so that
they do not depend on trackpy's internal counter and a rerun on the same candidates gives the
same ids. Tracks shorter than ``min_track_length`` frames, and tracks beyond the
``max_particles`` longest, are reported in the summary with why and left out of the linked
table.

:func:`mark_neighbours` adds, to each (particle, frame), the nearest other track in the same
frame and its distance, and the tracks whose holograms reach into its crop (their fringes
above the noise there: :mod:`holofit.crop.profile`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import pandas as pd

__all__ = [
    "TRACK_SUMMARY_UNITS",
    "LinkSettings",
    "LinkedTracks",
    "TrackError",
    "hidden_positions",
    "link_tracks",
    "mark_neighbours",
    "track_reach",
]

#: columns of the per-track summary returned by :func:`link_tracks`
TRACK_SUMMARY_UNITS = {
    "particle": "track id (0, 1, ... in order of first appearance); -1: left out",
    "first_frame": "index",
    "last_frame": "index",
    "n_frames": "count (frames with a detection)",
    "n_gaps": "count (frames within the track's span without a detection)",
    "mean_score": "1 (mean detection score)",
    "x_px_start": "pixel, full frame",
    "y_px_start": "pixel, full frame",
    "kept": "bool (linked table holds the track)",
    "reason": "text (why a track was left out)",
}


#: the shortest search range trackpy's adaptive search tries for a subnetwork too large, um
ADAPTIVE_STOP_UM = 0.3


class TrackError(ValueError):
    """Candidates or settings that cannot be linked; the message says which."""


@dataclass(frozen=True)
class LinkSettings:
    """How holograms are linked into tracks.

    Attributes
    ----------
    search_range_um : float
        Farthest a hologram centre may move between two successive frames in which it is
        detected, um (full-frame x-y). It must exceed the largest step of a particle (for a
        1 um sphere in water at 100 frames/s the rms 2D step is ~0.13 um) and should stay below
        half the closest approach of two particles, or trackpy resolves the pair as a
        subnetwork (slower, and ambiguous when they pass within a step of each other).
    memory : int
        Frames a hologram may go undetected and keep its track. Two holograms closer than the
        centre finder resolves (about 2 um) give one detection for as long as they stay that
        close; a track must outlive that gap, or the detection that merged both carries on
        with the wrong particle when they part (docs: validation, "field of view").
    min_track_length : int
        Shorter tracks (in detected frames) are reported and left out.
    min_detected_fraction : float
        Tracks detected in fewer than this fraction of the frames of their span are reported
        and left out: sparse detections (a fringe of a strong hologram found now and then)
        that the memory strings together; a real track bridging a close approach keeps most
        of its span.
    max_particles : int, optional
        Keep at most this many tracks: the longest (ties: the higher mean score).
    """

    search_range_um: float = 1.5
    memory: int = 10
    min_track_length: int = 10
    max_particles: int | None = None
    min_detected_fraction: float = 0.5

    def __post_init__(self) -> None:
        if not (math.isfinite(self.search_range_um) and self.search_range_um > 0):
            raise TrackError(
                f"search_range_um must be a positive number of micrometres, got "
                f"{self.search_range_um!r}"
            )
        if self.memory < 0:
            raise TrackError(f"memory must be >= 0 frames, got {self.memory}")
        if self.min_track_length < 1:
            raise TrackError(f"min_track_length must be >= 1 frame, got {self.min_track_length}")
        if not 0.0 <= self.min_detected_fraction <= 1.0:
            raise TrackError("min_detected_fraction must lie in [0, 1], got "
                             f"{self.min_detected_fraction!r}")
        if self.max_particles is not None and self.max_particles < 1:
            raise TrackError(f"max_particles must be >= 1, got {self.max_particles}")

    def as_dict(self) -> dict[str, Any]:
        """Plain dict for sidecar files."""
        return asdict(self)


@dataclass
class LinkedTracks:
    """What :func:`link_tracks` found.

    Attributes
    ----------
    candidates : pandas.DataFrame
        The kept candidates, one per (particle, frame), with the column ``particle``; sorted by
        particle, then frame.
    summary : pandas.DataFrame
        One row per track found, kept or not (columns :data:`TRACK_SUMMARY_UNITS`).
    """

    candidates: pd.DataFrame
    summary: pd.DataFrame

    @property
    def particles(self) -> list[int]:
        """The kept track ids."""
        return sorted(int(p) for p in self.candidates["particle"].unique())


def _check_candidates(candidates: pd.DataFrame) -> pd.DataFrame:
    missing = [c for c in ("frame", "x_px", "y_px") if c not in candidates.columns]
    if missing:
        raise TrackError(f"the candidate table lacks the column(s) {', '.join(missing)}")
    table = candidates.copy()
    coords = table[["frame", "x_px", "y_px"]].to_numpy(dtype=float)
    bad = ~np.isfinite(coords).all(axis=1)
    if bad.any():
        frame = table["frame"].iloc[int(np.argmax(bad))]
        raise TrackError(f"frame {frame}: a candidate with a position that is not a number")
    table["frame"] = table["frame"].astype(int)
    if "score" not in table.columns:
        table["score"] = np.nan
    return table


def _empty_summary() -> pd.DataFrame:
    return pd.DataFrame({c: pd.Series(dtype=object) for c in TRACK_SUMMARY_UNITS})


def _summarise(linked: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for pid, track in linked.groupby("particle", sort=False):
        track = track.sort_values("frame")
        first, last = int(track["frame"].iloc[0]), int(track["frame"].iloc[-1])
        rows.append({
            "particle": pid,
            "first_frame": first,
            "last_frame": last,
            "n_frames": len(track),
            "n_gaps": last - first + 1 - len(track),
            "mean_score": float(track["score"].mean()),
            "x_px_start": float(track["x_px"].iloc[0]),
            "y_px_start": float(track["y_px"].iloc[0]),
        })
    return pd.DataFrame(rows)


def link_tracks(
    candidates: pd.DataFrame, pixel_size_um: float, options: LinkSettings | None = None
) -> LinkedTracks:
    """Link the hologram centres of every frame into tracks.

    Parameters
    ----------
    candidates : pandas.DataFrame
        Candidate centres: columns ``frame``, ``x_px``, ``y_px`` (full-frame pixels) and,
        optionally, ``score`` and any others (carried along).
    pixel_size_um : float
        Size of a camera pixel in the sample plane, um.
    options : LinkSettings, optional
        Linking settings.

    Returns
    -------
    LinkedTracks

    Raises
    ------
    TrackError
        Missing columns, non-finite positions, a bad pixel size or bad options.
    """
    import trackpy

    options = options or LinkSettings()
    if not (math.isfinite(pixel_size_um) and pixel_size_um > 0):
        raise TrackError(f"pixel_size_um must be a positive number, got {pixel_size_um!r}")
    table = _check_candidates(candidates)
    if table.empty:
        return LinkedTracks(table.assign(particle=pd.Series(dtype=int)), _empty_summary())
    work = table.reset_index(drop=True)
    work["x"], work["y"] = work["x_px"], work["y_px"]
    trackpy.quiet()
    search_px = options.search_range_um / pixel_size_um
    # adaptive search: a subnetwork too large to resolve (a crowded frame, a cluster of
    # fringe candidates) is linked again with a shorter search range instead of failing
    linked = trackpy.link(
        work, search_range=search_px, memory=options.memory,
        adaptive_stop=min(ADAPTIVE_STOP_UM / pixel_size_um, 0.5 * search_px),
        adaptive_step=0.9,
    )
    linked = linked.drop(columns=["x", "y"]).reset_index(drop=True)

    summary = _summarise(linked)
    # ids in order of first appearance, then of x: independent of trackpy's counter
    summary = summary.sort_values(["first_frame", "x_px_start"], kind="stable")
    long_enough = summary["n_frames"] >= options.min_track_length
    span = summary["last_frame"] - summary["first_frame"] + 1
    dense = summary["n_frames"] >= options.min_detected_fraction * span
    summary["kept"] = long_enough & dense
    summary["reason"] = [
        "" if k else
        f"{n} frames, fewer than min_track_length {options.min_track_length}" if not ln else
        f"detected in {n} of the {s} frames of its span, under min_detected_fraction "
        f"{options.min_detected_fraction:g} (sparse detections linked by the memory)"
        for k, ln, n, s in zip(summary["kept"], long_enough, summary["n_frames"], span,
                               strict=True)
    ]
    if options.max_particles is not None:
        ranked = summary[summary["kept"]].sort_values(
            ["n_frames", "mean_score"], ascending=False, kind="stable"
        )
        surplus = ranked.index[options.max_particles:]
        summary.loc[surplus, "kept"] = False
        summary.loc[surplus, "reason"] = (
            f"beyond the {options.max_particles} longest tracks (max_particles)"
        )
    kept = summary[summary["kept"]]
    new_ids = {old: new for new, old in enumerate(kept["particle"])}
    summary["particle"] = [new_ids.get(p, -1) for p in summary["particle"]]
    linked = linked[linked["particle"].isin(list(new_ids))].copy()
    linked["particle"] = linked["particle"].map(new_ids).astype(int)
    linked = linked.sort_values(["particle", "frame"], kind="stable").reset_index(drop=True)
    summary = summary.sort_values(
        ["kept", "particle", "first_frame"], ascending=[False, True, True], kind="stable"
    ).reset_index(drop=True)
    return LinkedTracks(linked, summary[list(TRACK_SUMMARY_UNITS)])


def track_reach(linked: pd.DataFrame) -> dict[int, float]:
    """Each track's reach, pixels: the median of its detections' ``reach_px`` (the radius
    within which its fringes stand above the noise, :mod:`holofit.crop.profile`; a track's
    median, since a single frame's profile can be lengthened by a neighbour); 0 where unknown
    (detections without it): then a neighbour overlaps a crop only if its centre lies in
    it."""
    reach: dict[int, float] = {}
    values = (linked["reach_px"] if "reach_px" in linked.columns
              else pd.Series(np.nan, index=linked.index))
    for p, r in values.groupby(linked["particle"]):
        r = r.to_numpy(dtype=float)
        r = r[np.isfinite(r) & (r > 0)]
        reach[int(p)] = float(np.median(r)) if r.size else 0.0
    return reach


def mark_neighbours(linked: pd.DataFrame, size: int | None = None) -> pd.DataFrame:
    """Add, to each (particle, frame), the nearest other track in that frame, and which
    other tracks' holograms reach into its crop.

    A track counts in the frames within its span where it was not detected too, at its
    linearly interpolated position: a hologram that merged into a neighbour's (closer than the
    centre finder resolves) still overlaps that neighbour's crop.

    Parameters
    ----------
    linked : pandas.DataFrame
        Columns ``particle``, ``frame``, ``x_px``, ``y_px`` (and ``reach_px``, for the
        overlap).
    size : int, optional
        Crop side, pixels: with it, ``overlap`` and ``n_overlapping`` are added. Another
        track's hologram reaches into the crop (a ``size`` square about the centre) when its
        centre is closer to the square than its reach (:func:`track_reach`): its fringes
        stand above the noise somewhere in the crop.

    Returns
    -------
    pandas.DataFrame
        A copy with ``neighbour`` (particle id, -1 if alone in the frame) and
        ``neighbour_px`` (centre-to-centre distance, pixels; inf if alone), and with
        ``size`` ``overlap`` (bool) and ``n_overlapping`` (count).

    Raises
    ------
    TrackError
        A (particle, frame) pair that occurs more than once.
    """
    dup = linked.duplicated(["particle", "frame"])
    if dup.any():
        row = linked[dup].iloc[0]
        raise TrackError(
            f"particle {int(row['particle'])} has more than one row in frame "
            f"{int(row['frame'])}: a track holds one hologram per frame"
        )
    out = linked.copy()
    n = len(out)
    hidden = hidden_positions(out)  # undetected holograms within their tracks' spans
    both = pd.concat([out[["particle", "frame", "x_px", "y_px"]], hidden], ignore_index=True)
    neighbour = np.full(len(both), -1, dtype=int)
    distance = np.full(len(both), np.inf)
    reaching = np.zeros(len(both), dtype=int)
    pos = both[["x_px", "y_px"]].to_numpy(dtype=float)
    ids = both["particle"].to_numpy()
    reach = track_reach(out) if size is not None else {}
    for rows in both.groupby("frame").indices.values():
        if len(rows) < 2:
            continue
        delta = pos[None, rows, :] - pos[rows, None, :]  # [i, j]: j's centre from i's
        d = np.hypot(delta[..., 0], delta[..., 1])
        np.fill_diagonal(d, np.inf)
        nearest = np.argmin(d, axis=1)
        neighbour[rows] = ids[rows][nearest]
        distance[rows] = d[np.arange(len(rows)), nearest]
        if size is not None:
            gap = np.hypot(*np.maximum(np.abs(delta) - size / 2.0, 0.0).transpose(2, 0, 1))
            into = gap < np.array([reach[int(q)] for q in ids[rows]])[None, :]
            np.fill_diagonal(into, False)
            reaching[rows] = into.sum(axis=1)
    out["neighbour"] = neighbour[:n]
    out["neighbour_px"] = distance[:n]
    if size is not None:
        out["n_overlapping"] = reaching[:n]
        out["overlap"] = reaching[:n] > 0
    return out


def hidden_positions(linked: pd.DataFrame) -> pd.DataFrame:
    """Where each track's hologram is, by linear interpolation, in the frames within its span
    where it was not detected (bridged by the linker's memory): usually hidden in a
    neighbour's, whose crop it then overlaps."""
    parts = []
    for p, track in linked.groupby("particle", sort=False):
        frames = track["frame"].to_numpy()
        order = np.argsort(frames)
        frames = frames[order]
        missing = np.setdiff1d(np.arange(frames[0], frames[-1] + 1), frames)
        if missing.size == 0:
            continue
        xs = np.interp(missing, frames, track["x_px"].to_numpy(dtype=float)[order])
        ys = np.interp(missing, frames, track["y_px"].to_numpy(dtype=float)[order])
        parts.append(pd.DataFrame({"particle": p, "frame": missing, "x_px": xs, "y_px": ys}))
    if not parts:
        return pd.DataFrame({"particle": pd.Series(dtype=int), "frame": pd.Series(dtype=int),
                             "x_px": pd.Series(dtype=float), "y_px": pd.Series(dtype=float)})
    return pd.concat(parts, ignore_index=True)


#: the former name, kept for existing code (deprecated)
LinkOptions = LinkSettings
