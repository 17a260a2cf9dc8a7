"""``holofit analyze`` as a library function: trajectory in, diffusion coefficients out.

Steps (paper sections 4.2-4.3), the same for every particle model; what differs between models
is the model's recipe (:mod:`holofit.analysis.recipes`):

1. the fit table becomes a regular time series with gaps (missing or failed frames);
2. an optional constant drift (sedimentation) is removed: ``v = (r_last - r_first) / T``, the
   maximum-likelihood drift of Brownian motion, reported with its Brownian error. Removing it
   turns the path into a Brownian bridge, whose MSD is lower by exactly ``1 - tau / T``; the
   translational MSD models carry that factor (:func:`holofit.analysis.linefit.linear_msd_model`),
   so the subtraction leaves the coefficients unbiased at any length, drift or no drift;
3. orientation cleaning (:mod:`holofit.analysis.cleaning`): head-tail flips (rods), dropped
   excursions and rejected pairs (probability < 1e-4 under rotational diffusion with ``D_est``);
4. lag statistics of the recipe's observables (:mod:`holofit.analysis.msd`) and fits whose
   errors include the correlations between lags (:mod:`holofit.analysis.linefit`: generalised
   least squares with the MSDs' analytic covariance; for the projection correlation a weighted
   fit with a simulated covariance), over a fit range that grows with the measured
   localisation error (:func:`_adaptive_last_lag`);
5. the rejection is redone with ``D_est`` times 2/3 and 4/3 and the coefficients reported for
   each (sensitivity, not folded into the statistical error);
6. hydrodynamic predictions (:mod:`holofit.analysis.hydrodynamics`);
7. the physical-consistency check (:mod:`holofit.analysis.consistency`): the hydrodynamic size
   against the fitted one and the motion against Brownian motion; a track that fails is
   flagged, with the numbers, in its notes and summary;
8. the summary table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

import holofit.analysis.hydrodynamics as hd
from holofit.analysis.body_frame import BodyFrameCoefficients, fit_body_frame
from holofit.analysis.cleaning import (
    MIN_ESTIMATE_PAIRS,
    OrientationCleaning,
    RotationEstimate,
    clean_orientations,
)
from holofit.analysis.consistency import check_consistency
from holofit.analysis.errors import AnalysisError
from holofit.analysis.linefit import CurveModel, FitResult, fit_lag_statistics
from holofit.analysis.measurement import Measurement
from holofit.analysis.msd import (
    LagStatistics,
    Observables,
    PairFilter,
    default_lags,
    lag_statistics,
)
from holofit.analysis.recipes import MODELS, Probe, Recipe, recipe_for
from holofit.analysis.results import AnalysisResult
from holofit.analysis.settings import AnalysisConfig
from holofit.analysis.summary import summary_rows
from holofit.analysis.trajectory import Trajectory

__all__ = [
    "MODELS",
    "AnalysisConfig",
    "AnalysisResult",
    "Measurement",
    "analyze_trajectory",
]

#: lags of the preliminary fits that measure the reduced localisation error
PRELIM_LAGS = 10
#: default fit range 1..p with p = P_BASE + P_SLOPE sqrt(x), clipped to [MIN_FIT_LAGS, P_MAX]
#: (a probe may allow fewer, :class:`holofit.analysis.recipes.Probe`)
P_BASE = 2.0
P_SLOPE = 2.5
P_MAX = 20
MIN_FIT_LAGS = 3
#: a long rotational fit range uses every lag up to FIT_DENSE, then FIT_LOG log-spaced lags
FIT_DENSE = 20
FIT_LOG = 40
#: fewer frames with a fit than this cannot be analysed (the rotational-diffusion estimate of
#: the rejection needs MIN_ESTIMATE_PAIRS pairs at lags 1 and 2: 10 consecutive frames)
MIN_FRAMES = MIN_ESTIMATE_PAIRS + 2
#: fewer frames than this get a note: the errors are calibrated but large, and the estimates
#: skewed (docs: validation, "analysis pulls")
SHORT_FRAMES = 100
#: observables whose positions were drift-corrected (their models get the bridge factor)
POSITIONAL = ("par", "perp", "lab_x", "lab_y", "lab_z", "lab_3d", "xy")

SIZE_ALIASES = {
    "a_um": ("a_um", "radius_um", "core_radius_um", "cap_radius_um"),
    "b_um": ("b_um", "half_length_um"),
}

#: measured quantities whose sensitivity to the rejection's D_est is reported
SENSITIVE = ("D_par", "D_perp", "D_t", "D_t_lab", "D_par/D_perp", "D_r")


def _drift(traj: Trajectory) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """End-to-end drift velocity, its Brownian error (um/s) and the span ``T`` (s).

    The error of ``(r_last - r_first) / T`` per coordinate is ``sqrt(span * m1) / T``, with
    ``m1`` the mean squared one-frame step after the drift's removal and ``span`` the frames
    between the ends (the steps are independent for Brownian motion; the noise adds a little).
    """
    v = np.flatnonzero(traj.valid)
    if v.size < 2:
        return np.zeros(3), np.full(3, np.nan), 0.0
    frames = int(v[-1] - v[0])
    span = frames * traj.frame_interval_s
    vel = (traj.position_um[v[-1]] - traj.position_um[v[0]]) / span
    step = np.diff(traj.position_um, axis=0) - vel * traj.frame_interval_s
    ok = traj.valid[1:] & traj.valid[:-1]
    m1 = np.mean(step[ok] ** 2, axis=0) if ok.any() else np.full(3, np.nan)
    return vel, np.sqrt(frames * m1) / span, span


def _range(
    rng: tuple[int, int], n_frames: int, what: str, sparse: bool = False
) -> NDArray[np.int64]:
    """Lags of a fit range; ``sparse``: every lag up to 20, then about 40 log-spaced ones."""
    lo, hi = rng
    hi = min(hi, n_frames - 1)
    if hi - lo + 1 < 2:
        raise AnalysisError(
            f"{what} fit range {rng} leaves fewer than 2 lags in {n_frames} frames"
        )
    lags = np.arange(lo, hi + 1)
    if sparse and lags.size > FIT_DENSE + FIT_LOG:
        head = lags[lags < lo + FIT_DENSE]
        tail = np.unique(np.round(np.geomspace(lo + FIT_DENSE, hi, FIT_LOG)).astype(np.int64))
        lags = np.union1d(head, tail)
    return lags


def _merge(stats: dict[str, LagStatistics], more: dict[str, LagStatistics]) -> None:
    for name, extra in more.items():
        if name not in stats:
            stats[name] = extra
            continue
        base = stats[name]
        lags = np.concatenate([base.lags, extra.lags])
        order = np.argsort(lags, kind="stable")
        keep = np.concatenate([[True], np.diff(lags[order]) != 0])
        sel = order[keep]

        def cat(a, b, sel=sel):
            return np.concatenate([a, b])[sel]

        stats[name] = LagStatistics(
            name, lags[sel], cat(base.tau_s, extra.tau_s), cat(base.mean, extra.mean),
            cat(base.sem, extra.sem), cat(base.count, extra.count),
            cat(base.rejected, extra.rejected), cat(base.converged, extra.converged),
        )


def _adaptive_last_lag(noise_sq: float, step_sq: float, n_frames: int,
                       minimum: int = MIN_FIT_LAGS) -> int:
    """Last lag of the default fit range from the reduced localisation error.

    ``x = noise_sq / step_sq`` (``eps^2 / (D dt)`` for an MSD ``k (D tau + eps^2)``); the range
    is 1..p with ``p = 2 + 2.5 sqrt(x)`` (at least ``minimum``, at most 20 lags), the rule that
    minimised
    the scatter of this estimator in simulations for x = 0.01-10 (the optimal number of MSD
    points grows with the localisation error, as Michalet, Phys. Rev. E 82, 041914, 2010, found
    for unweighted fits).
    """
    if not step_sq > 0:
        return min(PRELIM_LAGS, n_frames - 1)
    x = max(noise_sq, 0.0) / step_sq
    p = math.floor(P_BASE + P_SLOPE * math.sqrt(x) + 0.5)
    return max(minimum, min(p, P_MAX, n_frames - 1))


def _usable_until(usable: NDArray[np.bool_], st: LagStatistics, n_frames: int) -> tuple[int, int]:
    """From lag 1 to the last lag before the first one that is not usable (automatic rotational
    fit range), at least MIN_FIT_LAGS and at most a quarter of the run."""
    outside = np.flatnonzero(~usable)
    if outside.size == 0:
        last = int(st.lags[-1])
    elif outside[0] == 0:
        last = MIN_FIT_LAGS
    else:
        last = int(st.lags[outside[0] - 1])
    return 1, min(max(last, MIN_FIT_LAGS), max(n_frames // 4, MIN_FIT_LAGS))


def _size(
    traj: Trajectory, name: str, given: float | None, given_err: float | None
) -> tuple[float, float, str] | None:
    if given is not None:
        return float(given), float(given_err or 0.0), "given"
    for col in SIZE_ALIASES[name]:
        if col in traj.static:
            s = traj.static[col]
            err = s["std"] / math.sqrt(s["count"]) if given_err is None else float(given_err)
            return s["median"], err, f"fit table '{col}' (median of {s['count']} frames)"
    return None


@dataclass
class _Core:
    cleaning: OrientationCleaning | None
    valid: NDArray[np.bool_]
    stats: dict[str, LagStatistics]
    fits: dict[str, FitResult]
    measured: dict[str, Measurement]


class _Pass:
    """One pass of the analysis for one choice of ``D_est``: cleaning, lag statistics, fit
    ranges and the recipe's fits.

    ``ranges`` (``"t"``, ``"r"``: inclusive fit ranges in frames) is shared between passes: the
    first pass chooses the ranges, the sensitivity passes reuse them.
    """

    def __init__(
        self, traj: Trajectory, settings: AnalysisConfig, recipe: Recipe, pos: NDArray,
        ranges: dict[str, tuple[int, int]], bridge_s: float | None = None,
    ) -> None:
        self.traj = traj
        self.bridge_s = bridge_s
        self.settings = settings
        self.recipe = recipe
        self.pos = pos
        self.ranges = ranges
        self.dt = traj.frame_interval_s
        self.n = traj.n_frames
        # what the pass finds, step by step (set by run)
        self.cleaning: OrientationCleaning | None = None
        self.valid: NDArray[np.bool_] = traj.valid
        self.axis: NDArray[np.float64] | None = traj.axis
        self.pair_filter: PairFilter | None = None
        self.obs: Observables | None = None
        self.stats: dict[str, LagStatistics] = {}
        self.fits: dict[str, FitResult] = {}

    def run(
        self, d_est: float | None, eps_r: float | None, estimate: RotationEstimate | None,
        lags: NDArray | None,
    ) -> _Core:
        """Clean with ``d_est``/``eps_r``/``estimate``, compute the lag statistics (at
        ``lags``, default: the plots' and fits' lags), choose or reuse the fit ranges, fit."""
        self._clean(d_est, eps_r, estimate)
        self.obs = Observables(self.pos, self.axis, self.valid)
        self.stats = lag_statistics(self.obs, list(self.recipe.observables),
                                    self._lags(lags), self.dt, self.pair_filter)
        t_lags = _range(self._translation_range(), self.n, "translation")
        self._ensure(t_lags)
        r_lags = self._rotation_lags()
        measured = self.recipe.measure(self, t_lags, r_lags, self.settings)
        return _Core(self.cleaning, self.valid, self.stats, self.fits, measured)

    def _clean(
        self, d_est: float | None, eps_r: float | None, estimate: RotationEstimate | None
    ) -> None:
        s = self.settings
        self.valid = self.traj.valid.copy()
        if not self.recipe.orientation:
            return
        if self.axis is None:
            raise AnalysisError(
                f"model '{s.model}' needs the orientation (ux, uy, uz or theta_rad, psi_rad)"
            )
        self.cleaning = clean_orientations(
            self.axis, self.valid, self.dt, head_tail=bool(s.head_tail), reject=bool(s.reject),
            probability=s.reject_probability, d_est=d_est, eps_r=eps_r, estimate=estimate,
        )
        self.valid, self.axis = self.cleaning.valid, self.cleaning.axis
        self.pair_filter = self.cleaning.pair_mask

    def _lags(self, lags: NDArray | None) -> NDArray:
        """Lags computed: the plots' lags, the probes' and any given fit range."""
        if lags is not None:
            return lags
        s, n = self.settings, self.n
        lags = np.union1d(default_lags(n, s.max_lag), np.arange(1, min(PRELIM_LAGS, n - 1) + 1))
        if s.fit_lags_translation is not None:  # fitted at every lag of its range
            lags = np.union1d(lags, _range(s.fit_lags_translation, n, "translation"))
        if s.fit_lags_rotation is not None:
            lags = np.union1d(lags, _range(s.fit_lags_rotation, n, "rotation", sparse=True))
        return lags

    def _model(self, name: str, model: CurveModel) -> CurveModel:
        """``model``, with the bridge factor where the drift was removed from ``name``."""
        if self.bridge_s and name in POSITIONAL and model.bridged is not None:
            return model.bridged(self.bridge_s)
        return model

    @property
    def observables(self) -> Observables:
        """The pass's pairs (set by :meth:`run` before anything is fitted)."""
        if self.obs is None:
            raise AnalysisError("internal: the lag statistics are not computed yet")
        return self.obs

    def fit(self, key: str, observable: str, model: CurveModel, lags: NDArray) -> FitResult:
        """Fit ``observable`` at ``lags`` and keep the result as ``key``."""
        f = fit_lag_statistics(self.stats[observable].at(lags), self._model(observable, model),
                               self.observables, self.pair_filter)
        self.fits[key] = f
        return f

    __call__ = fit

    def body_frame(self, lags: NDArray) -> tuple[FitResult, FitResult]:
        """Fit ``par`` and ``perp`` at ``lags`` together, with the exact means of the measured
        axis path and the drift removal (:mod:`holofit.analysis.body_frame`)."""
        span = None
        if self.bridge_s:
            v = np.flatnonzero(self.traj.valid)
            span = (int(v[0]), int(v[-1]))
        if self.axis is None:
            raise AnalysisError("the body-frame fit needs the rod's axis")
        coeffs = BodyFrameCoefficients(self.axis, self.valid, self.dt, self.pair_filter, span)
        fp, fq = fit_body_frame(self.stats["par"].at(lags), self.stats["perp"].at(lags), coeffs,
                                self.observables, self.pair_filter)
        self.fits["par"], self.fits["perp"] = fp, fq
        return fp, fq

    def _probe_last_lag(self, probe: Probe, last: int, what: str) -> int:
        """The adaptive last lag from a preliminary fit of lags 1..``last``."""
        pre = fit_lag_statistics(
            self.stats[probe.observable].at(_range((1, last), self.n, what)),
            self._model(probe.observable, probe.model()), self.observables, self.pair_filter,
        )
        eps2 = pre.value("eps2") - probe.resolved_sigma * pre.error("eps2")
        minimum = probe.min_last_lag if probe.min_last_lag is not None else MIN_FIT_LAGS
        return _adaptive_last_lag(probe.noise_factor * eps2, pre.value("D") * self.dt, self.n,
                                  minimum)

    def _translation_range(self) -> tuple[int, int]:
        if "t" not in self.ranges:
            given = self.settings.fit_lags_translation
            self.ranges["t"] = given if given is not None else (
                1, self._probe_last_lag(self.recipe.translation_probe, PRELIM_LAGS,
                                        "translation"))
        return self.ranges["t"]

    def _rotation_lags(self) -> NDArray[np.int64] | None:
        rot = self.recipe.rotation
        if rot is None:
            return None
        if "r" not in self.ranges:
            given = self.settings.fit_lags_rotation
            if given is not None:
                self.ranges["r"] = given
            else:
                st = self.stats[rot.observable]
                limit = _usable_until(rot.usable(st.mean), st, self.n)
                self.ranges["r"] = limit
                if rot.probe is not None:
                    last = self._probe_last_lag(rot.probe, min(PRELIM_LAGS, limit[1]),
                                                "rotation")
                    self.ranges["r"] = (1, min(last, limit[1]))
        r_lags = _range(self.ranges["r"], self.n, "rotation", sparse=True)
        self._ensure(r_lags)
        return r_lags

    def _ensure(self, lags: NDArray[np.int64]) -> None:
        """Compute the lag statistics at ``lags`` where they are missing (a fit range the
        probe chose longer than the lags computed for the plots)."""
        missing = np.setdiff1d(lags, next(iter(self.stats.values())).lags)
        if missing.size:
            _merge(self.stats, lag_statistics(self.observables, list(self.recipe.observables),
                                              missing, self.dt, self.pair_filter))


