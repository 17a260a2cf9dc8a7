"""Diffusion of every track in a field of view, and the tracks pooled.

A multi-particle fit table holds one row per (``particle``, ``frame``); ``particle`` is the track
id (trackpy's name). Each track is analysed on its own, exactly as a single-particle table is
(:func:`holofit.analysis.pipeline.analyze_trajectory`), with its own analysis model: the one of
the particle model the fit gave it (a run may fit a population of models; a sphere among rods
translates only), or the one given for all (:mod:`holofit.analysis.population`). Tracks of one
analysis model estimate the same quantities and are pooled, never with another model's:

* the pooled value is the inverse-variance weighted mean ``sum(w_i x_i) / sum(w_i)`` with
  ``w_i = 1 / sigma_i^2``, its error ``1 / sqrt(sum w_i)``;
* the tracks' consistency is ``chi^2 = sum(w_i (x_i - mean)^2)`` on ``n - 1`` degrees of
  freedom, with its p-value: a small p says the tracks are not alike;
* each track's pull against the mean of the *other* tracks,
  ``(x_i - mean_{-i}) / sqrt(sigma_i^2 + sigma_{mean,-i}^2)``, names the one that is not like
  the others (an impurity, a dimer among rods): ``|pull| > outlier_sigma`` marks it
  ``outlier`` in the pooled table, and it is left out of that quantity's pooled value.

Every track is a row of the result, analysed or not, with its status and why
(:data:`TRACK_STATUSES`): a track the fit left out keeps the fit's reason and remedy (the fit's
``tracks.csv``, :mod:`holofit.analysis.population`); one the selection leaves out is
``excluded``; one too short, mostly ``poor_fit``, whose analysis failed or that fails the
physical-consistency check (``flagged``: a hydrodynamic size unlike the fitted one, sticking,
a drift that changes, swimming; :mod:`holofit.analysis.consistency`) is not pooled, the last
unless ``TrackPooling(include_flagged=True)`` asks for it. The tables and the report are
:mod:`holofit.analysis.track_tables`'.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy.stats import chi2 as chi2_dist

from holofit.analysis.errors import AnalysisError
from holofit.analysis.pipeline import analyze_trajectory
from holofit.analysis.population import (
    FitTrack,
    TrackModel,
    TrackSelection,
    read_fit_tracks,
    settings_for_model,
    track_kinds,
    track_model,
)
from holofit.analysis.results import AnalysisResult
from holofit.analysis.settings import AnalysisConfig
from holofit.analysis.trajectory import Trajectory
from holofit.io.tables import sidecar_path
from holofit.status import OK, POOR_FIT, SKIPPED
from holofit.tables.fit import REQUIRED_COLUMNS, FitTableError, validate_fit_table

__all__ = [
    "POOLED_QUANTITIES",
    "TRACK_COLUMN",
    "TRACK_STATUSES",
    "PooledEstimate",
    "TrackPooling",
    "TrackResult",
    "TracksResult",
    "analyze_tracks",
    "has_tracks",
    "n_tracks",
    "pool_estimates",
    "split_tracks",
]

#: the column that holds the track id (trackpy's name)
TRACK_COLUMN = "particle"
#: the quantities pooled over the tracks of one analysis model, when their analyses measured them
POOLED_QUANTITIES = ("D_t", "D_par", "D_perp", "D_r", "D_xy")
#: what became of a track in the analysis
TRACK_STATUSES = {
    "analysed": "analysed and pooled with the tracks of its model",
    "flagged": "analysed; fails the physical-consistency check: not pooled unless asked",
    "poor_fit": "analysed; most fitted frames are poor_fit (dust, an impurity): not pooled",
    "short": "fewer ok frames than the pooling's min_frames: not analysed",
    "failed": "its analysis raised (the reason says why)",
    "left_out": "the fit left it out (the fit's reason and remedy)",
    "unmodelled": "no model of the fit's population fits it (the fit's reason and remedy)",
    "excluded": "left out by --particle / --exclude-particle (of the fit or the analysis)",
    "no_model": "no analysis model suits its particle model: give one (--model)",
}


@dataclass(frozen=True)
class TrackPooling:
    """Which tracks are analysed and pooled.

    Attributes
    ----------
    min_frames : int
        Tracks with fewer usable (``ok``) frames are reported as ``short`` and not analysed.
    max_poor_fraction : float
        Tracks in which more than this fraction of the fitted frames are ``poor_fit`` are
        reported as ``poor_fit`` and not pooled.
    outlier_sigma : float
        A track whose pull against the other tracks exceeds this is an outlier of that quantity.
    include_flagged : bool
        Pool the tracks that failed the physical-consistency check too (by default they are
        reported as ``flagged`` and left out: their coefficients do not measure free
        diffusion of the fitted particle).
    """

    min_frames: int = 20
    max_poor_fraction: float = 0.5
    outlier_sigma: float = 3.0
    include_flagged: bool = False

    def __post_init__(self) -> None:
        if self.min_frames < 3:
            raise ValueError(f"min_frames must be >= 3, got {self.min_frames}")
        if not 0.0 < self.max_poor_fraction <= 1.0:
            raise ValueError(f"max_poor_fraction must be in (0, 1], got {self.max_poor_fraction}")
        if not self.outlier_sigma > 0:
            raise ValueError(f"outlier_sigma must be > 0, got {self.outlier_sigma}")


@dataclass
class TrackResult:
    """One track: its frames, its model, why it is (not) pooled, and its analysis.

    Attributes
    ----------
    particle : int
        Track id.
    n_frames, n_ok, n_poor : int
        Rows of the track, ``ok`` rows, ``poor_fit`` rows.
    status : str
        One of :data:`TRACK_STATUSES`; ``analysed`` tracks are pooled (``flagged`` ones only
        when the pooling asks).
    message : str
        Why, for the others.
    result : AnalysisResult or None
        The track's analysis (also for ``poor_fit`` and ``flagged`` tracks).
    model : str
        Its analysis model ('' when it has none).
    kind : str
        The particle model the fit gave it ('' when not recorded).
    model_source : str
        Why that analysis model.
    remedy : str
        What to try, for a track left out ('' otherwise).
    statics : dict
        The static parameters its fit fixed (the fit's table of tracks; the model's units).
    """

    particle: int
    n_frames: int
    n_ok: int
    n_poor: int
    status: str
    message: str = ""
    result: AnalysisResult | None = None
    model: str = ""
    kind: str = ""
    model_source: str = ""
    remedy: str = ""
    statics: dict[str, float] = field(default_factory=dict)

    @property
    def poor_fraction(self) -> float:
        fitted = self.n_ok + self.n_poor
        return self.n_poor / fitted if fitted else math.nan


@dataclass
class PooledEstimate:
    """One quantity pooled over the tracks of one analysis model (inverse-variance weighted).

    Attributes
    ----------
    quantity, unit : str
    value, error : float
        Pooled value and its 1-sigma error.
    chi2 : float
        Consistency chi^2 of the pooled tracks about the value.
    dof : int
        ``n_tracks - 1``.
    p_value : float
        Probability of a chi^2 at least this large if the tracks measure one value.
    particles : list of int
        Tracks pooled.
    outliers : list of int
        Tracks left out as not like the others.
    pulls : dict
        Track -> pull against the other tracks' mean.
    model : str
        The analysis model of the pooled tracks.
    """

    quantity: str
    unit: str
    value: float
    error: float
    chi2: float
    dof: int
    p_value: float
    particles: list[int] = field(default_factory=list)
    outliers: list[int] = field(default_factory=list)
    pulls: dict[int, float] = field(default_factory=dict)
    model: str = ""


@dataclass
class TracksResult:
    """Every track's analysis and the pooled estimates, by (analysis model, quantity).

    Attributes
    ----------
    tracks : list of TrackResult
        Every track, analysed or not, by track id.
    pooled : dict
        ``(model, quantity)`` -> :class:`PooledEstimate`.
    pooling : TrackPooling
    notes : list of str
    selection : TrackSelection
        The tracks asked for and the model imposed, if any.
    """

    tracks: list[TrackResult]
    pooled: dict[tuple[str, str], PooledEstimate]
    pooling: TrackPooling
    notes: list[str] = field(default_factory=list)
    selection: TrackSelection = field(default_factory=TrackSelection)

    def estimate(self, quantity: str, model: str | None = None) -> PooledEstimate | None:
        """The pooled ``quantity`` of ``model``'s tracks; without ``model``, the one model's
        that has it (None when none, or several, do)."""
        if model is not None:
            return self.pooled.get((model, quantity))
        found = [e for (_, q), e in self.pooled.items() if q == quantity]
        return found[0] if len(found) == 1 else None

    @property
    def models(self) -> dict[int, str]:
        """Each track's analysis model ('' for a track without one)."""
        return {t.particle: t.model for t in self.tracks}

    @property
    def left_out(self) -> list[TrackResult]:
        """The tracks not analysed, each with its status and reason."""
        return [t for t in self.tracks if t.result is None]


