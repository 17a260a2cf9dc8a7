"""How good a fit is: every chi^2 bar and every rule that makes a row ``poor_fit``.

One module holds them so that a row's status always means the same thing, whichever stage
or pass wrote it. Each rule is a function that changes ``ok`` rows (or one fit) to
``poor_fit`` and says why in the message; none changes any other status, and none is undone
by applying it again. The rules, in the order a fit meets them:

=========================  ===============================================================
rule                       a converged fit becomes ``poor_fit`` when
=========================  ===============================================================
:func:`judge_fit`          a parameter ends outside its physical or search range, the model
                           explains no more than a flat background would (no particle), or
                           its reduced chi^2 is far above the noise with an R^2 below
                           ``good_r2`` (:class:`QualityLimits`)
:func:`flag_small_crop`    (prefit) the crop is too small for the hologram it holds
:func:`flag_outliers`      its reduced chi^2 is ``factor`` times the track's median
:func:`flag_improbable`    its chi^2 is improbable for a frame in the track's right minimum
                           (the pixel noise and the track's excess scatter)
:func:`flag_off_level`     (initial pass) it fits clearly worse than the pass's best quarter
:func:`flag_above_bar`     (following a track) it stays above the movie's bar after
                           re-acquisition
=========================  ===============================================================

A low R^2 alone never makes a fit poor: a faint particle fitted down to the camera noise has
a low R^2 and an honest error. The bars: :func:`chi2_bar` (median plus a lower-half spread;
which frames are suspects),
:func:`small_sample_bar` (the same for a few rows, the spread at least the noise model's),
:func:`initial_level` (the initial pass's best quarter) and :func:`flag_bars` (per-row bars
from the chi^2 distribution and the movie's excess scatter). The numbers behind the defaults
are in the docs' validation pages.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy import stats

from holofit.status import OK, POOR_FIT

__all__ = [
    "EXCESS_FLOOR",
    "FLAG_PROBABILITY",
    "FlagBars",
    "Goodness",
    "QualityLimits",
    "chi2_bar",
    "flag_above_bar",
    "flag_bars",
    "flag_improbable",
    "flag_off_level",
    "flag_outliers",
    "flag_small_crop",
    "initial_level",
    "join_message",
    "judge_fit",
    "outlier_rule",
    "outlier_sidecar",
    "per_track",
    "small_sample_bar",
    "under_bar",
]

#: statuses of a converged fit (the bars are taken over these)
CONVERGED = (OK, POOR_FIT)
#: the lower-half spread is median minus this quantile (one normal sd below the median)
_ONE_SIGMA_BELOW = 15.87
#: the least relative scatter of a right-minimum frame's reduced chi^2 beyond the chi^2
#: distribution's (the noise estimate's error, the model's frame-to-frame misfit)
EXCESS_FLOOR = 0.01
#: a normal sample's 25 % quantile lies this many standard deviations above its 5 % one
_Q05_TO_Q25_SIGMAS = 0.971
#: fewer converged rows than this: no initial level (a quarter of them is not a reference)
LEVEL_MIN_ROWS = 4
#: scatter measured from the lower half of n values is as uncertain as a sample standard
#: deviation with n / 3 degrees of freedom; its relative bias, about -0.8 / n, is divided out
_DOF_PER_ROW = 1.0 / 3.0
_LOWER_HALF_BIAS = 0.8


def join_message(a: str, b: str) -> str:
    """``a; b``, or ``b`` alone where ``a`` is empty or only says the fit converged."""
    a = "" if not isinstance(a, str) or a == "nan" else a
    return b if not a or a == "converged" else f"{a}; {b}"


def _append(table: pd.DataFrame, rows: NDArray[np.bool_], note: str) -> None:
    """Mark ``rows`` of ``table`` ``poor_fit`` and add ``note`` to their messages (in place)."""
    if "message" not in table:
        table["message"] = ""
    table["message"] = table["message"].astype(object)
    table.loc[rows, "status"] = POOR_FIT
    table.loc[rows, "message"] = [join_message(m, note) for m in table.loc[rows, "message"]]


# -- one fit ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class QualityLimits:
    """When a converged fit is still not ``ok`` (:func:`judge_fit`).

    Attributes
    ----------
    max_chi2_red : float
        Largest reduced chi^2 (residual over the camera noise) of an ``ok`` fit whose R^2 is
        below ``good_r2``: the gross bar of a fit on its own; whether a chi^2 is probable for
        the frames of a track is :func:`flag_improbable`'s.
    good_r2 : float
        A fit that explains this much of the fringe variance is close to the data even when
        its reduced chi^2 is large: real holograms carry imperfections of the set-up far
        above a low camera noise.
    detection_probability : float
        A fit whose chi^2 gain over a flat background would be reached by the noise alone
        with at least this probability (the chi^2 distribution with as many degrees of
        freedom as fitted parameters) found no particle.
    ranges : dict
        Parameter name -> (low, high): an ``ok`` fit ends inside (besides each parameter's
        physical range).
    """

    max_chi2_red: float = 10.0
    good_r2: float = 0.8
    detection_probability: float = 1e-4
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.max_chi2_red > 0:
            raise ValueError(f"max_chi2_red must be > 0, got {self.max_chi2_red}")


@dataclass(frozen=True)
class Goodness:
    """How close one fit is to its data.

    Attributes
    ----------
    chi2_red : float
        Residual sum of squares over ``noise_sd^2 (N - p)``.
    r2 : float
        Coefficient of determination.
    signal_chi2 : float
        The chi^2 the model explains beyond a flat level: ``(sum (d - mean d)^2 - rss) /
        noise_sd^2``.
    n_params : int
        Fitted parameters.
    """

    chi2_red: float
    r2: float
    signal_chi2: float = math.inf
    n_params: int = 0


def judge_fit(out_of_range: list[str], values: dict[str, float], fitted: tuple[str, ...],
              goodness: Goodness, limits: QualityLimits) -> tuple[str, str]:
    """The status of a converged fit and why: ``("ok", "")`` or ``("poor_fit", reasons)``.

    Parameters
    ----------
    out_of_range : list of str
        The parameter space's own complaints (a parameter outside its physical range).
    values : dict
        The fitted values.
    fitted : tuple of str
        The parameters the optimiser varied (``limits.ranges`` applies to those).
    goodness : Goodness
        How close the fit is to its data.
    limits : QualityLimits
        The limits.
    """
    reasons = list(out_of_range)
    for name, (lo, hi) in limits.ranges.items():
        v = values.get(name, math.nan)
        if name in fitted and not lo <= v <= hi:
            reasons.append(f"{name} = {v:.4g} outside [{lo:.4g}, {hi:.4g}]")
    chi2_red, r2 = goodness.chi2_red, goodness.r2
    if goodness.n_params > 0 and math.isfinite(goodness.signal_chi2):
        bar = float(stats.chi2.isf(limits.detection_probability, goodness.n_params))
        if not goodness.signal_chi2 > bar:
            reasons.append(f"no particle: the model explains chi^2 {goodness.signal_chi2:.3g} "
                           f"beyond a flat background, what noise alone reaches with "
                           f"probability {limits.detection_probability:g} (chi^2 {bar:.3g})")
    if math.isfinite(chi2_red) and chi2_red > limits.max_chi2_red and not r2 >= limits.good_r2:
        reasons.append(f"reduced chi2 {chi2_red:.3g} > {limits.max_chi2_red:g} with R^2 "
                       f"{r2:.3g} < {limits.good_r2:g} (residual far above the pixel noise)")
    if reasons:
        return POOR_FIT, "; ".join(reasons)
    return OK, ""


class _Judged(Protocol):
    """What the one-fit rules change: a fit's status and message (a ``FitResult``)."""

    status: str
    message: str
    chi2_red: float


