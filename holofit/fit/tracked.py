"""The tracking final pass as a batch: chunks of the track are the items.

The final pass follows the track (:mod:`holofit.fit.tracking`): each frame is fitted from its
predecessor's fit. To run in parallel and resume, the track (today one per crop folder) is
cut into *chunks* (:func:`plan_chunks`): consecutive runs of frames, each starting with a full
library fit and reaching ``overlap`` frames into the next chunk. A chunk is one item of the
batch runner (:mod:`holofit.batch.runner`), a *multi-row item*: its rows are keyed by
``(chunk, frame)`` in ``fit_chunks.csv`` (journal, partial table and resume as for any stage;
a finished chunk is never redone). :func:`stitch_table` joins the chunks into one row per
frame (:func:`holofit.fit.tracking.stitch_chunks`: in an overlap the earlier chunk's warm row
is kept unless the two disagree and the later fits better) and lists where the overlaps
disagree.

The movie's chi^2 bar (:func:`holofit.fit.continuity.chi2_bar`, as the continuity sweeps
compute it) is taken from the initial pass's table (:func:`bar_from_initial`): the final pass
needs it before any of its chunks runs, and the initial pass is the one table of this movie
fitted before it; its ``ok`` rows count (rows clearly worse than the pass's best are
``poor_fit``: :mod:`holofit.fit.initial_level`). A short movie's initial pass has fewer than 10
such frames, too few to measure the movie's spread: its bar
(:func:`holofit.fit.continuity.small_sample_bar`) takes the spread at least from the noise
model (the chi^2 distribution of the pixel count plus a floor for the excess scatter), widened
for the few frames. Only a movie without any ``ok`` initial frame has no bar (a warm fit is
then checked by its status and its step only).

The initial pass's converged rows are also each frame's independent check
(:func:`initial_poses`; :mod:`holofit.fit.tracking`, step 6): the final pass evaluates the
hologram at the initial row's pose, and where that beats the track's fit it refits from there;
:func:`initial_check_summary` counts what the check did.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.batch.runner import Precomputed
from holofit.batch.stage import FrameLoader, fingerprint
from holofit.fit.continuity import EXCESS_FLOOR, chi2_bar, small_sample_bar
from holofit.fit.frame import fit_frame_warm
from holofit.fit.task import FitConfig, worker_theory
from holofit.fit.tracking import (
    INITIAL_POSE,
    ChunkFrame,
    TrackOptions,
    state_of,
    stitch_chunks,
    track_chunk,
)
from holofit.io.tables import read_table, write_json
from holofit.status import ERROR, OK, POOR_FIT

__all__ = [
    "CHUNK_KEY",
    "INITIAL_MIN_CHUNK",
    "INITIAL_OVERLAP",
    "MIN_CHUNK",
    "OVERLAP",
    "ChunkPayload",
    "TrackedConfig",
    "bar_from_initial",
    "chunk_loader",
    "consecutive_runs",
    "final_bar",
    "initial_check_summary",
    "initial_poses",
    "initial_refits",
    "plan_chunks",
    "stitch_table",
    "track_chunk_task",
]

def consecutive_runs(frames: Sequence[int]) -> list[list[int]]:
    """``frames`` (sorted) cut where a frame does not follow its predecessor."""
    runs: list[list[int]] = []
    for f in sorted(int(x) for x in frames):
        if runs and f == runs[-1][-1] + 1:
            runs[-1].append(f)
        else:
            runs.append([f])
    return runs


#: the key columns of the chunk table
CHUNK_KEY = ("chunk", "frame")
#: longest chunk (frames before the overlap)
MAX_CHUNK = 100
#: a short movie is still cut into up to this many chunks (parallel work) ...
MIN_CHUNKS = 8
#: ... of at least this many frames each
MIN_CHUNK = 12
#: frames a chunk of the final pass reaches into the next one
OVERLAP = 3
#: ... and of the initial pass: none. Its frames are direct DDA solves with sizes free (a
#: Janus frame costs tens of solves), so an overlap frame, fitted twice, lengthens the longest
#: chunk (the pass's wall time on a few workers) by a whole frame, and the pass's product, the
#: static parameters' median, needs no stitching: every chunk starts from the library
INITIAL_OVERLAP = 0
#: the initial pass's shortest chunk (its default 8 frames: 2 chunks, one per worker)
INITIAL_MIN_CHUNK = 4


def plan_chunks(frames: Sequence[int], overlap: int = OVERLAP,
                max_chunk: int = MAX_CHUNK, min_chunk: int = MIN_CHUNK) -> list[list[int]]:
    """Cut a track's frames (time order) into overlapping chunks.

    The number of chunks is ``ceil(n / max_chunk)``, raised for a short movie to up to
    :data:`MIN_CHUNKS` of at least ``min_chunk`` frames so that the workers share it; it
    depends on the frames only (not on the workers), so a rerun with other workers resumes the
    same chunks. Each chunk is its share of the frames plus the next share's first
    ``overlap`` frames.

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


