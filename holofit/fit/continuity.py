"""Trajectory continuity: frames left in a wrong local minimum, refitted from their neighbours.

A particle turns little between frames, so a good neighbour's fitted orientation is a start
inside the right basin for a frame whose library candidates led the fit into another one.
After the final pass (the sweeps, as batches: :mod:`holofit.fit.sweeps`):

1. **Suspects**: frames not ``ok`` (and not failed or skipped), frames whose reduced chi^2 is
   above the movie's bar (:func:`holofit.quality.chi2_bar`, which wrong-minimum frames cannot
   inflate), and frames whose axis is more than ``jump_factor`` times the movie's median
   frame-to-frame step away from a neighbour's (a wrong minimum close to the data shows only
   against a fit from the right start).
2. **Starts**: the fitted orientations (and heights and alphas) of the nearest *sources*
   before and after (``ok`` frames under the chi^2 bar), at most ``max_gap`` frames away; a
   start tried once for a frame is not tried again.
3. **Refit and merge**: the stage fits those frames from those starts (the same pixels and
   noise as the first fit, so the chi^2 compare exactly); a refit replaces the row when its
   chi^2 is lower by more than ``min_gain_chi2``, and the replaced fit becomes the runner-up
   if it is the closer competitor.
4. Sweeps repeat while rows improve (a run of bad frames is eaten from its ends), at most
   ``max_sweeps``.
5. **Flag** (``flag``): an ``ok`` frame still improbable for a frame in the right minimum
   becomes ``poor_fit`` (:func:`holofit.quality.flag_improbable`).

**Followed tables** (:func:`is_followed`: the pass followed the track,
:mod:`holofit.fit.follow`) were checked frame by frame already, so their suspects
(:func:`followed_suspects`) are only the frames not ``ok``, above the bar, ``ambiguous``,
re-acquired (``follow_source``), flagged ``follow_jump`` (with their neighbours: either side of
a jump may be the wrong one), and frames whose axis is more than ``followed_jump_factor``
times the median step from a neighbour's (where chunks were stitched). The median-step rule
of step 1, which would mark most frames of a smooth track, is kept for tables of independent
frames (``--independent-frames``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from holofit.fit.frame import SAME_BASIN_RAD, SAME_BASIN_Z_UM
from holofit.library.search import Candidate
from holofit.quality import chi2_bar, flag_bars, flag_improbable, join_message
from holofit.status import NOT_CONVERGED, OK, POOR_FIT

__all__ = [
    "ContinuityReport",
    "ContinuitySettings",
    "NeighbourStart",
    "followed_suspects",
    "is_followed",
    "merge_refits",
    "neighbour_starts",
    "repair_by_continuity",
    "sources",
    "suspects",
]

_CONVERGED = (OK, POOR_FIT)
#: statuses a refit may improve (failed, error and skipped frames have no fit to improve on)
_REFITTABLE = (OK, POOR_FIT, NOT_CONVERGED)


@dataclass(frozen=True)
class ContinuitySettings:
    """How the continuity sweeps run.

    Attributes
    ----------
    enabled : bool
        Run the sweeps at all.
    max_sweeps : int
        Most sweeps (the last ones, a few frames each, take seconds).
    max_gap : int
        Neighbours at most this many frames away give starts.
    chi2_sigmas : float
        Suspect bar on the reduced chi^2: the median plus this many lower-half spreads.
    jump_factor : float
        Suspect when the axis is this many median frame-to-frame steps from a neighbour's.
    followed_jump_factor : float
        On a followed table (:func:`is_followed`): suspect when the axis is this many median
        frame-to-frame steps from a neighbour's (the follower's ``step_factor``).
    min_gain_chi2 : float
        A refit replaces a row only if its chi^2 (residual sum of squares over the pixel
        noise^2) is lower by more than this: a refit that lands in the same minimum differs
        by solver precision only, and must not set off new refits of its neighbours.
    flag : bool
        Mark ``ok`` frames whose chi^2 is improbable after the sweeps ``poor_fit``
        (:func:`flag_bars`).
    flag_probability : float
        Probability that a frame in the right minimum is flagged (the one-sided tail of its
        chi^2 beyond the flag bar).
    """

    enabled: bool = True
    max_sweeps: int = 500
    max_gap: int = 5
    chi2_sigmas: float = 4.0
    jump_factor: float = 1.0
    followed_jump_factor: float = 5.0
    min_gain_chi2: float = 1.0
    flag: bool = True
    flag_probability: float = 1e-4

    def __post_init__(self) -> None:
        if self.max_sweeps < 0 or self.max_gap < 1:
            raise ValueError("continuity: max_sweeps >= 0 and max_gap >= 1 needed")
        if not (self.chi2_sigmas > 0 and self.jump_factor > 0 and self.followed_jump_factor > 0
                and self.min_gain_chi2 >= 0):
            raise ValueError("continuity: chi2_sigmas, jump_factor and followed_jump_factor "
                             "must be > 0, min_gain_chi2 >= 0")
        if not 0 < self.flag_probability < 0.5:
            raise ValueError("continuity: flag_probability must be in (0, 0.5), got "
                             f"{self.flag_probability}")


@dataclass(frozen=True)
class NeighbourStart:
    """Starts for one suspect frame: the neighbours' orientations, height and alpha."""

    candidates: tuple[Candidate, ...]
    sources: tuple[int, ...]
    z_um: float
    alpha: float


