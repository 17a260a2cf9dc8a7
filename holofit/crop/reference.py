"""Reading background and dark frames: one frame, or a stack reduced by its per-pixel median."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from holofit.crop.errors import CropError
from holofit.io.movie import MovieError, open_movie

__all__ = ["MAX_REFERENCE_FRAMES", "read_dark", "read_reference_frame"]

#: Longer background / dark stacks are subsampled evenly to this many frames before the median
#: (memory stays bounded; the median of ~200 frames is as good as that of all).
MAX_REFERENCE_FRAMES = 201


def read_reference_frame(path: str | Path, what: str = "background") -> NDArray[np.float64]:
    """One reference frame from a TIFF file, stack or folder of frames.

    Parameters
    ----------
    path : str or Path
        A single frame, a multi-page TIFF, or a folder of TIFF frames.
    what : str
        What it is, for error messages ("background", "dark frame").

    Returns
    -------
    ndarray of float64, shape (rows, cols)
        The frame, or the per-pixel median of the stack (at most
        :data:`MAX_REFERENCE_FRAMES` evenly spaced frames).

    Raises
    ------
    CropError
        Unreadable file, a frame that cannot be read (naming the frame), non-finite values.
    """
    try:
        with open_movie(path) as movie:
            n = len(movie)
            picks = (
                np.arange(n)
                if n <= MAX_REFERENCE_FRAMES
                else np.unique(np.linspace(0, n - 1, MAX_REFERENCE_FRAMES).round().astype(int))
            )
            stack = np.empty((len(picks), *movie.frame_shape), dtype=movie.dtype)
            for slot, index in enumerate(picks):
                stack[slot] = movie[int(index)]
    except MovieError as exc:
        raise CropError(f"{what}: {exc}") from None
    if stack.dtype.kind == "f":
        bad = ~np.isfinite(stack)
        if bad.any():
            k, row, col = np.unravel_index(int(np.argmax(bad)), bad.shape)
            raise CropError(
                f"{path}: {what} has {int(bad.sum())} non-finite (NaN/inf) value(s), first in "
                f"frame {picks[k]} at row {row}, column {col}"
            )
    if stack.shape[0] == 1:
        return stack[0].astype(np.float64)
    return np.median(stack, axis=0).astype(np.float64)


def read_dark(dark: str | Path | float | None) -> float | NDArray[np.float64] | None:
    """A dark level given as a number of counts, or as a dark frame / stack file."""
    if dark is None:
        return None
    if isinstance(dark, int | float | np.integer | np.floating):
        value = float(dark)
        if not np.isfinite(value):
            raise CropError(f"dark count must be a finite number, got {dark!r}")
        return value
    return read_reference_frame(dark, "dark frame")