def n_tracks(path: str | Path) -> int:
    """How many tracks a fit table holds (0 without a track column; unreadable files: 0, and
    the reader that follows names the problem)."""
    try:
        head = pd.read_csv(path, usecols=lambda c: c == TRACK_COLUMN)
    except (OSError, ValueError, pd.errors.ParserError, pd.errors.EmptyDataError):
        return 0
    return int(head[TRACK_COLUMN].nunique()) if TRACK_COLUMN in head.columns else 0


def has_tracks(table: pd.DataFrame) -> bool:
    """True when ``table`` has a track column (even with a single track)."""
    return TRACK_COLUMN in table.columns


def split_tracks(table: pd.DataFrame, source: str = "<table>") -> dict[int, pd.DataFrame]:
    """The rows of each track, without the track column, by track id.

    Raises
    ------
    AnalysisError
        Track ids that are not integers (the message names the file and the first row).
    """
    ids = pd.to_numeric(table[TRACK_COLUMN], errors="coerce")
    bad = ids.isna() | (np.mod(ids, 1) != 0)
    if bad.any():
        row = int(np.flatnonzero(bad.to_numpy())[0])
        raise AnalysisError(f"{source}: column {TRACK_COLUMN!r} must hold integer track ids; "
                            f"row {row} holds {table[TRACK_COLUMN].iloc[row]!r}")
    ids = ids.astype(np.int64)
    return {int(p): g.drop(columns=TRACK_COLUMN).reset_index(drop=True)
            for p, g in table.assign(**{TRACK_COLUMN: ids}).groupby(TRACK_COLUMN, sort=True)}