@dataclass
class ContinuityReport:
    """What the sweeps did (recorded in ``fit.csv``'s sidecar).

    Attributes
    ----------
    sweeps : int
        Sweeps run.
    refitted : int
        Frame refits over all sweeps.
    replaced : int
        Rows replaced by a better refit.
    flagged : int
        ``ok`` rows marked ``poor_fit`` for an improbable chi^2 (:func:`flag_bars`).
    chi2_bar : float
        The final suspect bar on the reduced chi^2.
    flag_bar : float
        The final flag bar on the reduced chi^2 of a frame with the movie's median pixel
        count (each frame's follows its own count).
    excess_scatter : float
        The measured relative scatter of the reduced chi^2 beyond the chi^2 distribution's.
    per_sweep : list of dict
        Suspects, refits and replacements of each sweep.
    """

    sweeps: int = 0
    refitted: int = 0
    replaced: int = 0
    flagged: int = 0
    chi2_bar: float = math.nan
    flag_bar: float = math.nan
    excess_scatter: float = math.nan
    per_sweep: list[dict[str, int]] = field(default_factory=list)

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


def _axes(table: pd.DataFrame) -> NDArray[np.float64]:
    return table[["ux", "uy", "uz"]].to_numpy(dtype=float)


def _angle(u: NDArray[np.float64], v: NDArray[np.float64], head_tail: bool) -> NDArray:
    dot = np.sum(u * v, axis=-1)
    if head_tail:
        dot = np.abs(dot)
    return np.arccos(np.clip(dot, -1.0, 1.0))


def suspects(table: pd.DataFrame, opts: ContinuitySettings, head_tail: bool,
             bar: float | None = None) -> NDArray[np.bool_]:
    """Which rows of a frame-sorted fit table may sit in a wrong minimum (see module doc).

    Parameters
    ----------
    table : DataFrame
        Fit table sorted by frame.
    opts : ContinuitySettings
        Bars.
    head_tail : bool
        Whether u and -u are one orientation.
    bar : float, optional
        The chi^2 bar (default: :func:`chi2_bar` of ``table``).

    Returns
    -------
    ndarray of bool
    """
    out = _unsound(table, opts, bar)
    out |= _axis_jumps(table, opts.jump_factor, head_tail)
    return out