def _sensitivity(
    core: _Core, traj: Trajectory, s: AnalysisConfig, recipe: Recipe, pos: NDArray,
    ranges: dict[str, tuple[int, int]], bridge_s: float | None,
) -> None:
    """Redo the measurement with the rejection's ``D_est`` scaled by each sensitivity factor
    (same fit ranges) and record the values in the measurements' ``sensitivity``."""
    est = core.cleaning.estimate if core.cleaning is not None else None
    if est is None:
        return
    fit_lags = np.union1d(_range(ranges["t"], traj.n_frames, "translation"),
                          _range(ranges["r"], traj.n_frames, "rotation", sparse=True))
    for factor in s.sensitivity_factors:
        alt = _Pass(traj, s, recipe, pos, dict(ranges), bridge_s).run(
            est.d_est * factor, est.eps_r, est, fit_lags)
        for key in SENSITIVE:
            if key in core.measured and key in alt.measured:
                core.measured[key].sensitivity[f"D_est x {factor:.3g}"] = (
                    alt.measured[key].value
                )


def _fit_notes(fits: dict[str, FitResult]) -> list[str]:
    notes = []
    for key, f in fits.items():
        if not f.success:
            notes.append(f"fit '{key}': the least-squares fit did not converge")
        if not f.error_converged:
            notes.append(
                f"fit '{key}': the block-error plateau was not reached for every parameter "
                "(trajectory short compared with the correlation of its lags); its errors may "
                "be underestimated"
            )
    return notes