def pool_estimates(values: NDArray[np.float64], errors: NDArray[np.float64]
                   ) -> tuple[float, float, float, int, float]:
    """Inverse-variance weighted mean of ``values`` with ``errors`` (1 sigma).

    Returns
    -------
    value, error, chi2, dof, p_value
    """
    x = np.asarray(values, dtype=float)
    s = np.asarray(errors, dtype=float)
    if x.size == 0 or not np.all(s > 0):
        return math.nan, math.nan, math.nan, 0, math.nan
    w = 1.0 / s**2
    mean = float(np.sum(w * x) / np.sum(w))
    err = float(1.0 / math.sqrt(np.sum(w)))
    chi2 = float(np.sum(w * (x - mean) ** 2))
    dof = x.size - 1
    p = float(chi2_dist.sf(chi2, dof)) if dof > 0 else math.nan
    return mean, err, chi2, dof, p


def _leave_one_out_pulls(x: NDArray[np.float64], s: NDArray[np.float64]) -> NDArray[np.float64]:
    pulls = np.full(x.size, np.nan)
    if x.size < 2:
        return pulls
    for i in range(x.size):
        rest = np.arange(x.size) != i
        m, e, *_ = pool_estimates(x[rest], s[rest])
        pulls[i] = (x[i] - m) / math.hypot(s[i], e)
    return pulls


