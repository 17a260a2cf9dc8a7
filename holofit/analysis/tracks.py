"""Diffusion of every track in a field of view, and the tracks pooled.

A multi-particle fit table holds one row per (``particle``, ``frame``); ``particle`` is the track
id (trackpy's name). Each track is analysed on its own, exactly as a single-particle table is
(:func:`holofit.analysis.pipeline.analyze_trajectory`). The tracks of one run are fitted with
one particle model, so their coefficients estimate the same quantities and are pooled:

* the pooled value is the inverse-variance weighted mean ``sum(w_i x_i) / sum(w_i)`` with
  ``w_i = 1 / sigma_i^2``, its error ``1 / sqrt(sum w_i)``;
* the tracks' consistency is ``chi^2 = sum(w_i (x_i - mean)^2)`` on ``n - 1`` degrees of
  freedom, with its p-value: a small p says the tracks are not alike;
* each track's pull against the mean of the *other* tracks,
  ``(x_i - mean_{-i}) / sqrt(sigma_i^2 + sigma_{mean,-i}^2)``, names the one that is not like
  the others (an impurity, a dimer among rods): ``|pull| > outlier_sigma`` marks it
  ``outlier`` in the pooled table, and it is left out of that quantity's pooled value.

Tracks are left out of the pool, and say why, when they are too short (``short``), when most of
their fitted frames missed the particle model (``poor_fit``: dust or an impurity, not the
particle the model describes), when their analysis failed (``failed``), or when they fail the
physical-consistency check (``flagged``: a hydrodynamic size unlike the fitted one, sticking, a
drift that changes, swimming; :mod:`holofit.analysis.consistency`), unless
``TrackPooling(include_flagged=True)`` asks for them; the message and ``tracks.csv`` give the
numbers.
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
from holofit.analysis.results import AnalysisResult
from holofit.analysis.settings import AnalysisConfig
from holofit.analysis.trajectory import Trajectory
from holofit.io.tables import sidecar_path, write_table
from holofit.provenance import sidecar
from holofit.status import OK, POOR_FIT
from holofit.tables.fit import FitTableError, validate_fit_table

__all__ = [
    "CHECK_COLUMNS",
    "TRACK_COLUMN",
    "PooledEstimate",
    "TrackPooling",
    "TrackResult",
    "TracksResult",
    "analyze_tracks",
    "check_columns",
    "format_tracks_report",
    "has_tracks",
    "n_tracks",
    "pool_estimates",
    "pooled_rows",
    "split_tracks",
    "track_rows",
    "write_tracks",
]

#: the column that holds the track id (trackpy's name)
TRACK_COLUMN = "particle"
#: the quantities pooled over tracks, when a track's analysis measured them
POOLED_QUANTITIES = ("D_t", "D_par", "D_perp", "D_r", "D_xy")


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
    """One track: its frames, why it is (not) pooled, and its analysis.

    Attributes
    ----------
    particle : int
        Track id.
    n_frames, n_ok, n_poor : int
        Rows of the track, ``ok`` rows, ``poor_fit`` rows.
    status : {"analysed", "short", "poor_fit", "failed", "flagged"}
        ``analysed`` tracks are pooled (``flagged`` ones only when the pooling asks).
    message : str
        Why, for the others.
    result : AnalysisResult or None
        The track's analysis (also for ``poor_fit`` tracks, when it ran).
    """

    particle: int
    n_frames: int
    n_ok: int
    n_poor: int
    status: str
    message: str = ""
    result: AnalysisResult | None = None

    @property
    def poor_fraction(self) -> float:
        fitted = self.n_ok + self.n_poor
        return self.n_poor / fitted if fitted else math.nan


@dataclass
class PooledEstimate:
    """One quantity pooled over tracks (inverse-variance weighted).

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


@dataclass
class TracksResult:
    """Every track's analysis and the pooled estimates."""

    tracks: list[TrackResult]
    pooled: dict[str, PooledEstimate]
    pooling: TrackPooling
    notes: list[str] = field(default_factory=list)


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


def _pool(quantity: str, tracks: list[TrackResult], pooling: TrackPooling
          ) -> PooledEstimate | None:
    sigma = pooling.outlier_sigma
    use = _pooled_status(pooling)
    rows = [(t.particle, t.result.measured[quantity]) for t in tracks
            if t.status in use and t.result is not None and quantity in t.result.measured]
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
    )