#: a bar from fewer refitted initial frames than this takes its spread at least from the
#: noise model (:func:`holofit.fit.continuity.small_sample_bar`): a few consecutive frames
#: do not show the movie's spread
REFIT_MIN_ROWS = 30
#: ... with this least excess scatter of a right-minimum frame fitted with the movie's fixed
#: statics: measured 1.86 % (median minus the 15.87 % quantile, relative) over the 2658
#: right-branch frames of a 3000-frame Janus replicate, whose 10 refitted initial frames
#: alone gave a bar of 1.053 with 7.8 % of the right frames above it; rounded up (the 1 % of
#: :data:`holofit.fit.continuity.EXCESS_FLOOR` was measured with the true statics)
FIXED_STATICS_FLOOR = 0.02


def bar_from_initial(path: Path, sigmas: float,
                     refit: Callable[[pd.DataFrame], pd.DataFrame] | None = None
                     ) -> tuple[float | None, str]:
    """The movie's chi^2 bar from the initial pass's table, and where it came from.

    With at least 10 ``ok`` frames, :func:`holofit.fit.continuity.chi2_bar`; with fewer (a
    short movie's initial pass), :func:`holofit.fit.continuity.small_sample_bar`: the same
    form with the spread taken at least from the noise model and widened for the few rows, so
    that a warm frame clearly off the data is re-acquired and, if still above it, flagged,
    never plain ``ok``. Only the ``ok`` rows count: the initial pass's rows clearly worse than
    its best ones are ``poor_fit`` (:mod:`holofit.fit.initial_level`) and would raise the bar.

    ``refit`` (:func:`initial_refits`) takes those rows to the same frames fitted as the final
    pass fits them, the static parameters fixed at the pass's values: the initial rows fit
    each frame's own statics, and where those scatter far beyond their errors (a Janus cap's
    thickness and index: 10-20 standard errors between frames) their chi^2 sits below what
    any frame reaches with the statics fixed, so a bar from them flags right frames
    (measured: a 3000-frame Janus replicate, bar 1.03 from 10 initial rows at 1.002-1.034,
    609 right frames at 1.05-1.08 above it and re-acquired).
    Returns ``(None, reason)`` when there is no such table or no ``ok`` frame in it.
    """
    if not path.exists():
        return None, f"no chi^2 bar for the tracking ({path.name} not found): warm fits " \
                     "checked by status and step only"
    table = read_table(path)
    table = table[table["status"] == OK]
    source = path.name
    min_rows, floor = 10, EXCESS_FLOOR
    if refit is not None and len(table):
        table = refit(table)
        table = table[table["status"] == OK]
        source = f"{path.name}'s frames refitted with the final statics"
        min_rows, floor = REFIT_MIN_ROWS, FIXED_STATICS_FLOOR
    bar = chi2_bar(table, sigmas, min_rows)
    if math.isfinite(bar):
        return bar, f"tracking chi^2 bar {bar:.4g} (reduced; median + {sigmas:g} " \
                    f"lower-half spreads of {source})"
    bar = small_sample_bar(table, sigmas, min_rows, floor)
    if not math.isfinite(bar):
        return None, (f"no chi^2 bar for the tracking (no ok frame in {source}): "
                      "warm fits checked by status and step only")
    n = len(table)
    return bar, (f"tracking chi^2 bar {bar:.4g} (reduced; {n} ok frame(s) in "
                 f"{source}, fewer than {min_rows}: median + {sigmas:g} spreads, the spread "
                 f"at least the noise model's with a {100 * floor:g} % excess, widened for the "
                 "few frames)")


#: where the final pass keeps its bar (beside ``initial.csv``): computed once per initial table
#: and pass settings, so that a rerun resumes with the very same bar (a refit's last digits
#: depend on the engine's warm starts)
FINAL_BAR_FILE = "final_bar.json"