def _pooled_status(pooling: TrackPooling) -> tuple[str, ...]:
    return ("analysed", "flagged") if pooling.include_flagged else ("analysed",)


def _pool(model: str, quantity: str, tracks: list[TrackResult], pooling: TrackPooling
          ) -> PooledEstimate | None:
    """``quantity`` pooled over the pooled tracks of analysis model ``model`` only."""
    sigma = pooling.outlier_sigma
    use = _pooled_status(pooling)
    rows = [(t.particle, t.result.measured[quantity]) for t in tracks
            if t.model == model and t.status in use and t.result is not None
            and quantity in t.result.measured]
    rows = [(p, m) for p, m in rows
            if not m.upper_limit and math.isfinite(m.value) and m.error > 0]
    if not rows:
        return None
    ids = [p for p, _ in rows]
    x = np.array([m.value for _, m in rows])
    s = np.array([m.error for _, m in rows])
    pulls = _leave_one_out_pulls(x, s)
    # with two tracks a disagreement cannot say which one is odd: both stay in
    odd = (np.abs(pulls) > sigma) if x.size >= 3 else np.zeros(x.size, bool)
    keep = ~odd
    value, error, chi2, dof, p = pool_estimates(x[keep], s[keep])
    return PooledEstimate(
        quantity, rows[0][1].unit, value, error, chi2, dof, p,
        particles=[i for i, k in zip(ids, keep, strict=True) if k],
        outliers=[i for i, o in zip(ids, odd, strict=True) if o],
        pulls={i: float(v) for i, v in zip(ids, pulls, strict=True)},
        model=model,
    )


def _own_columns(rows: pd.DataFrame) -> pd.DataFrame:
    """A track's rows without the columns empty on every row (another model's of the run: a
    sphere's rows hold no rod's orientation or lengths), so that the fit table's checks and
    the size defaults see the track's own model."""
    empty = [c for c in rows.columns if c not in REQUIRED_COLUMNS and rows[c].isna().all()]
    return rows.drop(columns=empty)


def _counts(particle: int, rows: pd.DataFrame) -> TrackResult:
    status = rows["status"].astype(str).str.strip().str.lower()
    n_ok, n_poor = int((status == OK).sum()), int((status == POOR_FIT).sum())
    return TrackResult(particle, len(rows), n_ok, n_poor, "analysed")


def _fit_left_out(track: TrackResult, rows: pd.DataFrame, fit: FitTrack | None) -> bool:
    """Mark ``track`` with the fit's reason if the fit left it out; whether it did. Without
    the fit's table of tracks, a track whose rows are all ``skipped`` with the fit's
    message ("track N left out (...): ...") is one."""
    if fit is not None and fit.left_out:
        track.status = fit.status
        track.message, track.remedy = fit.reason or f"the fit left it out ({fit.status})", \
            fit.remedy
        return True
    status = rows["status"].astype(str).str.strip().str.lower()
    msgs = rows["message"].astype(str) if "message" in rows else pd.Series([], dtype=str)
    if track.n_ok == 0 and len(rows) and (status == SKIPPED).all() \
            and msgs.str.startswith(f"track {track.particle} left out").all():
        track.status, track.message = "left_out", str(msgs.iloc[0])
        return True
    return False


