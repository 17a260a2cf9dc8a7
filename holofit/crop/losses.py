"""Tracks lost next to another hologram: reported, never silent.

When a hologram stops being detected while another is within reach, the finder has most
likely merged the two (their centres closer than it resolves, or one hidden in the other's
fringes) or the linker has given its detections to the neighbour; the analysis would then
see a track that ends, or a gap, with no hint why. :func:`track_losses` finds, for every
kept track,

``lost``
    its last detection before the movie's last frame,
``late``
    its first detection after the movie's first frame (the second half of a track split by
    a merge),
``undetected``
    each run of frames within its span without a detection (bridged by the linker's memory),

wherever another track's hologram is within reach at that frame: the two centres closer
than the larger of the two tracks' reaches (:func:`holofit.crop.tracks.track_reach`; 0 where
unknown: no report). A track that ends or starts with its centre within two zone radii of
the frame's edge (most of its central fringes outside) has left or entered the field of
view, and is not reported.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from holofit.crop.tracks import hidden_positions, track_reach

__all__ = ["LOSS_KINDS", "describe_losses", "track_losses"]

#: what happened to a track next to another hologram
LOSS_KINDS = {
    "lost": "not detected after its last frame",
    "late": "not detected before its first frame",
    "undetected": "not detected in these frames within its span",
}
#: a centre within this many zone radii of the frame's edge has left (or entered) it
EDGE_ZONES = 2.0


def _positions(linked: pd.DataFrame) -> pd.DataFrame:
    """Every track's centre in every frame of its span (detected or interpolated)."""
    cols = ["particle", "frame", "x_px", "y_px"]
    return pd.concat([linked[cols], hidden_positions(linked)], ignore_index=True)


def _zone(linked: pd.DataFrame, p: int) -> float:
    zone = linked.loc[linked["particle"] == p, "zone_px"] if "zone_px" in linked else []
    values = np.asarray(zone, dtype=float)
    values = values[np.isfinite(values)]
    return float(np.median(values)) if values.size else 0.0


def track_losses(linked: pd.DataFrame, n_frames: int, frame_shape: tuple[int, int],
                 pixel_size_um: float) -> list[dict[str, Any]]:
    """Where a track is lost, starts late or goes undetected next to another hologram.

    Parameters
    ----------
    linked : pandas.DataFrame
        The kept tracks' detections: ``particle``, ``frame``, ``x_px``, ``y_px`` and
        ``reach_px``, ``zone_px`` (:mod:`holofit.crop.profile`).
    n_frames : int
        Frames in the movie.
    frame_shape : tuple of int
        ``(rows, cols)`` of the frames.
    pixel_size_um : float
        Pixel size in the sample plane, um.

    Returns
    -------
    list of dict
        One per event, in track then frame order: ``particle``, ``kind``
        (:data:`LOSS_KINDS`), ``first_frame``, ``last_frame`` (the frames concerned),
        ``neighbour`` (the nearest track within reach) and ``distance_um`` (centre to centre,
        at the frame where it happened).
    """
    if linked.empty or linked["particle"].nunique() < 2:
        return []
    reach = track_reach(linked)
    where = _positions(linked).set_index(["frame", "particle"]).sort_index()
    rows, cols = frame_shape
    events: list[dict[str, Any]] = []

    def neighbour_at(p: int, frame: int, x: float, y: float) -> tuple[int, float] | None:
        if frame not in where.index.get_level_values(0):
            return None
        here = where.loc[frame]
        best = None
        for q, r in here.iterrows():
            q = int(q)
            if q == p:
                continue
            d = math.hypot(float(r["x_px"]) - x, float(r["y_px"]) - y)
            if d < max(reach[p], reach[q]) and (best is None or d < best[1]):
                best = (q, d)
        return best

    def at_edge(x: float, y: float, zone: float) -> bool:
        margin = EDGE_ZONES * zone
        return min(x, y, cols - 1 - x, rows - 1 - y) < margin

    def add(p: int, kind: str, first: int, last: int, frame: int, x: float, y: float) -> None:
        near = neighbour_at(p, frame, x, y)
        if near is not None:
            events.append({"particle": p, "kind": kind, "first_frame": int(first),
                           "last_frame": int(last), "neighbour": near[0],
                           "distance_um": round(near[1] * pixel_size_um, 3)})

    for p, track in linked.groupby("particle"):
        p = int(p)
        track = track.sort_values("frame")
        frames = track["frame"].to_numpy(dtype=int)
        xs, ys = track["x_px"].to_numpy(dtype=float), track["y_px"].to_numpy(dtype=float)
        zone = _zone(linked, p)
        if frames[0] > 0 and not at_edge(xs[0], ys[0], zone):
            add(p, "late", 0, frames[0] - 1, int(frames[0]), xs[0], ys[0])
        for k in np.nonzero(np.diff(frames) > 1)[0]:
            first, last = frames[k] + 1, frames[k + 1] - 1
            add(p, "undetected", first, last, int(first), float(np.interp(first, frames, xs)),
                float(np.interp(first, frames, ys)))
        if frames[-1] < n_frames - 1 and not at_edge(xs[-1], ys[-1], zone):
            add(p, "lost", frames[-1] + 1, n_frames - 1, int(frames[-1]), xs[-1], ys[-1])
    return events


def describe_losses(events: list[dict[str, Any]], shown: int = 5) -> str | None:
    """One warning line for ``events`` (None without any)."""
    if not events:
        return None
    words = {"lost": "lost from frame {first}", "late": "found only from frame {next}",
             "undetected": "undetected in frames {first}-{last}"}
    parts = []
    for e in events[:shown]:
        what = words[e["kind"]].format(first=e["first_frame"], last=e["last_frame"],
                                       next=e["last_frame"] + 1)
        parts.append(f"track {e['particle']} {what} (track {e['neighbour']} "
                     f"{e['distance_um']:.2f} um away)")
    more = f" (and {len(events) - shown} more)" if len(events) > shown else ""
    return (f"{len(events)} time(s) a track was not detected next to another hologram within "
            "reach (merged with it or hidden in its fringes; the sidecar's track_losses "
            "lists them all): " + "; ".join(parts) + more)