def flag_small_crop(result: _Judged, why: str) -> None:
    """An ``ok`` prefit whose crop is too small for its hologram (``why``, non-empty: the
    fringes the fit needs run off the crop) becomes ``poor_fit``."""
    if result.status == OK and why:
        result.status, result.message = POOR_FIT, why


def under_bar(result: _Judged, chi2_bar: float | None) -> bool:
    """Whether a fit is ``ok`` and its reduced chi^2 at most ``chi2_bar`` (no bar: any)."""
    if result.status != OK:
        return False
    return chi2_bar is None or not math.isfinite(chi2_bar) or result.chi2_red <= chi2_bar


def flag_above_bar(result: _Judged, chi2_bar: float | None) -> None:
    """An ``ok`` fit above the movie's bar (:func:`under_bar`) becomes ``poor_fit``: a frame
    that neither its neighbour's fit nor the library's starts bring under the bar."""
    if result.status == OK and not under_bar(result, chi2_bar):
        result.status = POOR_FIT
        result.message = join_message(result.message, f"reduced chi^2 {result.chi2_red:.3g} "
                                      f"above the movie's bar {chi2_bar:.3g}")


# -- a track's table ------------------------------------------------------------------------
def per_track(rule: Callable[[pd.DataFrame], int]) -> Callable[[pd.DataFrame], int]:
    """``rule`` applied to each track's rows of a table keyed by ``(particle, frame)`` (in
    place; the rows newly flagged): every track is its own movie, with its own chi^2 level."""

    def apply(table: pd.DataFrame) -> int:
        if "particle" not in table or table["particle"].nunique() <= 1:
            return rule(table)
        flagged = 0
        for _, index in table.groupby("particle", sort=True).groups.items():
            part = table.loc[index].copy()
            n = rule(part)
            if n:
                table.loc[index, ["status", "message"]] = part[["status", "message"]]
                flagged += n
        return flagged

    return apply