def _unsound(table: pd.DataFrame, opts: ContinuitySettings,
             bar: float | None) -> NDArray[np.bool_]:
    """Refittable rows not ``ok`` or above the chi^2 bar."""
    status = table["status"].to_numpy()
    refittable = np.isin(status, _REFITTABLE)
    out = refittable & (status != OK)
    bar = chi2_bar(table, opts.chi2_sigmas) if bar is None else bar
    if math.isfinite(bar):
        out |= refittable & (table["chi2_red"].to_numpy(dtype=float) > bar)
    return out


def _axis_jumps(table: pd.DataFrame, factor: float, head_tail: bool) -> NDArray[np.bool_]:
    """``ok`` rows whose axis is more than ``factor`` median steps from a neighbour's."""
    out = np.zeros(len(table), dtype=bool)
    ok = table["status"].to_numpy() == OK
    u = _axes(table)
    usable = ok & np.all(np.isfinite(u), axis=1)
    idx = np.flatnonzero(usable)
    if idx.size >= 3:
        frames = table["frame"].to_numpy()
        steps = _angle(u[idx[1:]], u[idx[:-1]], head_tail)
        adjacent = np.diff(frames[idx]) == 1
        if adjacent.any():
            bar_jump = factor * float(np.median(steps[adjacent]))
            before = np.r_[np.inf, steps]
            after = np.r_[steps, np.inf]
            # a neighbour far away (an end has one neighbour)
            jump = np.fmax(np.where(np.isinf(before), np.nan, before),
                           np.where(np.isinf(after), np.nan, after)) > bar_jump
            out[idx[jump]] = True
    return out


def is_followed(table: pd.DataFrame) -> bool:
    """Whether the final pass followed the track (some row fitted warm, ``follow_source``)."""
    return "follow_source" in table and bool(
        table["follow_source"].astype(str).isin(("warm", "reacquired")).any())


def followed_suspects(table: pd.DataFrame, opts: ContinuitySettings, head_tail: bool,
                     bar: float | None = None) -> NDArray[np.bool_]:
    """The suspects of a frame-sorted followed table (see the module doc).

    Parameters and returns as :func:`suspects`.
    """
    status = table["status"].to_numpy()
    refittable = np.isin(status, _REFITTABLE)
    out = _unsound(table, opts, bar)
    out |= _axis_jumps(table, opts.followed_jump_factor, head_tail)
    out |= refittable & (table["follow_source"].astype(str) == "reacquired").to_numpy()
    if "ambiguous" in table:
        out |= refittable & (pd.to_numeric(table["ambiguous"], errors="coerce")
                             .fillna(0).to_numpy() > 0)
    if "follow_jump" in table:
        jump = pd.to_numeric(table["follow_jump"], errors="coerce").fillna(0).to_numpy() > 0
        frames = table["frame"].to_numpy()
        near = jump.copy()
        for i in np.flatnonzero(jump):  # the frames either side of the jump
            for j in (i - 1, i + 1):
                if 0 <= j < len(table) and abs(int(frames[j]) - int(frames[i])) <= opts.max_gap:
                    near[j] = True
        out |= refittable & near
    return out


def _candidate(row: Mapping[str, object]) -> Candidate:
    phi = row.get("phi_rad", 0.0)
    phi = 0.0 if phi is None or not math.isfinite(float(phi)) else float(phi)  # type: ignore[arg-type]
    return Candidate(float(row["psi_rad"]), float(row["theta_rad"]), phi,  # type: ignore[arg-type]
                     math.nan)


def sources(table: pd.DataFrame, bar: float) -> NDArray[np.bool_]:
    """Rows whose orientation may serve as a neighbour's start: ``ok``, under the chi^2 bar."""
    good = (table["status"] == OK).to_numpy() & np.all(np.isfinite(_axes(table)), axis=1)
    if math.isfinite(bar):
        good &= table["chi2_red"].to_numpy(dtype=float) <= bar
    return good


