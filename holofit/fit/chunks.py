"""A track cut into chunks (the batch's items when a pass follows the track) and stitched
back into one row per frame.

A chunk is a run of consecutive frames of one track that starts with a library fit and reaches
``overlap`` frames into the next chunk (:func:`plan_chunks`); it depends on the frames only,
so a rerun with other workers resumes the same chunks. :func:`stitch_chunks` joins one
track's chunks (in an overlap the earlier chunk's row is kept, reached warm along the track,
unless the two disagree and the later one fits better) and lists where they disagree;
:func:`stitch_table` does it for every track of a chunk table keyed by
:data:`CHUNK_KEY`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from holofit.status import ERROR

__all__ = [
    "CHUNK_KEY",
    "INITIAL_MIN_CHUNK",
    "INITIAL_OVERLAP",
    "MAX_CHUNK",
    "MIN_CHUNK",
    "MIN_CHUNKS",
    "OVERLAP",
    "consecutive_runs",
    "initial_min_chunk",
    "plan_chunks",
    "stitch_chunks",
    "stitch_table",
]

#: the key columns of a chunk table: a chunk is the item ``(particle, chunk, first frame)``,
#: its rows are keyed ``(particle, chunk, frame)``
CHUNK_KEY = ("particle", "chunk", "frame")
#: longest chunk (frames before the overlap)
MAX_CHUNK = 100
#: a short movie is still cut into up to this many chunks (parallel work) ...
MIN_CHUNKS = 8
#: ... of at least this many frames each
MIN_CHUNK = 12
#: frames a chunk of the final pass reaches into the next one
OVERLAP = 3
#: ... and of the initial pass: none. Its frames are direct DDA solves with sizes free, so an
#: overlap frame, fitted twice, lengthens the longest chunk by a whole frame, and the pass's
#: product, the static parameters' median, needs no stitching
INITIAL_OVERLAP = 0
#: the initial pass's shortest chunk (its default 8 frames: 2 chunks, one per worker)
INITIAL_MIN_CHUNK = 4


def consecutive_runs(frames: Sequence[int]) -> list[list[int]]:
    """``frames`` (sorted) cut where a frame does not follow its predecessor."""
    runs: list[list[int]] = []
    for f in sorted(int(x) for x in frames):
        if runs and f == runs[-1][-1] + 1:
            runs[-1].append(f)
        else:
            runs.append([f])
    return runs


def initial_min_chunk(n_frames: int) -> int:
    """The initial pass's shortest chunk for ``n_frames`` frames: a short initial pass is
    still cut in two, one chunk per worker of a 2-core machine."""
    if n_frames >= 2 * INITIAL_MIN_CHUNK:
        return INITIAL_MIN_CHUNK
    return max(n_frames // 2, 2)


def plan_chunks(frames: Sequence[int], overlap: int = OVERLAP,
                max_chunk: int = MAX_CHUNK, min_chunk: int = MIN_CHUNK) -> list[list[int]]:
    """Cut a track's frames (time order) into overlapping chunks.

    The number of chunks is ``ceil(n / max_chunk)``, raised for a short movie to up to
    :data:`MIN_CHUNKS` of at least ``min_chunk`` frames so that the workers share it; each
    chunk is its share of the frames plus the next share's first ``overlap`` frames.

    Returns
    -------
    list of list of int
        The chunks' frames, in time order.
    """
    frames = sorted(int(f) for f in frames)
    n = len(frames)
    if n == 0:
        return []
    if overlap < 0 or max_chunk < 1:
        raise ValueError("chunks: overlap >= 0 and max_chunk >= 1 needed")
    count = max(math.ceil(n / max_chunk), min(MIN_CHUNKS, n // max(min_chunk, 1)), 1)
    size = math.ceil(n / count)
    starts = list(range(0, n, size))
    return [frames[s:min(s + size + overlap, n)] for s in starts]


def stitch_chunks(
    chunks: Sequence[pd.DataFrame],
    head_tail: bool,
    position_tol_um: float = 0.02,
    axis_tol_rad: float = math.radians(2.0),
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Join the tables of overlapping chunks of one track (in time order).

    In an overlap the earlier chunk's row is kept (it was reached warm, along the track),
    unless the two disagree (position beyond ``position_tol_um`` or axis beyond
    ``axis_tol_rad``) and the later one has the lower chi^2.

    Parameters
    ----------
    chunks : sequence of pandas.DataFrame
        :func:`holofit.fit.follow.follow_chunk` tables, in time order.
    head_tail : bool
        The particle's axis u and -u are one orientation.
    position_tol_um, axis_tol_rad : float
        When two fits of one frame agree.

    Returns
    -------
    table : pandas.DataFrame
        One row per frame.
    disagreements : pandas.DataFrame
        ``frame, chunk, position_diff_um, axis_diff_rad, chi2_earlier, chi2_later, kept``
        for every overlapping frame whose fits disagree.
    """
    rows: dict[int, dict[str, Any]] = {}
    bad = []
    for i, chunk in enumerate(chunks):
        for row in chunk.to_dict("records"):
            frame = int(row["frame"])
            old = rows.get(frame)
            if old is None:
                rows[frame] = row
                continue
            dpos, dax = _row_difference(old, row, head_tail)
            if dpos <= position_tol_um and dax <= axis_tol_rad:
                continue
            later_better = float(row["chi2"]) < float(old["chi2"])
            bad.append({"frame": frame, "chunk": i, "position_diff_um": dpos,
                        "axis_diff_rad": dax, "chi2_earlier": float(old["chi2"]),
                        "chi2_later": float(row["chi2"]),
                        "kept": "later" if later_better else "earlier"})
            if later_better:
                rows[frame] = row
    table = pd.DataFrame([rows[k] for k in sorted(rows)])
    cols = ["frame", "chunk", "position_diff_um", "axis_diff_rad", "chi2_earlier",
            "chi2_later", "kept"]
    return table, pd.DataFrame(bad, columns=cols)