def _analyse_track(track: TrackResult, rows: pd.DataFrame, settings: AnalysisConfig,
                   pooling: TrackPooling, source: str, dt: float | None) -> TrackResult:
    if track.n_ok < pooling.min_frames:
        track.status = "short"
        track.message = (f"{track.n_ok} ok frame(s), fewer than {pooling.min_frames}: "
                         "not analysed")
        return track
    try:
        fit = validate_fit_table(_own_columns(rows), f"{source} (particle {track.particle})", dt)
        track.result = analyze_trajectory(
            Trajectory.from_fit_table(fit, bool(settings.drop_ambiguous)), settings)
    except (FitTableError, AnalysisError) as exc:
        track.status, track.message = "failed", f"{track.model} analysis: {exc}"
        return track
    if track.poor_fraction > pooling.max_poor_fraction:
        track.status = "poor_fit"
        track.message = (f"{track.n_poor} of {track.n_ok + track.n_poor} fitted frames are "
                         f"poor_fit ({100 * track.poor_fraction:.0f} %): not the particle the "
                         "model describes (dust, an impurity?); not pooled")
    elif track.result.flagged:
        assert track.result.consistency is not None
        track.status = "flagged"
        track.message = track.result.consistency.message + (
            "; pooled as asked (include_flagged)" if pooling.include_flagged
            else "; not pooled (TrackPooling(include_flagged=True) pools it)")
    return track


@dataclass(frozen=True)
class _Run:
    """What every track of one table shares."""

    settings: AnalysisConfig
    pooling: TrackPooling
    selection: TrackSelection
    source: str
    dt: float | None
    kinds: dict[int, str]
    fit_tracks: dict[int, FitTrack]
    default: tuple[str | None, str]
    primary: dict[str, Any]


def _track(run: _Run, particle: int, rows: pd.DataFrame, kept: set[int]) -> TrackResult:
    """One track's row: left out (by the selection, by the fit, for want of a model) or
    analysed with its own model."""
    track = _counts(particle, rows)
    fit = run.fit_tracks.get(particle)
    tm: TrackModel = track_model(particle, run.kinds, run.fit_tracks, run.selection,
                                 run.default, run.primary)
    track.kind, track.model, track.model_source = tm.kind, tm.model or "", tm.source
    track.statics = dict(fit.statics) if fit is not None else {}
    if particle not in kept:
        track.status, track.message = "excluded", run.selection.why_left_out(particle)
        return track
    if _fit_left_out(track, rows, fit):
        track.model = ""  # not analysed: no analysis model is reported for it
        return track
    if tm.model is None:
        track.status = "no_model"
        track.message = f"no analysis model suits it: {tm.source}"
        track.remedy = "give the analysis model (--model rod, janus or sphere)"
        return track
    return _analyse_track(track, rows, settings_for_model(run.settings, tm.model), run.pooling,
                          run.source, run.dt)