def _effective_radii(result: AnalysisResult) -> None:
    s = result.settings
    t, dt_c = s.temperature_c, s.temperature_err_c
    for key, fn, name in (
        ("D_t", hd.radius_from_translational, "a_eff_t"),
        ("D_r", hd.radius_from_rotational, "a_eff_r"),
    ):
        m = result.measured.get(key)
        if m is None:
            continue
        if not m.value > 1e-6 * m.sides()[1]:  # zero, or at the fit's bound
            result.notes.append(f"{key} = {m.value:.3g} is not positive (the run is too short "
                                "to resolve it): no effective radius from it")
            continue
        val = fn(m.value, t)
        below, above = m.sides()
        up, dn = fn(m.value + above, t), fn(max(m.value - below, 1e-12), t)
        err_d = abs(dn - up) / 2 if math.isfinite(up) and math.isfinite(dn) else float("nan")
        err_t = abs(fn(m.value, t + dt_c) - fn(m.value, t - dt_c)) / 2 if dt_c > 0 else 0.0
        result.measured[name] = Measurement(1e3 * val, 1e3 * math.hypot(err_d, err_t), "nm")


def _analyze(traj: Trajectory, s: AnalysisConfig) -> AnalysisResult:
    recipe = recipe_for(s.model)
    if traj.valid.sum() < MIN_FRAMES:
        raise AnalysisError(f"only {int(traj.valid.sum())} frames with a fit "
                            f"(the analysis needs at least {MIN_FRAMES})")
    drift, drift_err, span = _drift(traj)
    if not s.subtract_drift:
        drift = np.zeros(3)
    bridge_s = span if s.subtract_drift and span > 0 else None
    pos = traj.position_um - np.outer(traj.time_s, drift)
    ranges: dict[str, tuple[int, int]] = {}
    core = _Pass(traj, s, recipe, pos, ranges, bridge_s).run(s.d_est, s.eps_r_est, None, None)
    if core.cleaning is not None and core.cleaning.estimate is not None and s.reject:
        _sensitivity(core, traj, s, recipe, pos, ranges, bridge_s)
    notes = _fit_notes(core.fits)
    if traj.valid.sum() < SHORT_FRAMES:
        notes.append(
            f"only {int(traj.valid.sum())} frames: the errors are large and, below about "
            f"{SHORT_FRAMES} frames, skewed (a low estimate gets a smaller error than a high "
            "one); see the README's calibration table")
    if traj.n_ambiguous:
        notes.append(f"{traj.n_ambiguous} frame(s) the fit flagged ambiguous (the mirrored "
                     "orientation fits as well) left out")
    sizes = {}
    for name in recipe.sizes:
        given, given_err = getattr(s, name), getattr(s, name.replace("_um", "_err_um"))
        size = _size(traj, name, given, given_err)
        if size is not None:
            sizes[name] = size
    predictions = recipe.predict(sizes, s.temperature_c, s.temperature_err_c, notes)
    result = AnalysisResult(
        s, traj, core.valid, drift, core.cleaning, core.stats, core.fits, core.measured,
        predictions, sizes, [], notes, drift_err,
    )
    _effective_radii(result)
    if s.check_consistency and recipe.consistency is not None:
        result.consistency = check_consistency(
            result, recipe.consistency, pos,
            core.cleaning.axis if core.cleaning is not None else None,
            traj.frame_interval_s, bridge_s, s.consistency_alpha, s.theory_tolerance)
        if result.consistency.flagged:
            notes.append(f"flagged: {result.consistency.message}")
    result.rows = summary_rows(result)
    return result


def analyze_trajectory(traj: Trajectory, settings: AnalysisConfig) -> AnalysisResult:
    """Diffusion analysis of one trajectory (see the module docstring).

    Raises
    ------
    AnalysisError
        If the trajectory cannot be analysed as asked; the message names its source.
    """
    try:
        return _analyze(traj, settings)
    except AnalysisError as exc:
        raise AnalysisError(f"{traj.source}: {exc}") from None
