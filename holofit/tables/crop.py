"""The crop table (``crops.csv``) and candidate table: their columns and units, defined once
for the stage that writes them (:mod:`holofit.crop.stage`) and the stages that read them
(:mod:`holofit.tables.cropset`)."""

from __future__ import annotations

from holofit.status import CROP_STATUS_MEANINGS, describe

__all__ = ["CANDIDATE_UNITS", "CROP_COLUMNS", "CROP_UNITS", "REQUIRED_CROP_COLUMNS"]

CROP_UNITS = {
    "frame": "index (0-based, movie order)",
    "status": describe(CROP_STATUS_MEANINGS),
    "message": "text (why a frame is edge, no_particle or error)",
    "x_px": "pixel, full frame (column; pixel centres are integers)",
    "y_px": "pixel, full frame (row)",
    "x_um": "um (x_px * pixel_size_um)",
    "y_um": "um (y_px * pixel_size_um)",
    "corner_row": "pixel index, full frame, of crop pixel [0, 0] (empty: no crop)",
    "corner_col": "pixel index, full frame, of crop pixel [0, 0] (empty: no crop)",
    "score": "1 (transform peak / rms transform of pure noise at the frame's noise level)",
    "alignment": "1 (0-1: fraction of nearby gradient energy pointing at the centre)",
    "symmetry": "1 (-1..1: point symmetry about the centre; 1 = perfect)",
    "refinement": "symmetry | radial (near an edge) | none (coarse centre)",
    "n_candidates": "count (accepted candidate centres in the frame)",
    "n_masked": "pixels (masked, NaN, in the crop)",
}

CANDIDATE_UNITS = {
    "frame": "index",
    "rank": "0 = strongest",
    "x_px": CROP_UNITS["x_px"],
    "y_px": CROP_UNITS["y_px"],
    "score": CROP_UNITS["score"],
    "alignment": CROP_UNITS["alignment"],
    "symmetry": CROP_UNITS["symmetry"],
    "refinement": CROP_UNITS["refinement"],
    "selected": "bool (the candidate cropped in this frame)",
}

#: columns of ``crops.csv``, in order
CROP_COLUMNS: tuple[str, ...] = tuple(CROP_UNITS)
#: columns a reader of a crop folder needs
REQUIRED_CROP_COLUMNS: tuple[str, ...] = (
    "frame", "status", "x_um", "y_um", "corner_row", "corner_col",
)