def flag_outliers(table: pd.DataFrame, factor: float = 4.0, min_rows: int = 10) -> int:
    """Mark ``ok`` rows whose reduced chi^2 is more than ``factor`` times the median of the
    converged rows ``poor_fit`` (in place; the rows newly flagged).

    Real holograms never match a model down to the camera noise, so an absolute bar is either
    loose or flags every frame; within one track a frame ``factor`` times the median is an
    outlier. The median is over a set that flagging does not change. Fewer than ``min_rows``
    converged rows: nothing is flagged.
    """
    converged = table["status"].isin(CONVERGED).to_numpy()
    chi = table["chi2_red"].to_numpy(dtype=float)
    good = converged & np.isfinite(chi)
    if good.sum() < min_rows:
        return 0
    median = float(np.median(chi[good]))
    bad = (table["status"] == OK).to_numpy() & (chi > factor * median)
    if not bad.any():
        return 0
    _append(table, bad, f"reduced chi2 more than {factor:g} times the movie's median "
                        f"({median:.3g}): an outlier frame")
    return int(bad.sum())


#: the default probability that a frame in the right minimum is flagged by its chi^2
#: (:func:`flag_improbable`)
FLAG_PROBABILITY = 1e-4


def outlier_rule(factor: float, probability: float | None = FLAG_PROBABILITY
                 ) -> Callable[[pd.DataFrame], int]:
    """The table finisher of a pass of frames fitted with fixed statics: each track's
    outliers at ``factor`` times its median (:func:`flag_outliers`), then its frames whose
    chi^2 is improbable (:func:`flag_improbable` at ``probability``; None: not). The batch
    runner applies it before the table is written, so a table that looks complete is always
    flagged."""

    def finish(table: pd.DataFrame) -> int:
        n = flag_outliers(table, factor)
        if probability is not None:
            n += flag_improbable(table, probability)[0]
        return n

    return per_track(finish)


