"""Saturation found in the data: a pile-up of pixels at the movie's top count.

The instrument's ``bit_depth`` gives the camera's full scale, ``2**bit_depth - 1``; but a
12-bit camera's movie is often stored in 16-bit files, and with ``bit_depth = 16`` its
saturated pixels (at 4095) would pass for data, and bias every fit that uses them. A sensor
that clips piles every count above its top into the top level, so that level holds more
pixels than the levels just below it, where an unclipped histogram's tail thins out toward
its maximum (a smooth fringe maximum spreads its pixels evenly over the last few levels).
:func:`find_pile_up` looks at a few frames and calls the top count saturated when, in most of
them, it holds at least :data:`MIN_PILE` pixels and :data:`PILE_RATIO` times as many as the
mean of the :data:`BELOW` levels under it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from holofit.io.movie import Movie, MovieError

__all__ = ["BELOW", "MIN_PILE", "PILE_RATIO", "PileUp", "find_pile_up"]

#: the top level must hold at least this many pixels (a handful of equal maxima is chance)
MIN_PILE = 10
#: ... and this many times the mean count of the levels below it
PILE_RATIO = 3.0
#: levels below the top that the pile-up is compared with
BELOW = 4
#: frames looked at (spread over the movie)
SAMPLE_FRAMES = 5


@dataclass(frozen=True)
class PileUp:
    """A saturation level found in the data.

    Attributes
    ----------
    level : float
        The top count, at which pixels are clipped.
    pixels_per_frame : float
        Mean number of pixels at that count in the frames looked at.
    frames : int
        Frames looked at.
    """

    level: float
    pixels_per_frame: float
    frames: int

    def describe(self, full_scale: float, bit_depth: int) -> str:
        """What was found and done, for the crop's warnings."""
        bits = int(np.log2(self.level + 1))
        camera = (f" (a {bits}-bit camera's top count)" if 2**bits - 1 == self.level else "")
        return (f"{self.pixels_per_frame:.0f} pixels a frame pile up at count {self.level:g}"
                f"{camera}, below the full scale {full_scale:g} of bit_depth {bit_depth}: the "
                "camera saturates there; pixels at or above it are masked (set bit_depth in "
                "the instrument config to the camera's, or --keep-saturated to use them)")


def _sample(n_frames: int) -> list[int]:
    if n_frames <= SAMPLE_FRAMES:
        return list(range(n_frames))
    return sorted({int(v) for v in np.rint(np.linspace(0, n_frames - 1, SAMPLE_FRAMES))})


def find_pile_up(movie: Movie, full_scale: float) -> PileUp | None:
    """The movie's top count if its pixels pile up there below ``full_scale`` (module
    docstring); None otherwise, or for float data."""
    if movie.dtype.kind not in "ui":
        return None
    tops, frames = [], []
    for k in _sample(len(movie)):
        try:
            frame = np.asarray(movie[k])
        except MovieError:
            continue
        frames.append(frame)
        tops.append(int(frame.max()))
    if not frames:
        return None
    top = max(tops)
    if top >= full_scale or top < BELOW + 1:
        return None  # at the full scale the bit depth masks it already
    piled = []
    for frame, t in zip(frames, tops, strict=True):
        if t != top:
            continue
        counts = np.bincount(frame.ravel()[frame.ravel() >= top - BELOW] - (top - BELOW),
                             minlength=BELOW + 1)
        below = float(counts[:BELOW].mean())
        if counts[BELOW] >= MIN_PILE and counts[BELOW] >= PILE_RATIO * below:
            piled.append(int(counts[BELOW]))
    if len(piled) * 2 <= len(frames):
        return None
    return PileUp(float(top), float(np.mean(piled)), len(frames))