def _row_difference(a: dict[str, Any], b: dict[str, Any], head_tail: bool
                    ) -> tuple[float, float]:
    dpos = math.dist([a["x_um"], a["y_um"], a["z_um"]], [b["x_um"], b["y_um"], b["z_um"]])
    if "ux" not in a:
        return dpos, 0.0
    c = float(np.dot([a["ux"], a["uy"], a["uz"]], [b["ux"], b["uy"], b["uz"]]))
    return dpos, math.acos(min(1.0, abs(c) if head_tail else max(-1.0, c)))


def stitch_table(table: pd.DataFrame, chunks: Mapping[int, Sequence[Sequence[int]]],
                 head_tail: bool) -> tuple[pd.DataFrame, pd.DataFrame]:
    """One row per ``(particle, frame)`` from a chunk table keyed by :data:`CHUNK_KEY`, and
    the overlaps' disagreements (with ``particle``).

    ``chunks``: each track's planned chunks (:func:`plan_chunks`). A chunk that failed as a
    whole (one ``error`` row) gives its frames ``error`` rows with the chunk's message.
    """
    tracks, disagreements = [], []
    for p, planned in sorted(chunks.items()):
        mine = table[table["particle"] == p]
        parts, failed = [], []
        for i, frames in enumerate(planned):
            part = mine[mine["chunk"] == i].drop(columns=["chunk", "particle"])
            if len(part) == 1 and len(frames) > 1 and part["status"].iloc[0] == ERROR:
                msg = (f"chunk {i} (frames {frames[0]}-{frames[-1]}): "
                       f"{part['message'].iloc[0]}")
                failed += [{"frame": f, "status": ERROR, "message": msg} for f in frames]
                continue
            parts.append(part)
        rows, bad = stitch_chunks(parts, head_tail)
        have = set(rows["frame"].astype(int)) if len(rows) else set()
        extra = pd.DataFrame([r for r in failed if r["frame"] not in have])
        out = pd.concat([rows, extra], ignore_index=True) if len(extra) else rows
        if len(out):
            out = out.drop_duplicates("frame").sort_values("frame").reset_index(drop=True)
        tracks.append(out.assign(particle=p))
        disagreements.append(bad.assign(particle=p))
    stitched = pd.concat(tracks, ignore_index=True) if tracks else pd.DataFrame()
    bad = (pd.concat(disagreements, ignore_index=True) if disagreements
           else pd.DataFrame(columns=["particle"]))
    bad = bad[["particle", *[c for c in bad.columns if c != "particle"]]]
    return stitched, bad