def outlier_sidecar(factor: float, probability: float | None = FLAG_PROBABILITY
                    ) -> dict[str, Any]:
    """How :func:`outlier_rule` is recorded in a fit table's sidecar."""
    doc: dict[str, Any] = {
        "outlier_factor": factor,
        "rule": "ok rows whose chi2_red exceeds outlier_factor x the median chi2_red of the "
                "converged rows of their track become poor_fit"}
    if probability is not None:
        doc["flag_probability"] = probability
        doc["improbable"] = ("ok rows whose chi2_red a frame in the right minimum exceeds with "
                             "at most flag_probability (the chi^2 distribution of its pixels "
                             "and the track's excess scatter) become poor_fit")
    return doc


# -- bars ---------------------------------------------------------------------------------------
def chi2_bar(table: pd.DataFrame, sigmas: float, min_rows: int = 10) -> float:
    """``median + sigmas * (median - q15.87)`` of the converged rows' ``chi2_red``: the
    reduced chi^2 above which a frame is a suspect (NaN: fewer than ``min_rows`` rows). The
    spread of the lower half is one that frames in a wrong minimum cannot inflate."""
    chi = table.loc[table["status"].isin(CONVERGED), "chi2_red"].to_numpy(dtype=float)
    chi = chi[np.isfinite(chi)]
    if chi.size < min_rows:
        return math.nan
    med = float(np.median(chi))
    return med + sigmas * max(med - float(np.percentile(chi, _ONE_SIGMA_BELOW)), 0.0)


def small_sample_bar(table: pd.DataFrame, sigmas: float, min_rows: int = 10,
                     excess_floor: float = EXCESS_FLOOR) -> float:
    """:func:`chi2_bar` for a table with too few converged rows to measure the spread.

    The bar is ``median * (1 + sigmas * spread)`` with the relative spread the larger of the
    one measured on the rows (from 5 rows on) and the noise model's, ``sqrt(2 / nu +
    excess_floor^2)`` for the rows' median pixel count ``nu``, widened by ``sqrt(1 + pi /
    (2 n))`` for the error of a median of ``n`` rows. From ``min_rows`` rows on it is
    :func:`chi2_bar` itself. NaN when no row converged or no pixel count is known.
    """
    conv = table["status"].isin(CONVERGED).to_numpy()
    chi = table["chi2_red"].to_numpy(dtype=float)
    keep = conv & np.isfinite(chi)
    n = int(keep.sum())
    if n >= min_rows:
        return chi2_bar(table, sigmas, min_rows)
    if n == 0 or "n_pixels" not in table:
        return math.nan
    nu = table["n_pixels"].to_numpy(dtype=float)[keep]
    nu = nu[np.isfinite(nu) & (nu > 0)]
    if nu.size == 0:
        return math.nan
    chi = chi[keep]
    med = float(np.median(chi))
    model = math.sqrt(2.0 / float(np.median(nu)) + excess_floor**2)
    measured = (max(med - float(np.percentile(chi, _ONE_SIGMA_BELOW)), 0.0) / med
                if n >= 5 else 0.0)
    spread = max(model, measured) * math.sqrt(1.0 + math.pi / (2.0 * n))
    return med * (1.0 + sigmas * spread)