def _analyse_track(particle: int, rows: pd.DataFrame, settings: AnalysisConfig,
                   pooling: TrackPooling, source: str, dt: float | None) -> TrackResult:
    status = rows["status"].astype(str).str.strip().str.lower()
    n_ok, n_poor = int((status == OK).sum()), int((status == POOR_FIT).sum())
    track = TrackResult(particle, len(rows), n_ok, n_poor, "analysed")
    if n_ok < pooling.min_frames:
        track.status = "short"
        track.message = f"{n_ok} ok frame(s), fewer than {pooling.min_frames}: not analysed"
        return track
    try:
        fit = validate_fit_table(rows, f"{source} (particle {particle})", dt)
        track.result = analyze_trajectory(
            Trajectory.from_fit_table(fit, bool(settings.drop_ambiguous)), settings)
    except (FitTableError, AnalysisError) as exc:
        track.status, track.message = "failed", str(exc)
        return track
    if track.poor_fraction > pooling.max_poor_fraction:
        track.status = "poor_fit"
        track.message = (f"{n_poor} of {n_ok + n_poor} fitted frames are poor_fit "
                         f"({100 * track.poor_fraction:.0f} %): not the particle the model "
                         "describes (dust, an impurity?); not pooled")
    elif track.result.flagged:
        assert track.result.consistency is not None
        track.status = "flagged"
        track.message = track.result.consistency.message + (
            "; pooled as asked (include_flagged)" if pooling.include_flagged
            else "; not pooled (TrackPooling(include_flagged=True) pools it)")
    return track


def analyze_tracks(path: str | Path, settings: AnalysisConfig, *,
                   pooling: TrackPooling | None = None,
                   frame_interval_s: float | None = None) -> TracksResult:
    """Analyse every track of a multi-particle fit table and pool them.

    Parameters
    ----------
    path : str or Path
        A fit table with a ``particle`` column (and its sidecar, for the frame interval).
    settings : AnalysisConfig
        How each track is analysed (the same for all).
    pooling : TrackPooling, optional
        Which tracks are analysed and pooled.
    frame_interval_s : float, optional
        Overrides the sidecar's frame interval, s.

    Raises
    ------
    AnalysisError
        No track column, no rows, or no track long enough to analyse (naming the file).
    """
    pooling = pooling or TrackPooling()
    path = Path(path)
    table = pd.read_csv(path, dtype={"status": str, "message": str})
    if not has_tracks(table):
        raise AnalysisError(f"{path}: no {TRACK_COLUMN!r} column: a single-particle table "
                            "(analyse it with analyze_table)")
    if table.empty:
        raise AnalysisError(f"{path}: the table has no rows")
    dt = frame_interval_s if frame_interval_s is not None else _sidecar_interval(path)
    tracks = [_analyse_track(p, rows, settings, pooling, str(path), dt)
              for p, rows in split_tracks(table, str(path)).items()]
    if not any(t.result is not None for t in tracks):
        raise AnalysisError(f"{path}: no track could be analysed ("
                            + "; ".join(f"particle {t.particle}: {t.message}" for t in tracks)
                            + ")")
    pooled = {q: est for q in POOLED_QUANTITIES
              if (est := _pool(q, tracks, pooling)) is not None}
    return TracksResult(tracks, pooled, pooling, _notes(tracks, pooled, pooling))


def _sidecar_interval(path: Path) -> float | None:
    side = sidecar_path(path)
    if not side.is_file():
        return None
    try:
        value = json.loads(side.read_text()).get("frame_interval_s")
    except json.JSONDecodeError as exc:
        raise AnalysisError(f"{side}: sidecar is not valid JSON ({exc})") from None
    return float(value) if isinstance(value, int | float) else None


def _notes(tracks: list[TrackResult], pooled: dict[str, PooledEstimate], pooling: TrackPooling
           ) -> list[str]:
    sigma = pooling.outlier_sigma
    notes = [f"particle {t.particle}: {t.status}: {t.message}" for t in tracks
             if t.status != "analysed"]
    for est in pooled.values():
        if est.outliers:
            notes.append(f"{est.quantity}: particle(s) {', '.join(map(str, est.outliers))} not "
                         f"like the others (|pull| > {sigma:g}): left out of the pooled value")
        if est.dof > 0 and est.p_value < 1e-3:
            notes.append(f"{est.quantity}: the pooled tracks disagree (chi^2 {est.chi2:.1f} on "
                         f"{est.dof} dof, p {est.p_value:.1e})")
    return notes


#: the consistency columns of ``tracks.csv`` (:func:`check_columns`)
CHECK_COLUMNS = ("flagged", "check_failed", "check_threshold_p", "check_min_p",
                 "size_ratio_t", "size_ratio_t_err", "size_z_t", "size_ratio_r",
                 "size_ratio_r_err", "size_z_r")


