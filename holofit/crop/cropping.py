"""Placing an N x N crop around a centre, inside the frame, and the crop-table row it fills."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from holofit.status import CROP_EDGE, CROP_ERROR, CROP_OK

__all__ = ["blank_row", "crop_chosen", "crop_corner", "extract_crop"]


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


def blank_row(k: int) -> dict[str, Any]:
    """Frame ``k``'s row before anything is known of it (status ``error``)."""
    return {
        "particle": 0,
        "frame": k,
        "status": CROP_ERROR,
        "message": "",
        "x_px": math.nan,
        "y_px": math.nan,
        "x_um": math.nan,
        "y_um": math.nan,
        "corner_row": pd.NA,
        "corner_col": pd.NA,
        "score": math.nan,
        "alignment": math.nan,
        "symmetry": math.nan,
        "refinement": "",
        "zone_px": math.nan,
        "reach_px": math.nan,
        "n_candidates": 0,
        "n_masked": 0,
        "neighbour": -1,
        "neighbour_px": math.inf,
        "overlap": False,
        "n_overlapping": 0,
    }


def crop_chosen(row: dict[str, Any], best: pd.Series, image: NDArray, mask: NDArray,
                 size: int, pixel_size_um: float) -> NDArray:
    """Crop around the chosen candidate ``best``: fill in ``row``; the crop."""
    x, y = float(best["x_px"]), float(best["y_px"])
    corner_row, corner_col, shifted = crop_corner(x, y, size, image.shape)
    row.update(
        status=CROP_EDGE if shifted else CROP_OK,
        message="particle near the frame edge: crop shifted inside the frame"
        if shifted
        else "",
        x_px=x,
        y_px=y,
        x_um=x * pixel_size_um,
        y_um=y * pixel_size_um,
        corner_row=corner_row,
        corner_col=corner_col,
        score=float(best["score"]),
        alignment=float(best["alignment"]),
        symmetry=float(best["symmetry"]),
        refinement=str(best["refinement"]),
        zone_px=float(best["zone_px"]),
        reach_px=float(best["reach_px"]),
        n_masked=int(
            mask[corner_row : corner_row + size, corner_col : corner_col + size].sum()
        ),
    )
    return extract_crop(image, (corner_row, corner_col), size)
