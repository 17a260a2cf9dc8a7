"""Choosing which of a frame's candidate centres is *the* particle.

``strongest``: the best-ranked candidate of every frame, frame by frame independent.
``nearest``: the candidate nearest the particle's last known position (the user's start point
for the first frame, or the first frame's strongest candidate); a frame whose nearest candidate
is farther than ``max_jump_px`` has no particle, and the last known position is kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

__all__ = ["FOLLOW_MODES", "Follower", "Selection"]

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