def initial_level(table: pd.DataFrame, sigmas: float,
                  excess_floor: float = EXCESS_FLOOR) -> float:
    """The reduced chi^2 above which an initial-pass row fits clearly worse than the pass's
    best quarter of frames.

    ``level = q25 * (1 + sigmas * max(sqrt(2 / nu + floor^2), (q25 - q05) / (0.971 q25)))``
    with ``q25``, ``q05`` the converged rows' quantiles and ``nu`` their median pixel count:
    the initial pass has no bar of its own, and its rows' median is not a safe reference when
    half of them may sit in a wrong minimum. NaN with fewer than :data:`LEVEL_MIN_ROWS`
    converged rows or no pixel count.
    """
    conv = table["status"].isin(CONVERGED).to_numpy()
    chi = table["chi2_red"].to_numpy(dtype=float)
    keep = conv & np.isfinite(chi)
    if int(keep.sum()) < LEVEL_MIN_ROWS or "n_pixels" not in table:
        return math.nan
    nu = table["n_pixels"].to_numpy(dtype=float)[keep]
    nu = nu[np.isfinite(nu) & (nu > 0)]
    if nu.size == 0:
        return math.nan
    q05, q25 = (float(q) for q in np.percentile(chi[keep], [5.0, 25.0]))
    noise = math.sqrt(2.0 / float(np.median(nu)) + excess_floor**2)
    measured = (q25 - q05) / (_Q05_TO_Q25_SIGMAS * q25) if q25 > 0 else 0.0
    return q25 * (1.0 + sigmas * max(noise, measured))


def flag_off_level(table: pd.DataFrame, sigmas: float) -> int:
    """Mark the initial pass's ``ok`` rows above :func:`initial_level` ``poor_fit`` (in
    place; the rows newly flagged): they fix neither the static parameters nor the final
    pass's bar."""
    level = initial_level(table, sigmas)
    if not math.isfinite(level):
        return 0
    chi = table["chi2_red"].to_numpy(dtype=float)
    off = (table["status"] == OK).to_numpy() & (chi > level)
    if not off.any():
        return 0
    _append(table, off, f"chi2_red above {level:.4g}, the initial pass's best quarter of "
                        f"frames + {sigmas:g} spreads: a wrong minimum or a start far off; not "
                        "used for the static parameters")
    return int(off.sum())


def _to_symmetric(ratio: NDArray[np.float64]) -> NDArray[np.float64]:
    """Box-Cox transform with exponent -1/2, ``2 (1 - ratio^(-1/2))``, of reduced chi^2
    ratios to the movie's median: the scale on which the scatter is measured, where the part
    that comes from the noise estimate (``chi2_red ~ 1 / noise_sd^2``) is symmetric. To first
    order it is ``ratio - 1``."""
    return 2.0 * (1.0 - 1.0 / np.sqrt(ratio))


def _from_symmetric(y: NDArray[np.float64]) -> NDArray[np.float64]:
    """The ratio whose :func:`_to_symmetric` is ``y`` (infinite for ``y >= 2``)."""
    y = np.asarray(y, dtype=float)
    with np.errstate(divide="ignore"):
        return np.where(y < 2.0, 1.0 / np.square(1.0 - np.minimum(y, 2.0) / 2.0), np.inf)


@dataclass(frozen=True)
class FlagBars:
    """The flag bars of a fit table (:func:`flag_bars`).

    Attributes
    ----------
    bars : ndarray
        Per row, the reduced chi^2 above which the row is improbable (NaN: no bar).
    median : float
        The converged rows' median reduced chi^2 (the movie's level of a right minimum).
    excess : float
        Relative scatter of the reduced chi^2 beyond the chi^2 distribution's.
    typical : float
        The bar of a row with the median pixel count.
    n_rows : int
        Converged rows the scatter was measured on.
    """

    bars: NDArray[np.float64]
    median: float = math.nan
    excess: float = math.nan
    typical: float = math.nan
    n_rows: int = 0


