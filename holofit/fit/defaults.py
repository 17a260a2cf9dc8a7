"""Defaults of the fit stage that other modules need without importing the stage (e.g.
``holofit init``, which says what the fit will do)."""

from __future__ import annotations

__all__ = ["INITIAL_MAX", "INITIAL_MIN", "INITIAL_SHARE", "INITIAL_SHORT_MIN",
           "INITIAL_SHORT_SHARE",
           "default_initial_frames", "initial_rule"]

#: the initial pass's default length: one in INITIAL_SHARE of the frames that can be fitted,
#: at least INITIAL_MIN (as the demo) and at most INITIAL_MAX
#: (a 2000-frame movie: 100, as `make replicate`)
INITIAL_SHARE = 20
INITIAL_MIN = 8
INITIAL_MAX = 500
#: ... but never more than one in INITIAL_SHORT_SHARE (a movie shorter than 6 x 8 frames),
#: unless that leaves fewer than INITIAL_SHORT_MIN (the fewest with a spread: static.json)
INITIAL_SHORT_SHARE = 6
INITIAL_SHORT_MIN = 3


def default_initial_frames(n_fittable: int) -> int:
    """Frames of the initial pass when none are given: ``n / 20``, between 8 and 500, and at
    most ``n / 6`` (rounded up; a 24-frame movie's 4) unless that is under 3 (and at most
    ``n``). The initial pass fits every parameter
    free by direct DDA solves (a rod frame ~6 s, a Janus frame a minute or more on one core),
    the final pass from the T-matrix (~0.2 s): a 30-frame movie's initial pass on all its
    frames was most of its run, and a 24-frame Janus movie's on 8 of them still most of its
    set-up."""
    n = int(n_fittable)
    share = -(-n // INITIAL_SHARE)
    short = max(-(-n // INITIAL_SHORT_SHARE), INITIAL_SHORT_MIN)
    return max(min(max(share, INITIAL_MIN), short, INITIAL_MAX, n), 1)


def initial_rule() -> str:
    """The default rule in words (for the notes of ``holofit fit`` and ``holofit init``)."""
    return (f"1 in {INITIAL_SHARE}, at least {INITIAL_MIN} but at most 1 in "
            f"{INITIAL_SHORT_SHARE} (or {INITIAL_SHORT_MIN}), at most {INITIAL_MAX}")
