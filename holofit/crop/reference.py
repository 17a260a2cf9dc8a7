"""Reading background and dark frames: one frame, or a stack reduced by its per-pixel median."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from holofit.crop.errors import CropError
from holofit.io.movie import Movie, MovieError, open_movie

__all__ = ["MAX_REFERENCE_FRAMES", "read_dark", "read_reference_frame"]

#: Longer background / dark stacks are subsampled evenly to this many frames before the median
#: (memory stays bounded; the median of ~200 frames is as good as that of all).
MAX_REFERENCE_FRAMES = 201


def read_reference_frame(
    path: str | Path | Sequence[str | Path], what: str = "background"
) -> NDArray[np.float64]:
    """One reference frame from TIFF files, stacks or folders of frames.

    Parameters
    ----------
    path : str, Path, or a sequence of them
        A single frame, a multi-page TIFF, or a folder of TIFF frames; or several of these,
        whose frames are pooled (the per-pixel median of all of them is taken, as for one
        stack).
    what : str
        What it is, for error messages ("background", "dark frame").

    Returns
    -------
    ndarray of float64, shape (rows, cols)
        The frame, or the per-pixel median of all frames (at most
        :data:`MAX_REFERENCE_FRAMES` evenly spaced frames).

    Raises
    ------
    CropError
        Unreadable file, a frame that cannot be read (naming file and frame), files whose frames
        differ in shape, non-finite values.
    """
    paths = [Path(path)] if isinstance(path, str | Path) else [Path(p) for p in path]
    if not paths:
        raise CropError(f"no {what} given")
    movies: list[Movie] = []
    try:
        for p in paths:
            try:
                movies.append(open_movie(p))
            except MovieError as exc:
                raise CropError(f"{what}: {exc}") from None
            first, last = movies[0], movies[-1]
            if last.frame_shape != first.frame_shape:
                raise CropError(
                    f"{what}: {last.path} has frames of shape {tuple(last.frame_shape)}, "
                    f"{first.path} of shape {tuple(first.frame_shape)}"
                )
        return _median(movies, what)
    finally:
        for movie in movies:
            movie.close()


def _median(movies: list[Movie], what: str) -> NDArray[np.float64]:
    """Per-pixel median of the frames of ``movies`` taken together (subsampled evenly)."""
    index = [(m, k) for m in movies for k in range(len(m))]
    n = len(index)
    picks = (
        np.arange(n)
        if n <= MAX_REFERENCE_FRAMES
        else np.unique(np.linspace(0, n - 1, MAX_REFERENCE_FRAMES).round().astype(int))
    )
    dtype = np.result_type(*(m.dtype for m in movies))
    stack = np.empty((len(picks), *movies[0].frame_shape), dtype=dtype)
    for slot, i in enumerate(picks):
        movie, k = index[int(i)]
        try:
            stack[slot] = movie[k]
        except MovieError as exc:
            raise CropError(f"{what}: {exc}") from None
    if stack.dtype.kind == "f":
        bad = ~np.isfinite(stack)
        if bad.any():
            slot, row, col = (int(v) for v in np.unravel_index(int(np.argmax(bad)), bad.shape))
            movie, k = index[int(picks[slot])]
            raise CropError(
                f"{movie.path}: {what} has {int(bad.sum())} non-finite (NaN/inf) value(s), "
                f"first in frame {k} at row {row}, column {col}"
            )
    if stack.shape[0] == 1:
        return stack[0].astype(np.float64)
    return np.median(stack, axis=0).astype(np.float64)


def read_dark(
    dark: str | Path | Sequence[str | Path] | float | None,
) -> float | NDArray[np.float64] | None:
    """A dark level given as a number of counts, or as dark frame / stack files."""
    if dark is None:
        return None
    if isinstance(dark, int | float | np.integer | np.floating):
        value = float(dark)
        if not np.isfinite(value):
            raise CropError(f"dark count must be a finite number, got {dark!r}")
        return value
    return read_reference_frame(dark, "dark frame")