def flag_bars(table: pd.DataFrame, probability: float, min_rows: int = 10) -> FlagBars:
    """Per-row bars on the reduced chi^2 that a frame in the right minimum exceeds with
    probability ``probability`` at most.

    A right-minimum frame has ``chi2_red = m (1 + r)``: ``m`` the converged rows' median and
    ``r`` a relative scatter of variance ``2 / nu + e^2`` (the chi^2 distribution's for its
    ``nu`` pixels plus the movie's excess ``e``). The scatter ``s`` is measured on the lower
    half of the converged rows on the scale of :func:`_to_symmetric`, ``e^2 = max(s^2 - 2 /
    nu_med, 0)``; measured on ``n`` rows it is as uncertain as a sample standard deviation
    with ``n / 3`` degrees of freedom, so the bar takes Student's t quantile::

        bar = m * max(from_symmetric(t(p; n/3) sqrt(e^2 + 2/nu) sqrt(1 + pi/(2n))),
                      chi2_isf(p, nu) / nu)

    Fewer converged rows than ``min_rows``: no bar (NaN).
    """
    n_all = len(table)
    chi_all = table["chi2_red"].to_numpy(dtype=float)
    nu_all = (table["n_pixels"].to_numpy(dtype=float) if "n_pixels" in table
              else np.full(n_all, np.nan))
    converged = table["status"].isin(CONVERGED).to_numpy() & np.isfinite(chi_all)
    chi = chi_all[converged]
    n = int(chi.size)
    if n < min_rows:
        return FlagBars(np.full(n_all, np.nan), n_rows=n)
    med = float(np.median(chi))
    rel = _to_symmetric(chi / med)
    below = -rel[rel < 0]
    spread = (math.sqrt(math.pi / 2.0) * float(below.mean()) / (1.0 - _LOWER_HALF_BIAS / n)
              if below.size else 0.0)
    nu_conv = nu_all[converged]
    nu_conv = nu_conv[np.isfinite(nu_conv) & (nu_conv > 0)]
    nu_med = float(np.median(nu_conv)) if nu_conv.size else math.inf
    excess2 = max(spread**2 - 2.0 / nu_med, 0.0)
    t = float(stats.t.isf(probability, max(n * _DOF_PER_ROW, 1.0)))
    widen = math.sqrt(1.0 + math.pi / (2.0 * n))

    def bar(nu: NDArray[np.float64]) -> NDArray[np.float64]:
        known = np.isfinite(nu) & (nu > 0)
        nu_safe = np.where(known, nu, 1.0)
        theory = np.where(known, 2.0 / nu_safe, 2.0 / nu_med)
        measured = _from_symmetric(t * np.sqrt(excess2 + theory) * widen)
        chi2_only = np.where(known, stats.chi2.isf(probability, nu_safe) / nu_safe, 1.0)
        return med * np.maximum(measured, chi2_only)

    typical = float(bar(np.array([nu_med]))[0])
    return FlagBars(bar(nu_all), med, math.sqrt(excess2), typical, n)


def flag_improbable(table: pd.DataFrame, probability: float) -> tuple[int, FlagBars]:
    """Mark ``ok`` rows above their :func:`flag_bars` bar ``poor_fit`` (in place): after the
    continuity sweeps no neighbour's orientation fits such a frame better, so it likely sits
    in a wrong local minimum. Returns the rows newly flagged and the bars."""
    flags = flag_bars(table, probability)
    if not math.isfinite(flags.typical):
        return 0, flags
    chi = table["chi2_red"].to_numpy(dtype=float)
    hit = (table["status"] == OK).to_numpy() & (chi > flags.bars)
    if "message" not in table:
        table["message"] = ""
    table["message"] = table["message"].astype(object)
    col_status, col_message = table.columns.get_loc("status"), table.columns.get_loc("message")
    for i in np.flatnonzero(hit):
        note = (f"reduced chi2 {chi[i]:.4g} above {flags.bars[i]:.4g}, which a frame in "
                f"the right minimum exceeds with probability {probability:g} "
                f"(chi^2 of its pixels and the movie's excess scatter "
                f"{flags.excess:.2g}, measured on {flags.n_rows} frames), and no "
                "neighbour's orientation fits better: likely a wrong local minimum")
        table.iat[i, col_status] = POOR_FIT
        table.iat[i, col_message] = join_message(str(table.iat[i, col_message]), note)
    return int(hit.sum()), flags
