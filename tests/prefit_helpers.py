"""Crop folders for the prefit tests, in the format `holofit crop` writes.

These helpers stand in for the crop stage in tests: `make_crops_from_frame` (one particle of
one normalised frame) and `make_crops_from_movie` (a simulated movie) write ``crops.tif``,
``crops.csv`` and its sidecar exactly as the crop stage's output contract says. The centre
they are given plays the role of the crop stage's finder; it must never be the answer the
test checks. Once the crop stage is merged, a test can call ``holofit.crop.run_crop`` instead
of these functions and keep everything else.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from holofit.config import Instrument
from holofit.io import open_movie, write_table
from holofit.io.tiffstack import TiffStackWriter
from holofit.provenance import sidecar

CROP_UNITS = {
    "frame": "index",
    "status": "ok | edge | no_particle | error",
    "message": "text",
    "x_px": "pixel (full-frame column)",
    "y_px": "pixel (full-frame row)",
    "x_um": "um",
    "y_um": "um",
    "corner_row": "pixel",
    "corner_col": "pixel",
    "score": "1",
    "n_candidates": "count",
}


def cut_crop(
    frame: NDArray, centre_xy_px: tuple[float, float], size: int
) -> tuple[NDArray[np.float32], tuple[int, int], str]:
    """Cut a ``size`` x ``size`` crop centred on the pixel nearest the centre.

    Returns the crop (NaN outside the frame), the full-frame corner ``(row, col)`` and the
    status ``ok`` or ``edge`` (the crop sticks out of the frame).
    """
    cx, cy = centre_xy_px
    r0 = round(cy) - size // 2
    c0 = round(cx) - size // 2
    out = np.full((size, size), np.nan, dtype=np.float32)
    rs = slice(max(r0, 0), min(r0 + size, frame.shape[0]))
    cs = slice(max(c0, 0), min(c0 + size, frame.shape[1]))
    out[rs.start - r0 : rs.stop - r0, cs.start - c0 : cs.stop - c0] = frame[rs, cs]
    inside = rs.stop - rs.start == size and cs.stop - cs.start == size
    return out, (r0, c0), "ok" if inside else "edge"


def write_crop_dir(
    out_dir: str | Path,
    crops: Sequence[NDArray],
    rows: Sequence[dict],
    instrument: Instrument,
) -> Path:
    """Write ``crops.tif``, ``crops.csv`` and ``crops.csv.json`` (instrument in ``config``)."""
    out = Path(out_dir)
    with TiffStackWriter(out / "crops.tif", {"holofit": "crops (test helper)"}) as writer:
        for c in crops:
            writer.write(np.asarray(c, dtype=np.float32))
    table = pd.DataFrame(list(rows), columns=list(CROP_UNITS))
    write_table(
        out / "crops.csv",
        table,
        sidecar(
            kind="crop table (test helper)",
            units=CROP_UNITS,
            config={"instrument": instrument.as_dict()},
        ),
    )
    return out


def _row(frame: int, centre: tuple[float, float], corner: tuple[int, int], status: str, px: float):
    return {
        "frame": frame,
        "status": status,
        "message": "",
        "x_px": centre[0],
        "y_px": centre[1],
        "x_um": centre[0] * px,
        "y_um": centre[1] * px,
        "corner_row": corner[0],
        "corner_col": corner[1],
        "score": 1.0,
        "n_candidates": 1,
    }


def make_crops_from_frame(
    frame: NDArray,
    centre_xy_px: tuple[float, float],
    crop_size: int,
    instrument: Instrument,
    out_dir: str | Path,
    saturated: NDArray[np.bool_] | None = None,
) -> Path:
    """A crop folder with one crop of one particle in a normalised frame.

    Parameters
    ----------
    frame : ndarray
        Normalised frame (background 1).
    centre_xy_px : tuple of float
        The finder's centre (column, row), full-frame pixels.
    crop_size : int
        Crop side, pixels.
    instrument : Instrument
        Recorded in the sidecar.
    out_dir : str or Path
        The crop folder.
    saturated : ndarray of bool, optional
        Pixels at the camera's maximum count: NaN in the crop (the crop contract).
    """
    data = np.asarray(frame, dtype=float).copy()
    if saturated is not None:
        data[saturated] = np.nan
    crop, corner, status = cut_crop(data, centre_xy_px, crop_size)
    row = _row(0, centre_xy_px, corner, status, instrument.pixel_size_um)
    return write_crop_dir(out_dir, [crop], [row], instrument)


def make_crops_from_movie(
    movie_path: str | Path,
    background_path: str | Path,
    centres_xy_px: Sequence[tuple[float, float] | None],
    crop_size: int,
    instrument: Instrument,
    out_dir: str | Path,
) -> Path:
    """A crop folder from a raw movie: divide by the mean background, mark pixels at the
    camera's maximum count as NaN, cut a crop around each frame's centre (None: no particle,
    a NaN crop with status ``no_particle``)."""
    return make_crops_from_movies(
        [(movie_path, background_path)], centres_xy_px, crop_size, instrument, out_dir
    )


def make_crops_from_movies(
    movies: Sequence[tuple[str | Path, str | Path]],
    centres_xy_px: Sequence[tuple[float, float] | None],
    crop_size: int,
    instrument: Instrument,
    out_dir: str | Path,
) -> Path:
    """Like :func:`make_crops_from_movie` for several ``(movie, background)`` pairs played one
    after the other (frames numbered on)."""
    full = 2**instrument.bit_depth - 1
    crops, rows = [], []
    k = 0
    for movie_path, background_path in movies:
        with open_movie(background_path) as bg:
            background = np.mean([np.asarray(f, dtype=float) for f in bg], axis=0)
        with open_movie(movie_path) as movie:
            for raw in movie:
                centre = centres_xy_px[k]
                if centre is None:
                    crops.append(np.full((crop_size, crop_size), np.nan, np.float32))
                    row = _row(k, (np.nan, np.nan), (0, 0), "no_particle", instrument.pixel_size_um)
                    row.update(message="no hologram found", corner_row=np.nan, corner_col=np.nan)
                    rows.append(row)
                else:
                    norm = np.asarray(raw, dtype=float) / background
                    norm[np.asarray(raw) >= full] = np.nan
                    crop, corner, status = cut_crop(norm, centre, crop_size)
                    crops.append(crop)
                    rows.append(_row(k, centre, corner, status, instrument.pixel_size_um))
                k += 1
    return write_crop_dir(out_dir, crops, rows, instrument)
