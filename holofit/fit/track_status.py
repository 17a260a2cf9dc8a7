"""What became of each track: fitted, or left out with its cause and the remedy.

A track whose initial pass has no ``ok`` frame under the model it was given has no static
parameters to fix: it is left out of the final pass (its rows there are ``skipped`` and say
why), and the other tracks go on. :func:`left_out` says why from the track's initial rows
(their statuses, the quality rule that flagged them, the frames, a picture of one) and what
to try. ``tracks.csv`` (:func:`write_tracks`) has one row per track: its model, statics,
status and, for a track left out, the cause and the remedy.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from holofit.io.tables import write_table
from holofit.provenance import sidecar
from holofit.status import ERROR, NOT_CONVERGED, OK, POOR_FIT, SKIPPED

__all__ = ["TRACK_STATUSES", "TrackOutcome", "left_out", "write_tracks"]

#: the statuses of ``tracks.csv``
TRACK_STATUSES = {
    "fitted": "fitted in both passes with the model it was given",
    "left_out": "its initial pass has no ok frame under its model: no static parameters; its "
                "final-pass rows are skipped (cause and remedy in the row)",
    "unmodelled": "no model of the run fits it (cause in the row): left out as above",
    "excluded": "left out by --exclude-particle or --particle",
}

#: what to try, by what the initial rows say
_REMEDY = {
    SKIPPED: "the crop, prefit or library gave no frame of it to fit: see crops.csv, prefit.csv "
             "and library.csv for these frames",
    ERROR: "the fits raised (the message says why): fix the cause and rerun; frames in error "
           "are fitted again",
    NOT_CONVERGED: "the fits hit their iteration limit: check the prefit's heights of these "
                   "frames, or rerun with --retry-failed",
    "no particle": "its crops hold no hologram a model explains better than a flat background: "
                   "likely a false detection (raise holofit crop --min-score)",
    "outside": "its sizes or indices end outside the model's range: it is likely another kind "
               "of particle (give its model with another -p)",
    "overlap": "another track's hologram overlaps its crops: the overlap refit could not "
               "separate them",
    POOR_FIT: "no model of the run describes its hologram (an aggregate, dust, another species):"
              " give its model with another -p, or leave it out (--exclude-particle)",
}


@dataclass(frozen=True)
class TrackOutcome:
    """One track's fate after the initial pass.

    Attributes
    ----------
    particle : int
        The track.
    model : str
        The model it was given (its kind).
    status : str
        One of :data:`TRACK_STATUSES`.
    reason : str
        Why (the model test's result for a fitted track; the cause for one left out).
    remedy : str
        What to try ('' for a fitted track).
    frames : tuple of int
        The initial frames the outcome was judged on.
    statics : dict
        The static parameters its final pass fixes (empty when left out).
    """

    particle: int
    model: str
    status: str
    reason: str
    remedy: str = ""
    frames: tuple[int, ...] = ()
    statics: dict[str, float] = field(default_factory=dict)

    @property
    def fitted(self) -> bool:
        return self.status == "fitted"


def left_out(rows: pd.DataFrame, particle: int, model: str, picture: str | None = None
             ) -> TrackOutcome:
    """The outcome of a track whose initial rows (``rows``: status, message, frame) hold no
    ``ok`` frame: which statuses, which rule (the most common message), which frames, the
    remedy; ``picture`` names a data / model / residual picture of one of them."""
    frames = tuple(int(f) for f in rows["frame"])
    counts = Counter(str(s) for s in rows["status"])
    messages = Counter(str(m) for m, s in zip(rows["message"], rows["status"], strict=True)
                       if s != OK and isinstance(m, str) and m and m != "nan")
    common = messages.most_common(1)[0][0] if messages else ""
    key = _remedy_key(counts, common)
    where = (f"frames {frames[0]}-{frames[-1]}" if len(frames) > 1
             else f"frame {frames[0]}" if frames else "no frame")
    tally = ", ".join(f"{n} {s}" for s, n in counts.most_common())
    reason = (f"its initial pass ({model}) has no ok frame: {tally} ({where})"
              + (f"; most often: {common}" if common else "")
              + (f"; see {picture}" if picture else ""))
    return TrackOutcome(particle, model, "left_out", reason, _REMEDY[key], frames)


def _remedy_key(counts: Counter[str], message: str) -> str:
    """Which remedy fits what the rows say."""
    if not counts or set(counts) <= {SKIPPED}:
        return SKIPPED
    top = counts.most_common(1)[0][0]
    if top in (ERROR, NOT_CONVERGED):
        return top
    for word in ("no particle", "outside", "overlap"):
        if word in message:
            return word
    return POOR_FIT


def write_tracks(path: Path, outcomes: Sequence[TrackOutcome],
                 final: Mapping[int, Mapping[str, int]] | None = None,
                 inputs: Sequence[str | Path] = ()) -> Path:
    """``tracks.csv`` (+ sidecar): one row per track (its model, status, statics, reason and
    remedy, and with ``final`` its final-pass statuses); the path."""
    rows = []
    for o in outcomes:
        doc: dict[str, Any] = {k: v for k, v in asdict(o).items() if k not in ("frames",
                                                                               "statics")}
        doc["n_initial_frames"] = len(o.frames)
        doc.update({f"static_{k}": v for k, v in o.statics.items()})
        for status, n in (final or {}).get(o.particle, {}).items():
            doc[f"n_{status}"] = int(n)
        rows.append(doc)
    table = pd.DataFrame(rows).sort_values("particle") if rows else pd.DataFrame(
        columns=["particle", "model", "status", "reason", "remedy"])
    meta = sidecar(kind="the fit's tracks: one row per track, its model, statics and status",
                   units={"particle": "track id", "model": "the particle model's kind",
                          "status": " | ".join(f"{k} ({v})" for k, v in TRACK_STATUSES.items()),
                          "static_*": "the static parameters fixed in the final pass (the "
                                      "model's units)",
                          "n_*": "final-pass rows of each status"},
                   inputs=list(inputs))
    return write_table(path, table.reset_index(drop=True), meta)
