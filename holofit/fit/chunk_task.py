"""A pass that follows the tracks, as a batch: chunks of each track are the items.

Each track is cut into chunks (:func:`holofit.fit.chunks.plan_chunks`); a chunk is one item
of the batch runner, a *multi-row item*: its rows are keyed ``(particle, chunk, frame)``
(:data:`holofit.fit.chunks.CHUNK_KEY`) in ``<pass>_chunks.csv``, so that a finished chunk is
never redone. :func:`follow_chunk_task` follows one chunk (:func:`holofit.fit.follow.follow_chunk`).

The final pass needs each track's chi^2 bar before any chunk runs: :func:`bar_from_initial`
takes it from the track's initial-pass rows refitted with the final statics
(:func:`initial_refits`), and :func:`final_bars` keeps the bars in :data:`FINAL_BAR_FILE` so
that a rerun resumes with the very same bars. The initial pass's converged rows are also each
frame's independent check (:func:`initial_poses`;
:func:`holofit.fit.rescue.check_against_initial`).
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

from holofit.batch import Precomputed
from holofit.batch.stage import FrameLoader, fingerprint
from holofit.fit.chunks import INITIAL_MIN_CHUNK, MAX_CHUNK, MIN_CHUNK, MIN_CHUNKS, OVERLAP
from holofit.fit.follow import follow_chunk
from holofit.fit.follower import ChunkFitter, ChunkFrame
from holofit.fit.problem import state_of
from holofit.fit.rescue import INITIAL_POSE
from holofit.fit.settings import FollowSettings
from holofit.fit.task import FitPayload, PassConfig, frame_problem, item_theory, worker_theory
from holofit.fit.warm import fit_frame_warm
from holofit.io.tables import read_table, write_json
from holofit.library.search import Candidate
from holofit.quality import EXCESS_FLOOR, chi2_bar, small_sample_bar
from holofit.status import OK, POOR_FIT

__all__ = [
    "FINAL_BAR_FILE",
    "FIXED_STATICS_FLOOR",
    "REFIT_MIN_ROWS",
    "ChunkConfig",
    "ChunkPayload",
    "bar_from_initial",
    "chunk_loader",
    "final_bars",
    "follow_chunk_task",
    "initial_check_summary",
    "initial_poses",
    "initial_refits",
]

#: a bar from fewer refitted initial frames than this takes its spread at least from the
#: noise model (:func:`holofit.quality.small_sample_bar`): a few frames do not show the
#: movie's spread
REFIT_MIN_ROWS = 30
#: ... with this least excess scatter of a right-minimum frame fitted with the movie's fixed
#: statics: larger than :data:`holofit.quality.EXCESS_FLOOR`, since fixed statics are a little
#: off each frame's own (docs: validation, "the final pass's chi^2 bar")
FIXED_STATICS_FLOOR = 0.02
#: where the final pass keeps its bars (beside ``initial.csv``)
FINAL_BAR_FILE = "final_bar.json"


def bar_from_initial(initial: Path | pd.DataFrame, sigmas: float,
                     refit: Callable[[pd.DataFrame], pd.DataFrame] | None = None,
                     source: str = "initial.csv") -> tuple[float | None, str]:
    """A track's chi^2 bar from its initial-pass rows (a table, or the file ``initial``;
    ``source`` names a table in the note), and where it came from.

    Only the ``ok`` rows count. ``refit`` (:func:`initial_refits`) takes them to the same
    frames fitted as the final pass fits them, the statics fixed: the initial rows fit each
    frame's own statics, and their chi^2 sits below what any frame reaches with the statics
    fixed. With at least ``min_rows`` rows the bar is :func:`holofit.quality.chi2_bar`, with
    fewer :func:`holofit.quality.small_sample_bar`. Returns ``(None, reason)`` without any
    ``ok`` row.
    """
    if isinstance(initial, Path):
        if not initial.exists():
            return None, (f"no chi^2 bar ({initial.name} not found): warm fits checked by "
                          "status and step only")
        table, source = read_table(initial), initial.name
    else:
        table = initial
    table = table[table["status"] == OK]
    min_rows, floor = 10, EXCESS_FLOOR
    if refit is not None and len(table):
        table = refit(table)
        table = table[table["status"] == OK]
        source = f"{source}'s frames refitted with the final statics"
        min_rows, floor = REFIT_MIN_ROWS, FIXED_STATICS_FLOOR
    bar = chi2_bar(table, sigmas, min_rows)
    if math.isfinite(bar):
        return bar, (f"chi^2 bar {bar:.4g} (reduced; median + {sigmas:g} lower-half spreads "
                     f"of {source})")
    bar = small_sample_bar(table, sigmas, min_rows, floor)
    if not math.isfinite(bar):
        return None, (f"no chi^2 bar (no ok frame in {source}): warm fits checked by status "
                      "and step only")
    return bar, (f"chi^2 bar {bar:.4g} (reduced; {len(table)} ok frame(s) in {source}, "
                 f"fewer than {min_rows}: median + {sigmas:g} spreads, the spread at least the "
                 f"noise model's with a {100 * floor:g} % excess, widened for the few frames)")


def initial_refits(config: PassConfig, loader: FrameLoader
                   ) -> Callable[[pd.DataFrame], pd.DataFrame]:
    """The ``refit`` of :func:`bar_from_initial` for one track's pass ``config`` (its statics
    fixed): each initial row's frame fitted warm from the row's pose (no mirror: the chi^2 of
    the row's own minimum is wanted), with the pass's engine. Returns rows with ``frame``,
    ``status``, ``chi2_red``, ``n_pixels``."""
    def refit(rows: pd.DataFrame) -> pd.DataFrame:
        model = config.particle.model
        theory = worker_theory(config)
        quiet = replace(config, options=replace(config.options, mirror=False))
        out = []
        for row in rows.to_dict("records"):
            key = (int(row["particle"]), int(row["frame"]))
            got = loader(key)
            pose = {c: float(row[c]) for c in INITIAL_POSE if c in row}
            if isinstance(got, Precomputed) or not all(map(math.isfinite, pose.values())):
                continue
            payload = FitPayload(got.crop, got.corner, got.start, ())
            problem = frame_problem(quiet, payload, key[1], theory)
            res = fit_frame_warm(problem, state_of(pose, model)).result
            out.append({"frame": key[1], "status": res.status, "chi2_red": res.chi2_red,
                        "n_pixels": res.n_pixels})
        return pd.DataFrame(out, columns=["frame", "status", "chi2_red", "n_pixels"])

    return refit


def final_bars(initial: Path, config: PassConfig, tracks: Sequence[int], loader: FrameLoader,
               sigmas: float) -> dict[int, tuple[float | None, str]]:
    """Each track's :func:`bar_from_initial` of ``initial`` with :func:`initial_refits` for
    the final pass ``config``, kept in :data:`FINAL_BAR_FILE` keyed by the initial table's
    bytes, the pass's settings and ``sigmas`` (reused while they match)."""
    store = initial.parent / FINAL_BAR_FILE
    content = hashlib.sha256(initial.read_bytes()).hexdigest() if initial.exists() else None
    key = fingerprint({"initial": content, "fit": config.as_dict(), "sigmas": sigmas,
                       "tracks": sorted(int(p) for p in tracks)})
    if store.exists():
        try:
            kept = json.loads(store.read_text())
        except (OSError, ValueError):
            kept = {}
        if kept.get("key") == key:
            return {int(p): (None if v["bar"] is None else float(v["bar"]), str(v["note"]))
                    for p, v in kept.get("tracks", {}).items()}
    out: dict[int, tuple[float | None, str]] = {}
    table = read_table(initial) if initial.exists() else None
    for p in tracks:
        if table is None:
            out[p] = (None, f"no chi^2 bar ({initial.name} not found): warm fits checked by "
                            "status and step only")
            continue
        rows = table[table["particle"] == p]
        out[p] = bar_from_initial(rows, sigmas, initial_refits(config.for_track(p), loader),
                                  initial.name)
    write_json(store, {"key": key, "tracks": {str(p): {"bar": b, "note": n}
                                              for p, (b, n) in out.items()}})
    return out


def initial_poses(path: Path) -> dict[tuple[int, int], dict[str, float]]:
    """Each converged row of the initial pass's table at ``path`` (``ok`` or ``poor_fit``,
    its pose finite): ``(particle, frame)`` -> its
    :data:`holofit.fit.rescue.INITIAL_POSE` values; empty without the table."""
    if not path.exists():
        return {}
    table = read_table(path)
    cols = [c for c in INITIAL_POSE if c in table.columns]
    if not {"status", "frame", "particle"} <= set(table.columns):
        return {}
    rows = table[table["status"].isin((OK, POOR_FIT))]
    out = {}
    for row in rows.to_dict("records"):
        pose = {c: float(row[c]) for c in cols}
        if all(math.isfinite(v) for v in pose.values()):
            out[(int(row["particle"]), int(row["frame"]))] = pose
    return out


def initial_check_summary(table: pd.DataFrame) -> tuple[dict[str, int], str]:
    """What the check against the initial-pass rows did in a followed table: frames checked,
    refitted from the initial pose and changed by it, and the note that says so."""
    code = table["follow_initial"] if "follow_initial" in table.columns else pd.Series([])
    code = pd.to_numeric(code, errors="coerce")
    counts = {"checked": int((code >= 0).sum()), "refitted": int((code >= 1).sum()),
              "changed": int((code == 2).sum())}
    note = (f"final pass: {counts['checked']} frame(s) checked against their initial-pass "
            f"fit (one hologram each), {counts['refitted']} refitted from it, "
            f"{counts['changed']} changed (re-acquired; follow_initial 2)")
    return counts, note


@dataclass(frozen=True)
class ChunkConfig:
    """Everything a worker needs for the chunks of a followed pass (picklable).

    Attributes
    ----------
    fit : PassConfig
        The pass's settings (each track's statics and T-matrix).
    options : FollowSettings
        How a track is followed.
    chi2_bars : tuple
        ``(particle, bar)``: each track's bar on the reduced chi^2 (None: status and step
        only).
    overlap : int
        Frames a chunk reaches into the next one.
    """

    fit: PassConfig
    options: FollowSettings
    chi2_bars: tuple[tuple[int, float | None], ...] = ()
    overlap: int = OVERLAP

    def bar(self, particle: int) -> float | None:
        return dict(self.chi2_bars).get(int(particle))

    def as_dict(self) -> dict[str, Any]:
        opts = asdict(self.options)
        opts.pop("frame")  # in the fit config's options
        return {"fit": self.fit.as_dict(), "follow": opts,
                "chi2_bars": {str(p): b for p, b in self.chi2_bars},
                "chunks": {"max": MAX_CHUNK, "min": MIN_CHUNK, "count": MIN_CHUNKS,
                           "overlap": self.overlap, "min_initial": INITIAL_MIN_CHUNK}}


@dataclass(frozen=True)
class ChunkPayload:
    """What the driver sends a worker for one chunk: the frames to fit and the rows of the
    frames the loader skipped (their crop, prefit or library row says they cannot be fitted)."""

    frames: tuple[ChunkFrame, ...]
    skipped: tuple[dict[str, Any], ...]


def chunk_loader(loader: FrameLoader, chunks: Mapping[int, Sequence[Sequence[int]]],
                 frame_rate_hz: float | None,
                 initial: Mapping[tuple[int, int], dict[str, float]] | None = None
                 ) -> Callable[[Any], ChunkPayload]:
    """The batch loader of chunk items ``(particle, chunk, first frame)``; ``initial``: the
    initial pass's poses by ``(particle, frame)`` (:func:`initial_poses`)."""
    initial = initial or {}

    def load(key: Any) -> ChunkPayload:
        p = int(key[0])
        frames, skipped = [], []
        for f in chunks[p][int(key[1])]:
            got = loader((p, f))
            if isinstance(got, Precomputed):
                skipped.append({**got.row, "frame": f})
                continue
            s = got.start
            frames.append(ChunkFrame(
                f, got.crop, got.corner, (s["x_um"], s["y_um"], s["z_um"]), s["alpha"],
                tuple(Candidate(*c) for c in got.candidates),
                f / frame_rate_hz if frame_rate_hz else math.nan, initial.get((p, f))))
        return ChunkPayload(tuple(frames), tuple(skipped))

    return load


def follow_chunk_task(config: ChunkConfig, key: Any, payload: ChunkPayload
                      ) -> list[dict[str, Any]]:
    """Follow one chunk of a track; its rows, keyed ``(particle, chunk, frame)`` (a multi-row
    item)."""
    p, chunk = int(key[0]), int(key[1])
    fit = config.fit.for_track(p)
    inst = fit.instrument
    frames = list(payload.frames)
    fitter = ChunkFitter(item_theory(fit), fit.particle.model, inst.optics,
                         inst.pixel_size_um, fit.free, config.options)
    table = follow_chunk(frames, fitter, config.bar(p))
    rows = [*table.to_dict("records"), *(dict(r) for r in payload.skipped)]
    for row in rows:
        row["particle"], row["chunk"], row["model"] = p, chunk, fit.particle.model.kind
    return rows
