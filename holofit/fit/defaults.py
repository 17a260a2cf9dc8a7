"""Defaults of the fit stage that other modules need without importing the stage (e.g.
``holofit init``, which says what the fit will do)."""

from __future__ import annotations

__all__ = ["INITIAL_MAX", "INITIAL_MIN", "INITIAL_SHARE", "default_initial_frames"]

#: the initial pass's default length: one in INITIAL_SHARE of the frames that can be fitted,
#: at least INITIAL_MIN (as the demo) and at most INITIAL_MAX
#: (a 2000-frame movie: 100, as `make replicate`)
INITIAL_SHARE = 20
INITIAL_MIN = 8
INITIAL_MAX = 500


def default_initial_frames(n_fittable: int) -> int:
    """Frames of the initial pass when none are given: ``n / 20``, between 8 and 500 (and
    at most ``n``). The initial pass fits every parameter free by direct DDA solves, many
    times a final-pass frame's cost, so it takes a share of the movie, not all of it (docs:
    validation, "fits and replicates")."""
    share = -(-int(n_fittable) // INITIAL_SHARE)
    return max(min(max(share, INITIAL_MIN), INITIAL_MAX, int(n_fittable)), 1)
