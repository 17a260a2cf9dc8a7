"""The crop table (``crops.csv``) and candidate table: their columns and units, defined once
for the stage that writes them (:mod:`holofit.crop.stage`) and the stages that read them
(:mod:`holofit.tables.cropset`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd

from holofit.io.tables import sidecar_path, write_json, write_table
from holofit.provenance import sidecar
from holofit.status import CROP_STATUS_MEANINGS, describe

__all__ = [
    "CANDIDATE_UNITS",
    "CROP_COLUMNS",
    "CROP_UNITS",
    "REQUIRED_CROP_COLUMNS",
    "crop_extra",
    "keyed_columns",
    "merge_suspects",
    "stack_header",
    "write_candidates",
    "write_crop_table",
]

CROP_UNITS = {
    "particle": "track id (0, 1, ... in order of first appearance; 0 with one particle)",
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
    "refinement": ("symmetry | radial (near an edge) | peeled (found with a neighbour's "
                   "rings subtracted) | none (coarse centre)"),
    "zone_px": ("pixel (radius of the hologram's first Fresnel zone, sqrt(lambda_m |z|), "
                "from its fringes' zero crossings: holofit.crop.profile)"),
    "reach_px": ("pixel (radius within which the hologram's fringes stand above the pixel "
                 "noise: holofit.crop.profile)"),
    "n_candidates": "count (accepted candidate centres in the frame)",
    "n_masked": "pixels (masked, NaN, in the crop)",
    "neighbour": "track id of the nearest other track in the frame (-1: none)",
    "neighbour_px": "pixel, centre-to-centre distance to it (inf: none)",
    "overlap": "bool (another track's hologram reaches into the crop: its centre is closer "
               "to the crop's square than its reach, the track's median reach_px)",
    "n_overlapping": "count (other tracks whose holograms reach into the crop)",
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
    "zone_px": CROP_UNITS["zone_px"],
    "reach_px": CROP_UNITS["reach_px"],
    "selected": "bool (the candidate cropped in this frame)",
    "particle": "track id of the candidate (-1: in no kept track)",
}

#: columns of ``crops.csv``, in order
CROP_COLUMNS: tuple[str, ...] = tuple(CROP_UNITS)
#: columns a reader of a crop folder needs
REQUIRED_CROP_COLUMNS: tuple[str, ...] = (
    "frame", "status", "x_um", "y_um", "corner_row", "corner_col",
)


def keyed_columns(columns: tuple[str, ...], key_columns: tuple[str, ...]) -> tuple[str, ...]:
    """A stage table's ``columns`` with the key columns it lacks in front (``particle`` for
    crops of several tracks)."""
    return (*(c for c in key_columns if c not in columns), *columns)


def stack_header(size: int, n_frames: int) -> dict[str, Any]:
    """The description stored in the crop stack (``crops.tif``) itself."""
    return {
        "holofit": "crop stack",
        "size": size,
        "frames": n_frames,
        "table": "crops.csv",
        "pixels": "float32, normalised (background ~1), NaN = masked or no crop",
    }


def crop_extra(settings: dict[str, Any], movie: dict[str, Any], stack: Path, table: Path,
               pages: int, size: int, counts: dict[str, int],
               warnings: list[str], losses: list[dict[str, Any]] | None = None
               ) -> dict[str, Any]:
    """The ``extra`` of the crop stack's and the crop table's sidecars: the settings, the
    movie (``movie``: frames, frame_shape, dtype, problems, reader_notes), the stack's
    layout, the status counts, the warnings and ``track_losses``: every time a track was
    lost, started late or went undetected next to another hologram within reach
    (:func:`holofit.crop.losses.track_losses`; tracks mode)."""
    return {
        "track_losses": list(losses or []),
        "settings": settings,
        "movie": movie,
        "crops": {
            "file": stack.name,
            "table": table.name,
            "pages": pages,
            "page_shape": [size, size],
            "dtype": "float32",
            "contents": "normalised hologram (background ~1), one page per row of the "
            "table, in its order (frame, then particle); NaN marks masked pixels "
            "(background ~0 or saturated); frames with "
            "status no_particle or error get an all-NaN page",
            "coordinates": "crop pixel [i, j] is full-frame pixel "
            "[corner_row + i, corner_col + j] (corner_* in the table)",
        },
        "status_counts": counts,
        "warnings": warnings,
    }


def write_candidates(path: Path, candidates: list[tuple[Any, ...]], instrument: dict[str, Any],
                     inputs: list[str | Path], settings: dict[str, Any]) -> pd.DataFrame:
    """Write ``candidates.csv`` (+ sidecar) from rows of :data:`CANDIDATE_UNITS`; the table."""
    table = pd.DataFrame(candidates, columns=list(CANDIDATE_UNITS))
    write_table(path, table, sidecar(kind="crop candidates", units=CANDIDATE_UNITS,
                                     config={"instrument": instrument}, inputs=inputs,
                                     extra={"settings": settings}))
    return table


def write_crop_table(table_path: Path, stack_path: Path, frames: pd.DataFrame,
                     instrument: dict[str, Any], inputs: list[str | Path],
                     extra: dict[str, Any]) -> None:
    """Write the crop stack's sidecar, then ``crops.csv`` (+ sidecar): the table goes last,
    its presence marks a complete run."""
    config = {"instrument": instrument}
    write_json(sidecar_path(stack_path),
               sidecar(kind="crop stack", units={"pixel value": "1 (background = 1)"},
                       config=config, inputs=inputs, extra=extra))
    write_table(table_path, frames, sidecar(kind="crop table", units=CROP_UNITS, config=config,
                                            inputs=inputs, extra=extra))


def _span(event: dict[str, Any]) -> tuple[int, int]:
    return int(event["first_frame"]), int(event["last_frame"])


def merge_suspects(losses: list[dict[str, Any]]) -> dict[int, set[int]]:
    """The frames of each track whose hologram may hold a lost neighbour's, from the crop
    sidecar's ``track_losses`` (:func:`crop_extra`).

    A neighbour ``undetected`` within reach for frames ``a..b`` makes those frames suspect; a
    neighbour ``lost`` within reach from frame ``f`` and another one that starts ``late``
    within reach at frame ``s > f`` make ``f..s-1`` suspect (the two halves of a track split
    by a merge); a loss or a late start with no such partner makes its whole span suspect.
    Such frames look like a lone particle (no other track is there to mark an overlap) while
    the finder may have merged two holograms into one, so a static size or index measured on
    them is not the particle's.

    Parameters
    ----------
    losses : list of dict
        Loss events (``particle``, ``kind``, ``first_frame``, ``last_frame``,
        ``neighbour``).

    Returns
    -------
    dict of int to set of int
        Track id -> frames suspected of a merge (tracks without any left out).
    """
    out: dict[int, set[int]] = {}
    by_neighbour: dict[int, list[dict[str, Any]]] = {}
    for e in losses:
        if e.get("neighbour") is not None and e.get("kind") in ("lost", "late", "undetected"):
            by_neighbour.setdefault(int(e["neighbour"]), []).append(e)
    for p, events in by_neighbour.items():
        frames: set[int] = set()
        lost = sorted((e for e in events if e["kind"] == "lost"), key=_span)
        late = sorted((e for e in events if e["kind"] == "late"), key=lambda e: _span(e)[1])
        paired: set[int] = set()
        for e in lost:
            start = _span(e)[0]
            partner = next((j for j, g in enumerate(late)
                            if j not in paired and _span(g)[1] + 1 > start), None)
            if partner is None:
                frames.update(range(start, _span(e)[1] + 1))
                continue
            paired.add(partner)
            frames.update(range(start, _span(late[partner])[1] + 1))
        for j, g in enumerate(late):
            if j not in paired:
                frames.update(range(_span(g)[0], _span(g)[1] + 1))
        for e in events:
            if e["kind"] == "undetected":
                frames.update(range(_span(e)[0], _span(e)[1] + 1))
        if frames:
            out[p] = frames
    return out