def final_bar(initial: Path, fit: FitConfig, loader: FrameLoader, sigmas: float
              ) -> tuple[float | None, str]:
    """:func:`bar_from_initial` of ``initial`` with :func:`initial_refits` for the pass
    ``fit``, kept in :data:`FINAL_BAR_FILE` keyed by the initial table's bytes, the pass's
    settings and ``sigmas`` (reused while they match)."""
    store = initial.parent / FINAL_BAR_FILE
    content = hashlib.sha256(initial.read_bytes()).hexdigest() if initial.exists() else None
    key = fingerprint({"initial": content, "fit": fit.as_dict(), "sigmas": sigmas})
    if store.exists():
        try:
            kept = json.loads(store.read_text())
        except (OSError, ValueError):
            kept = {}
        if kept.get("key") == key:
            bar = kept.get("bar")
            return (None if bar is None else float(bar)), str(kept.get("note", ""))
    bar, note = bar_from_initial(initial, sigmas, initial_refits(fit, loader))
    write_json(store, {"key": key, "bar": bar, "note": note})
    return bar, note


def initial_refits(fit: FitConfig, loader: FrameLoader
                   ) -> Callable[[pd.DataFrame], pd.DataFrame]:
    """The ``refit`` of :func:`bar_from_initial` for the pass ``fit`` (its statics fixed):
    each initial row's frame fitted warm from the row's pose (no mirror: the chi^2 of the
    row's own minimum is wanted), with the pass's engine (its T-matrix where it has one).
    Returns rows with ``frame``, ``status``, ``chi2_red``, ``n_pixels``."""
    def refit(rows: pd.DataFrame) -> pd.DataFrame:
        model, inst = fit.particle.model, fit.instrument
        theory = worker_theory(fit)
        opts = replace(fit.options, mirror=False)
        out = []
        for row in rows.to_dict("records"):
            frame = int(row["frame"])
            got = loader(frame)
            pose = {c: float(row[c]) for c in INITIAL_POSE if c in row}
            if isinstance(got, Precomputed) or not all(map(math.isfinite, pose.values())):
                continue
            start = state_of(pose, model)
            res = fit_frame_warm(got.crop, got.corner, inst.pixel_size_um, theory, model,
                                 inst.optics, start, fit.free, opts, seed=frame).result
            out.append({"frame": frame, "status": res.status, "chi2_red": res.chi2_red,
                        "n_pixels": res.n_pixels})
        return pd.DataFrame(out, columns=["frame", "status", "chi2_red", "n_pixels"])

    return refit


def initial_poses(path: Path) -> dict[int, dict[str, float]]:
    """Each converged row of the initial pass's table at ``path`` (``ok`` or ``poor_fit``,
    its pose finite): frame -> its :data:`holofit.fit.tracking.INITIAL_POSE` values, the
    final pass's check of that frame; empty without the table."""
    if not path.exists():
        return {}
    table = read_table(path)
    cols = [c for c in INITIAL_POSE if c in table.columns]
    if "status" not in table.columns or "frame" not in table.columns:
        return {}
    rows = table[table["status"].isin((OK, POOR_FIT))]
    out = {}
    for row in rows.to_dict("records"):
        pose = {c: float(row[c]) for c in cols}
        if all(math.isfinite(v) for v in pose.values()):
            out[int(row["frame"])] = pose
    return out


def initial_check_summary(table: pd.DataFrame) -> tuple[dict[str, int], str]:
    """What the check against the initial-pass rows did in a tracked table: frames checked,
    refitted from the initial pose (it beat the fit by the margin) and changed by it, and
    the note that says so."""
    code = table["track_initial"] if "track_initial" in table.columns else pd.Series([])
    code = pd.to_numeric(code, errors="coerce")
    counts = {"checked": int((code >= 0).sum()), "refitted": int((code >= 1).sum()),
              "changed": int((code == 2).sum())}
    note = (f"final pass: {counts['checked']} frame(s) checked against their initial-pass "
            f"fit (one hologram each), {counts['refitted']} refitted from it, "
            f"{counts['changed']} changed (re-acquired; track_initial 2)")
    return counts, note