def neighbour_starts(table: pd.DataFrame, suspect: NDArray[np.bool_], source: NDArray[np.bool_],
                     opts: ContinuitySettings,
                     tried: set[tuple[int, int, float, float]]) -> dict[int, NeighbourStart]:
    """Starts for each suspect frame from its nearest sources (not tried before).

    Parameters
    ----------
    table : DataFrame
        Fit table sorted by frame.
    suspect : ndarray of bool
        From :func:`suspects`.
    source : ndarray of bool
        From :func:`sources`.
    opts : ContinuitySettings
        ``max_gap``.
    tried : set
        ``(frame, source frame, theta, psi)`` already tried; updated with the new starts.

    Returns
    -------
    dict
        Frame -> :class:`NeighbourStart`, for frames with at least one new start.
    """
    frames = table["frame"].to_numpy()
    rows = table.to_dict("records")
    out: dict[int, NeighbourStart] = {}
    pos = np.flatnonzero(source)
    for i in np.flatnonzero(suspect):
        f = int(frames[i])
        # the nearest source on each side (the frame itself is neither)
        before = int(np.searchsorted(pos, i, side="left")) - 1
        after = int(np.searchsorted(pos, i, side="right"))
        near = []
        if before >= 0 and f - frames[pos[before]] <= opts.max_gap:
            near.append(pos[before])
        if after < pos.size and frames[pos[after]] - f <= opts.max_gap:
            near.append(pos[after])
        cands, sources, zs, alphas = [], [], [], []
        for j in near:
            c = _candidate(rows[j])
            key = (f, int(frames[j]), round(c.theta, 6), round(c.psi, 6))
            if key in tried:
                continue
            tried.add(key)
            cands.append(c)
            sources.append(int(frames[j]))
            zs.append(float(rows[j]["z_um"]))  # type: ignore[arg-type]
            alphas.append(float(rows[j]["alpha"]))  # type: ignore[arg-type]
        if cands:
            out[f] = NeighbourStart(tuple(cands), tuple(sources), float(np.mean(zs)),
                                    float(np.mean(alphas)))
    return out


def _state_of(row: Mapping[str, object]) -> tuple[NDArray[np.float64], float]:
    return (np.array([row["ux"], row["uy"], row["uz"]], dtype=float),
            float(row["z_um"]))  # type: ignore[arg-type]


def merge_refits(table: pd.DataFrame, refits: pd.DataFrame, starts: Mapping[int, NeighbourStart],
                 head_tail: bool, ambiguity_chi2: float, min_gain_chi2: float = 0.0) -> int:
    """Put refits that fit better into ``table`` (in place); the number replaced.

    A refit replaces its frame's row when its chi^2 is lower by more than ``min_gain_chi2``
    (in pixel-noise units), or the old row has none. The
    replaced fit, if in another basin and closer than the refit's own runner-up, becomes the
    runner-up (``chi2_runner_up``, ``delta_chi2``, ``ambiguous``, ``runner_up_*``).
    """
    by_frame = {int(f): i for i, f in enumerate(table["frame"].to_numpy())}
    replaced = 0
    for new in refits.to_dict("records"):
        f = int(new["frame"])
        i = by_frame.get(f)
        if i is None or new.get("status") not in _REFITTABLE:
            continue
        old = table.iloc[i].to_dict()
        chi_new, chi_old = float(new["chi2"]), float(old["chi2"])
        noise = float(new["noise_sd"])
        gain = ((chi_old - chi_new) * float(new["n_pixels"]) / noise**2 if noise > 0
                else chi_old - chi_new)
        if not math.isfinite(chi_new) or (math.isfinite(chi_old) and not gain > min_gain_chi2):
            continue
        u_new, z_new = _state_of(new)
        u_old, z_old = _state_of(old)
        other_basin = (np.all(np.isfinite(u_old)) and (
            float(_angle(u_new, u_old, head_tail)) >= SAME_BASIN_RAD
            or abs(z_new - z_old) >= SAME_BASIN_Z_UM))
        runner = float(new.get("chi2_runner_up", math.nan))
        if other_basin and math.isfinite(chi_old) and not chi_old >= runner and noise > 0:
            delta = (chi_old - chi_new) * float(new["n_pixels"]) / noise**2
            new.update(chi2_runner_up=chi_old, delta_chi2=delta,
                       ambiguous=int(delta < ambiguity_chi2),
                       runner_up_theta_rad=old["theta_rad"], runner_up_psi_rad=old["psi_rad"],
                       runner_up_z_um=old["z_um"])
        source = _winning_source(new, starts.get(f))
        note = ("started from the fitted orientation of frame "
                f"{source} (trajectory continuity)" if source is not None
                else "refitted from a neighbour's orientation (trajectory continuity)")
        msg = str(new.get("message") or "")
        new["message"] = join_message(msg, note)
        for col in table.columns:
            if col in new:
                table.iat[i, table.columns.get_loc(col)] = new[col]
        replaced += 1
    return replaced


