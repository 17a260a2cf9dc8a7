"""Placing an N x N crop around a centre, inside the frame."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = ["crop_corner", "extract_crop"]


def crop_corner(
    x_px: float, y_px: float, size: int, frame_shape: tuple[int, int]
) -> tuple[int, int, bool]:
    """Full-frame ``(row, column)`` of the crop's pixel ``[0, 0]``.

    The pixel nearest the centre becomes crop pixel ``[size // 2, size // 2]``; when that would
    take the crop past the frame's edge, the crop is shifted just inside it.

    Parameters
    ----------
    x_px, y_px : float
        Centre, full-frame pixels (x = column, y = row).
    size : int
        Crop side, pixels (at most the frame's smaller side).
    frame_shape : tuple of int
        ``(rows, cols)`` of the frame.

    Returns
    -------
    corner_row, corner_col : int
        Full-frame index of crop pixel ``[0, 0]``.
    shifted : bool
        True if the crop had to be moved to stay inside the frame (particle near the edge).
    """
    rows, cols = frame_shape
    if size > rows or size > cols:
        raise ValueError(f"crop size {size} does not fit in a frame of {rows} x {cols} pixels")
    row = math.floor(y_px + 0.5) - size // 2
    col = math.floor(x_px + 0.5) - size // 2
    row_in = min(max(row, 0), rows - size)
    col_in = min(max(col, 0), cols - size)
    return row_in, col_in, (row_in, col_in) != (row, col)


def extract_crop(image: NDArray, corner: tuple[int, int], size: int) -> NDArray[np.float32]:
    """Copy of ``image[row:row + size, col:col + size]`` as float32."""
    row, col = corner
    block = image[row : row + size, col : col + size]
    if block.shape != (size, size):
        raise ValueError(f"crop at {corner} of size {size} leaves the {image.shape} frame")
    return np.array(block, dtype=np.float32)