def check_columns(result: AnalysisResult | None) -> dict[str, Any]:
    """A track's consistency numbers (:data:`CHECK_COLUMNS`): whether it is flagged, the
    tests it failed, the per-test threshold and the smallest p-value, and the hydrodynamic /
    optical size ratio with its error and ``z`` from ``D_t`` and ``D_r`` (NaN where not
    tested)."""
    out: dict[str, Any] = dict.fromkeys(CHECK_COLUMNS, math.nan)
    c = result.consistency if result is not None else None
    if c is None:
        return out
    ps = [t.p_value for t in c.tests if math.isfinite(t.p_value)]
    out.update(flagged=c.flagged, check_failed=" ".join(n.replace(" ", "_") for n in c.failed),
               check_threshold_p=c.threshold, check_min_p=min(ps) if ps else math.nan)
    for key, name in (("t", "size D_t"), ("r", "size D_r")):
        t = c.test(name)
        if t is not None and "size_ratio" in t.values:
            out[f"size_ratio_{key}"] = t.values["size_ratio"]
            out[f"size_ratio_{key}_err"] = t.values["size_ratio_err"]
            out[f"size_z_{key}"] = t.statistic
    return out


def track_rows(result: TracksResult) -> list[dict[str, Any]]:
    """One row per (track, quantity) for ``tracks.csv`` (tracks not analysed: one row), with
    the track's consistency numbers (:func:`check_columns`)."""
    rows: list[dict[str, Any]] = []
    for t in result.tracks:
        base = {"particle": t.particle, "status": t.status, "n_frames": t.n_frames,
                "n_ok": t.n_ok, "n_poor_fit": t.n_poor, "message": t.message,
                **check_columns(t.result)}
        measured = t.result.measured if t.result is not None else {}
        qs = [q for q in POOLED_QUANTITIES if q in measured]
        if not qs:
            rows.append({**base, "quantity": "", "measured": math.nan, "measured_err": math.nan,
                         "pull": math.nan, "pooled": False})
        for q in qs:
            m, est = measured[q], result.pooled.get(q)
            rows.append({**base, "quantity": q, "unit": m.unit, "measured": m.value,
                         "measured_err": m.error,
                         "pull": est.pulls.get(t.particle, math.nan) if est else math.nan,
                         "pooled": bool(est and t.particle in est.particles)})
    return rows


def pooled_rows(result: TracksResult) -> list[dict[str, Any]]:
    """One row per quantity for ``pooled.csv``."""
    return [{"quantity": e.quantity, "unit": e.unit, "value": e.value, "error": e.error,
             "chi2": e.chi2, "dof": e.dof, "p_value": e.p_value, "n_tracks": len(e.particles),
             "particles": " ".join(map(str, e.particles)),
             "outliers": " ".join(map(str, e.outliers))} for e in result.pooled.values()]


def write_tracks(result: TracksResult, out_dir: str | Path, inputs: list[str | Path]
                 ) -> dict[str, Path]:
    """Write ``tracks.csv`` and ``pooled.csv`` (+ sidecars, atomically; ``pooled.csv`` last)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cfg = {"pooling": result.pooling.__dict__}
    units = {"measured": "unit column", "measured_err": "unit column", "pull": "1",
             "check_threshold_p": "1", "check_min_p": "1", "size_ratio_t": "1",
             "size_ratio_t_err": "1", "size_z_t": "1 (sigma)", "size_ratio_r": "1",
             "size_ratio_r_err": "1", "size_z_r": "1 (sigma)"}
    files = {"tracks": write_table(out / "tracks.csv", pd.DataFrame(track_rows(result)),
                                   sidecar(kind="diffusion per track", units=units, config=cfg,
                                           inputs=inputs, extra={"notes": result.notes}))}
    files["pooled"] = write_table(
        out / "pooled.csv", pd.DataFrame(pooled_rows(result)),
        sidecar(kind="diffusion pooled over tracks (inverse-variance weighted)",
                units={"value": "unit column", "error": "unit column", "chi2": "1"},
                config=cfg, inputs=inputs, extra={"notes": result.notes}))
    return files


def format_tracks_report(result: TracksResult) -> str:
    """A short text report: each track, then the pooled values and their consistency."""
    lines = ["tracks:"]
    for t in result.tracks:
        d = t.result.measured.get("D_t") if t.result is not None else None
        dtxt = f"D_t {d.value:.3f} +- {d.error:.3f} um^2/s" if d is not None else ""
        lines.append(f"  particle {t.particle}: {t.n_ok}/{t.n_frames} ok frames, {t.status}"
                     + (f", {dtxt}" if dtxt else "") + (f" ({t.message})" if t.message else ""))
    lines.append("pooled over tracks (inverse-variance weighted):")
    for e in result.pooled.values():
        consistency = (f"chi^2 {e.chi2:.1f} on {e.dof} dof, p {e.p_value:.2g}" if e.dof > 0
                       else "one track")
        lines.append(f"  {e.quantity:<7} {e.value:.3f} +- {e.error:.3f} {e.unit} from "
                     f"{len(e.particles)} track(s); {consistency}"
                     + (f"; outliers: {' '.join(map(str, e.outliers))}" if e.outliers else ""))
    lines += [f"note: {n}" for n in result.notes]
    return "\n".join(lines)