def _winning_source(row: Mapping[str, object], start: NeighbourStart | None) -> int | None:
    if start is None:
        return None
    theta, psi = row.get("start_theta_rad"), row.get("start_psi_rad")
    for c, s in zip(start.candidates, start.sources, strict=True):
        if (isinstance(theta, float) and isinstance(psi, float)
                and math.isclose(c.theta, theta, abs_tol=1e-9)
                and math.isclose(c.psi, psi, abs_tol=1e-9)):
            return s
    return start.sources[0] if len(start.sources) == 1 else None


def repair_by_continuity(
    table: pd.DataFrame,
    refit: Callable[[int, dict[int, NeighbourStart]], pd.DataFrame],
    opts: ContinuitySettings,
    *,
    head_tail: bool,
    ambiguity_chi2: float,
    refinish: Callable[[pd.DataFrame], object] | None = None,
) -> tuple[pd.DataFrame, ContinuityReport]:
    """Run the continuity sweeps on a final-pass table (see the module docstring).

    Parameters
    ----------
    table : DataFrame
        The final pass's fit table.
    refit : callable
        ``refit(sweep, starts)`` fits the frames of ``starts`` from their neighbour starts and
        returns their rows (the stage runs it through the batch runner).
    opts : ContinuitySettings
        Settings.
    head_tail : bool
        Whether u and -u are one orientation.
    ambiguity_chi2 : float
        As :class:`holofit.fit.frame.FrameFitSettings`.
    refinish : callable, optional
        Re-applied to the table after each merge (the movie's outlier rule).

    Returns
    -------
    table : DataFrame
        Sorted by frame, with better refits merged and, with ``flag``, frames still above the
        chi^2 bar marked ``poor_fit``.
    report : ContinuityReport
    """
    table = table.sort_values("frame").reset_index(drop=True)
    for col in ("status", "message"):  # an all-empty message column reads back as floats
        table[col] = table[col].astype(object).where(table[col].notna(), "")
    report = ContinuityReport()
    if not opts.enabled or table.empty:
        return table, report
    tried: set[tuple[int, int, float, float]] = set()
    pick = followed_suspects if is_followed(table) else suspects
    for sweep in range(1, opts.max_sweeps + 1):
        bar = chi2_bar(table, opts.chi2_sigmas)
        suspect = pick(table, opts, head_tail, bar)
        starts = neighbour_starts(table, suspect, sources(table, bar), opts, tried)
        if not starts:
            break
        rows = refit(sweep, starts)
        n = merge_refits(table, rows, starts, head_tail, ambiguity_chi2, opts.min_gain_chi2)
        if refinish is not None:
            refinish(table)
        report.sweeps = sweep
        report.refitted += len(starts)
        report.replaced += n
        report.per_sweep.append({"suspects": int(suspect.sum()), "refitted": len(starts),
                                 "replaced": n})
        if n == 0:
            break
    report.chi2_bar = chi2_bar(table, opts.chi2_sigmas)
    if opts.flag:
        report.flagged, flags = flag_improbable(table, opts.flag_probability)
    else:
        flags = flag_bars(table, opts.flag_probability)
    report.flag_bar, report.excess_scatter = flags.typical, flags.excess
    return table, report

