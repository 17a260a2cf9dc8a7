"""Choosing which of a frame's candidate centres is *the* particle.

``strongest``: the best-ranked candidate of every frame, frame by frame independent. With two
particles in view the strongest can change from one to the other; :func:`off_track` then finds
the frames whose centre left the movie's main track (a jump larger than ``max_jump_px``), which
the crop stage marks ``off_track`` (not fitted) and reports.
``nearest``: the candidate nearest the particle's last known position (the user's start point
for the first frame, or the first frame's strongest candidate); a frame whose nearest candidate
is farther than ``max_jump_px`` has no particle, and the last known position is kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

__all__ = ["FOLLOW_MODES", "Follower", "Selection", "Tracks", "off_track"]

FOLLOW_MODES = ("strongest", "nearest")


@dataclass(frozen=True)
class Selection:
    """The chosen candidate of one frame (``index`` None: no particle, ``message`` says why)."""

    index: int | None
    message: str = ""


class Follower:
    """Picks one candidate per frame.

    Parameters
    ----------
    mode : {"strongest", "nearest"}
        How to choose.
    start : tuple of float, optional
        ``(x_px, y_px)`` where the particle is in the first frame (``nearest`` only).
    max_jump_px : float
        Largest accepted move between successive detections (``nearest`` only), pixels.
    """

    def __init__(
        self,
        mode: str = "strongest",
        start: tuple[float, float] | None = None,
        max_jump_px: float = 35.0,
    ) -> None:
        if mode not in FOLLOW_MODES:
            raise ValueError(f"follow must be one of {', '.join(FOLLOW_MODES)}, got {mode!r}")
        if start is not None and mode != "nearest":
            raise ValueError("a start point is only used with follow='nearest'")
        if not max_jump_px > 0:
            raise ValueError(f"max_jump_px must be > 0, got {max_jump_px}")
        self.mode = mode
        self.start = None if start is None else (float(start[0]), float(start[1]))
        self.max_jump_px = float(max_jump_px)
        self.last: tuple[float, float] | None = self.start

    def choose(self, candidates: pd.DataFrame) -> Selection:
        """Select from a ranked candidate table (columns ``x_px``, ``y_px``)."""
        if len(candidates) == 0:
            return Selection(None, "no hologram found")
        if self.mode == "strongest" or self.last is None:
            self.last = (float(candidates["x_px"].iat[0]), float(candidates["y_px"].iat[0]))
            return Selection(0)
        dist = np.hypot(
            candidates["x_px"].to_numpy() - self.last[0],
            candidates["y_px"].to_numpy() - self.last[1],
        )
        k = int(np.argmin(dist))
        if dist[k] > self.max_jump_px:
            return Selection(
                None,
                f"nearest candidate is {dist[k]:.1f} px from the last position "
                f"({self.last[0]:.1f}, {self.last[1]:.1f}) > max jump {self.max_jump_px:g} px",
            )
        self.last = (float(candidates["x_px"].iat[k]), float(candidates["y_px"].iat[k]))
        return Selection(k)


@dataclass(frozen=True)
class Tracks:
    """The tracks :func:`off_track` found.

    Attributes
    ----------
    label : ndarray of int
        Per frame, its track (0 the main one, the longest); -1 for frames without a centre.
    jumps : list of int
        Frames whose centre is more than the max jump from the previous centre.
    """

    label: NDArray[np.int64]
    jumps: list[int]

    @property
    def off(self) -> NDArray[np.bool_]:
        """Frames on a track other than the main one."""
        return self.label > 0

    @property
    def n_tracks(self) -> int:
        return int(self.label.max()) + 1 if self.label.size and self.label.max() >= 0 else 0


def off_track(x_px: ArrayLike, y_px: ArrayLike, max_jump_px: float) -> Tracks:
    """Split a movie's chosen centres into tracks at jumps larger than ``max_jump_px``.

    Consecutive centres (frames without one, NaN, are passed over) further apart than
    ``max_jump_px`` start a new segment; a segment joins the earlier track whose last centre
    is nearest its first, if that is within ``max_jump_px`` times the square root of the
    frames between them (diffusion), else it starts a track of its own. The track with the
    most frames is the main one (label 0; the earlier one on a tie); the others (another
    particle that was the strongest for a while, false detections) are labelled 1, 2, ...

    Parameters
    ----------
    x_px, y_px : array_like
        Per frame, the chosen centre (NaN: none), pixels.
    max_jump_px : float
        Largest move between successive frames of one particle, pixels.

    Returns
    -------
    Tracks
    """
    x = np.asarray(x_px, dtype=float)
    y = np.asarray(y_px, dtype=float)
    label = np.full(x.size, -1, dtype=np.int64)
    found = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
    if found.size == 0:
        return Tracks(label, [])
    # segments: runs of centres without a jump
    step = np.hypot(np.diff(x[found]), np.diff(y[found]))
    cut = np.flatnonzero(step > max_jump_px) + 1
    jumps = [int(found[c]) for c in cut]
    segments = np.split(found, cut)
    ends: list[int] = []  # per track, the frame of its last centre
    for seg in segments:
        first = int(seg[0])
        best, best_d = -1, np.inf
        for t, last in enumerate(ends):
            d = float(np.hypot(x[first] - x[last], y[first] - y[last]))
            if d <= max_jump_px * np.sqrt(max(first - last, 1)) and d < best_d:
                best, best_d = t, d
        if best < 0:
            ends.append(int(seg[-1]))
            best = len(ends) - 1
        else:
            ends[best] = int(seg[-1])
        label[seg] = best
    sizes = np.bincount(label[found], minlength=len(ends))
    # main track first (most frames; the earlier on a tie), then by first appearance
    order = sorted(range(len(ends)), key=lambda t: (t != int(np.argmax(sizes)), t))
    relabel = np.empty(len(ends), dtype=np.int64)
    relabel[order] = np.arange(len(ends))
    label[found] = relabel[label[found]]
    return Tracks(label, jumps)