@dataclass(frozen=True)
class TrackedConfig:
    """Everything a worker needs for the chunks of the tracking final pass (picklable).

    Attributes
    ----------
    fit : FitConfig
        The final pass's settings (statics fixed, the T-matrix).
    options : TrackOptions
        How the track is followed.
    chi2_bar : float, optional
        The movie's bar on the reduced chi^2 (None: status and step only).
    overlap : int
        Frames a chunk reaches into the next one.
    """

    fit: FitConfig
    options: TrackOptions
    chi2_bar: float | None
    overlap: int = OVERLAP

    def as_dict(self) -> dict[str, Any]:
        opts = asdict(self.options)
        opts.pop("frame")  # in the fit config's options
        return {"fit": self.fit.as_dict(), "tracking": opts, "chi2_bar": self.chi2_bar,
                "chunks": {"max": MAX_CHUNK, "min": MIN_CHUNK, "count": MIN_CHUNKS,
                           "overlap": self.overlap,
                           "min_initial": INITIAL_MIN_CHUNK}}


@dataclass(frozen=True)
class ChunkPayload:
    """What the driver sends a worker for one chunk: the frames to fit and the rows of the
    frames the loader skipped (their crop, prefit or library row says they cannot be fitted)."""

    frames: tuple[ChunkFrame, ...]
    skipped: tuple[dict[str, Any], ...]


def chunk_loader(loader: FrameLoader, chunks: Sequence[Sequence[int]],
                 frame_rate_hz: float | None,
                 initial: Mapping[int, dict[str, float]] | None = None
                 ) -> Callable[[Any], ChunkPayload]:
    """The batch loader of chunk items ``(chunk, first frame)``; ``initial``: the initial
    pass's poses by frame (:func:`initial_poses`), each frame's check."""
    initial = initial or {}

    def load(key: Any) -> ChunkPayload:
        frames, skipped = [], []
        for f in chunks[int(key[0])]:
            got = loader(f)
            if isinstance(got, Precomputed):
                skipped.append({**got.row, "frame": f})
                continue
            s = got.start
            frames.append(ChunkFrame(
                f, got.crop, got.corner, (s["x_um"], s["y_um"], s["z_um"]), s["alpha"],
                tuple(got.candidates),  # type: ignore[arg-type]
                f / frame_rate_hz if frame_rate_hz else math.nan, initial.get(f)))
        return ChunkPayload(tuple(frames), tuple(skipped))

    return load


def track_chunk_task(config: TrackedConfig, key: Any, payload: ChunkPayload
                     ) -> list[dict[str, Any]]:
    """Fit one chunk along the track; its rows, keyed ``(chunk, frame)`` (a multi-row item)."""
    from holofit.library.search import Candidate

    fit, inst = config.fit, config.fit.instrument
    frames = [ChunkFrame(f.frame, f.crop, f.corner, f.position_um, f.alpha,
                         tuple(Candidate(*c) for c in f.candidates), f.time_s, f.initial)
              for f in payload.frames]
    table = track_chunk(frames, worker_theory(fit), fit.particle.model, inst.optics,
                        inst.pixel_size_um, fit.free, config.chi2_bar, config.options)
    rows = [*table.to_dict("records"), *(dict(r) for r in payload.skipped)]
    for row in rows:
        row["chunk"] = int(key[0])
    return rows


def stitch_table(path: Path, chunks: Sequence[Sequence[int]], head_tail: bool
                 ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """One row per frame from the chunk table at ``path``, and the overlaps' disagreements.

    A chunk that failed as a whole (one ``error`` row) gives its frames ``error`` rows with
    the chunk's message.
    """
    table = read_table(path)
    parts, failed = [], []
    for i, frames in enumerate(chunks):
        part = table[table["chunk"] == i].drop(columns="chunk")
        if len(part) == 1 and len(frames) > 1 and part["status"].iloc[0] == ERROR:
            msg = f"chunk {i} (frames {frames[0]}-{frames[-1]}): {part['message'].iloc[0]}"
            failed += [{"frame": f, "status": ERROR, "message": msg} for f in frames]
            continue
        parts.append(part)
    rows, disagreements = stitch_chunks(parts, head_tail)
    have = set(rows["frame"].astype(int)) if len(rows) else set()
    extra = pd.DataFrame([r for r in failed if r["frame"] not in have])
    out = pd.concat([rows, extra], ignore_index=True) if len(extra) else rows
    out = out.drop_duplicates("frame").sort_values("frame").reset_index(drop=True)
    return out, disagreements