def analyze_tracks(path: str | Path, settings: AnalysisConfig, *,
                   pooling: TrackPooling | None = None,
                   frame_interval_s: float | None = None,
                   selection: TrackSelection | None = None) -> TracksResult:
    """Analyse every track of a multi-particle fit table, each with its model, and pool the
    tracks of each model.

    Parameters
    ----------
    path : str or Path
        A fit table with a ``particle`` column (its sidecar for the frame interval, the fit's
        ``tracks.csv`` beside it for the tracks it left out).
    settings : AnalysisConfig
        How each track is analysed; its model is that of the tracks whose own model is not
        recorded (:func:`holofit.analysis.population.settings_for_model` makes a track's of
        another model).
    pooling : TrackPooling, optional
        Which tracks are analysed and pooled.
    frame_interval_s : float, optional
        Overrides the sidecar's frame interval, s.
    selection : TrackSelection, optional
        The tracks analysed and a model imposed on all (default: every track, each its own).

    Raises
    ------
    AnalysisError
        No track column, no rows, a selection of tracks the table does not hold, or no track
        that could be analysed (naming the file and each track's reason).
    """
    pooling = pooling or TrackPooling()
    selection = selection or TrackSelection()
    path = Path(path)
    table = pd.read_csv(path, dtype={"status": str, "message": str})
    if not has_tracks(table):
        raise AnalysisError(f"{path}: no {TRACK_COLUMN!r} column: a single-particle table "
                            "(analyse it with analyze_table)")
    if table.empty:
        raise AnalysisError(f"{path}: the table has no rows")
    by_track = split_tracks(table, str(path))
    kept = selection.kept(by_track, str(path))
    fit_tracks = read_fit_tracks(path)
    run = _Run(settings, pooling, selection, str(path),
               frame_interval_s if frame_interval_s is not None else _sidecar_interval(path),
               track_kinds(table), fit_tracks, (settings.model, "the settings' model"),
               _sidecar_particle(path))
    tracks = [_track(run, p, rows, kept) for p, rows in by_track.items()]
    # tracks the fit records but the table lacks (left out before its final pass)
    for p, f in sorted(fit_tracks.items()):
        if p not in by_track:
            status = f.status if f.left_out else "left_out"
            tracks.append(TrackResult(p, 0, 0, 0, status, f.reason or "no rows in the fit table",
                                      kind=f.kind, model_source="the fit's table of tracks",
                                      remedy=f.remedy, statics=dict(f.statics)))
    tracks.sort(key=lambda t: t.particle)
    if not any(t.result is not None for t in tracks):
        raise AnalysisError(f"{path}: no track could be analysed ("
                            + "; ".join(f"particle {t.particle}: {t.status}: {t.message}"
                                        for t in tracks) + ")")
    models = sorted({t.model for t in tracks if t.result is not None})
    pooled = {(m, q): est for m in models for q in POOLED_QUANTITIES
              if (est := _pool(m, q, tracks, pooling)) is not None}
    return TracksResult(tracks, pooled, pooling, _notes(tracks, pooled, pooling), selection)


def _sidecar_interval(path: Path) -> float | None:
    side = sidecar_path(path)
    if not side.is_file():
        return None
    try:
        value = json.loads(side.read_text()).get("frame_interval_s")
    except json.JSONDecodeError as exc:
        raise AnalysisError(f"{side}: sidecar is not valid JSON ({exc})") from None
    return float(value) if isinstance(value, int | float) else None


def _sidecar_particle(path: Path) -> dict[str, Any]:
    """The run's primary particle's parameters from the fit table's sidecar ({} if none)."""
    try:
        doc = json.loads(sidecar_path(path).read_text())
    except (OSError, ValueError):
        return {}
    particle = (doc.get("config") or {}).get("particle") if isinstance(doc, dict) else None
    return dict(particle) if isinstance(particle, dict) else {}


def _notes(tracks: list[TrackResult], pooled: dict[tuple[str, str], PooledEstimate],
           pooling: TrackPooling) -> list[str]:
    sigma = pooling.outlier_sigma
    notes = [f"particle {t.particle}: {t.status}: {t.message}"
             + (f" (remedy: {t.remedy})" if t.remedy else "")
             for t in tracks if t.status != "analysed"]
    by_model: dict[str, list[int]] = {}
    for t in tracks:
        if t.result is not None:
            by_model.setdefault(t.model, []).append(t.particle)
    if len(by_model) > 1:
        notes.append("tracks of different models are pooled apart: " + "; ".join(
            f"{m}: particle(s) {', '.join(map(str, ps))}" for m, ps in by_model.items()))
    for est in pooled.values():
        what = f"{est.quantity} ({est.model})"
        if est.outliers:
            notes.append(f"{what}: particle(s) {', '.join(map(str, est.outliers))} not "
                         f"like the others (|pull| > {sigma:g}): left out of the pooled value")
        if est.dof > 0 and est.p_value < 1e-3:
            notes.append(f"{what}: the pooled tracks disagree (chi^2 {est.chi2:.1f} on "
                         f"{est.dof} dof, p {est.p_value:.1e})")
    return notes
