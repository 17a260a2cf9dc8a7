"""``holofit analyze`` as a library function: trajectory in, diffusion coefficients out.

Steps (DESIGN.md §5, paper sections 4.2-4.3):

1. the fit table becomes a regular time series with gaps (missing or failed frames);
2. an optional constant drift (sedimentation) is removed: ``v = (r_last - r_first) / T``, the
   maximum-likelihood drift of Brownian motion (it lowers the MSD by a factor ``1 - tau / T``,
   below 0.5 % in the default fit range of a 2000-frame run);
3. orientation cleaning (:mod:`holofit.analysis.cleaning`): head-tail flips (rods), dropped
   excursions and rejected pairs (probability < 1e-4 under rotational diffusion with ``D_est``);
4. lag statistics with block-decorrelated errors (:mod:`holofit.analysis.msd`) and weighted fits
   with influence-series errors (:mod:`holofit.analysis.fitting`), over a fit range that grows
   with the measured localisation error (:func:`_adaptive_last_lag`);
5. the rejection is redone with ``D_est`` times 2/3 and 4/3 and the coefficients reported for
   each (sensitivity, not folded into the statistical error);
6. hydrodynamic predictions (:mod:`holofit.analysis.hydrodynamics`) and the summary table.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from holofit.analysis import hydrodynamics as hd
from holofit.analysis.cleaning import OrientationCleaning, RotationEstimate, clean_orientations
from holofit.analysis.fitting import (
    FitResult,
    combine,
    fit_lag_statistics,
    linear_msd_model,
    orientation_msd_model,
    projection_model,
    single_exponential_model,
)
from holofit.analysis.msd import LagStatistics, Observables, default_lags, lag_statistics
from holofit.analysis.trajectory import Trajectory

__all__ = [
    "MODELS",
    "AnalysisResult",
    "AnalysisSettings",
    "Measurement",
    "analyze_trajectory",
]

MODELS = ("rod", "janus", "sphere")
#: lags of the preliminary fits that measure the reduced localisation error
PRELIM_LAGS = 10
#: default fit range 1..p with p = P_BASE + P_SLOPE sqrt(x), clipped to [MIN_FIT_LAGS, P_MAX]
P_BASE = 2.0
P_SLOPE = 2.5
P_MAX = 20
#: the automatic rotational fit range ends where <|du|^2> reaches this (rods) ...
ORIENT_MSD_LIMIT = 0.5
#: ... or where <p . p'> falls to this (Janus)
PROJECTION_LIMIT = 0.5
MIN_FIT_LAGS = 3
#: a long rotational fit range uses every lag up to FIT_DENSE, then FIT_LOG log-spaced lags
FIT_DENSE = 20
FIT_LOG = 40

SIZE_ALIASES = {
    "a_um": ("a_um", "radius_um", "core_radius_um", "cap_radius_um"),
    "b_um": ("b_um", "half_length_um"),
}


@dataclass
class AnalysisSettings:
    """How to analyse a trajectory.

    Parameters
    ----------
    model : {"rod", "janus", "sphere"}
        ``rod`` for any head-tail symmetric particle (rods, dimers); ``janus`` for particles with
        a distinguishable cap (only x, y and the azimuth psi are used, as in the paper); ``sphere``
        for translation only.
    temperature_c, temperature_err_c : float
        Sample temperature and its uncertainty, C.
    a_um, b_um : float, optional
        Sizes for the predictions (cap/sphere radius, half length), um; default: medians of the
        table's static parameters.
    a_err_um, b_err_um : float, optional
        Their uncertainties; default: the standard error of the table's per-frame values (zero
        when the fit held the sizes fixed).
    head_tail : bool, optional
        Correct head-tail flips (default: True for rods).
    reject : bool, optional
        Reject improbable angular jumps (default: True for rods, False for Janus particles, whose
        analysis uses psi only, which a mirrored polar angle does not change).
    reject_probability : float
        Tail-probability threshold of the rejection.
    d_est : float, optional
        Rotational diffusion coefficient for the rejection, 1/s (default: estimated).
    eps_r_est : float, optional
        Angular noise per frame for the rejection, rad (default: estimated; 0 reproduces the
        paper's rule exactly).
    sensitivity_factors : tuple of float
        Factors applied to ``D_est`` for the sensitivity report.
    subtract_drift : bool
        Remove a constant drift velocity.
    fit_lags_translation, fit_lags_rotation : tuple of int, optional
        Inclusive fit ranges in frames. Defaults: lags 1..p with ``p = 2 + 2.5 sqrt(x)``
        (3 <= p <= 20) for translation and for the rod's orientation MSD, ``x`` being the
        reduced localisation error ``eps^2 / (D dt)`` from a preliminary fit of lags 1-10 (the
        orientation MSD also stops before ``<|du|^2>`` reaches 0.5); for the Janus projection
        correlation, up to the lag where ``<p . p'>`` falls to 0.5.
    max_lag : int, optional
        Longest lag computed for the plots (default: a quarter of the trajectory).
    projection_amplitude : bool
        Fit an amplitude ``A`` in front of the projection series (absorbs angular noise).
    """

    model: str
    temperature_c: float = 21.0
    temperature_err_c: float = 2.0
    a_um: float | None = None
    b_um: float | None = None
    a_err_um: float | None = None
    b_err_um: float | None = None
    head_tail: bool | None = None
    reject: bool | None = None
    reject_probability: float = 1e-4
    d_est: float | None = None
    eps_r_est: float | None = None
    sensitivity_factors: tuple[float, ...] = (2 / 3, 4 / 3)
    subtract_drift: bool = True
    fit_lags_translation: tuple[int, int] | None = None
    fit_lags_rotation: tuple[int, int] | None = None
    max_lag: int | None = None
    projection_amplitude: bool = True

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"model must be one of {', '.join(MODELS)}, got {self.model!r}")
        if self.head_tail is None:
            self.head_tail = self.model == "rod"
        if self.reject is None:
            self.reject = self.model == "rod"
        if self.model == "sphere":
            self.head_tail, self.reject = False, False
        if not 0 < self.reject_probability < 1:
            raise ValueError(
                f"reject_probability must lie in (0, 1), got {self.reject_probability}"
            )
        if self.d_est is not None and not self.d_est > 0:
            raise ValueError(f"d_est must be > 0 (1/s), got {self.d_est}")
        for name in ("fit_lags_translation", "fit_lags_rotation"):
            rng = getattr(self, name)
            if rng is not None:
                lo, hi = int(rng[0]), int(rng[1])
                if lo < 1 or hi < lo:
                    raise ValueError(f"{name} must be 1 <= first <= last frames, got {rng}")
                setattr(self, name, (lo, hi))


@dataclass
class Measurement:
    """A measured quantity with its statistical error and its ``D_est`` sensitivity."""

    value: float
    error: float
    unit: str
    sensitivity: dict[str, float] = field(default_factory=dict)


@dataclass
class AnalysisResult:
    """Everything :func:`analyze_trajectory` found."""

    settings: AnalysisSettings
    trajectory: Trajectory
    valid: NDArray[np.bool_]
    drift_um_s: NDArray[np.float64]
    cleaning: OrientationCleaning | None
    stats: dict[str, LagStatistics]
    fits: dict[str, FitResult]
    measured: dict[str, Measurement]
    predictions: dict[str, tuple[hd.Prediction, str, str]]
    sizes: dict[str, tuple[float, float, str]]
    rows: list[dict[str, Any]]
    notes: list[str] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        """A JSON-ready description of the analysis."""
        traj = self.trajectory
        cl = self.cleaning
        doc: dict[str, Any] = {
            "settings": asdict(self.settings),
            "input": traj.source,
            "frame_interval_s": traj.frame_interval_s,
            "frames": {
                "first": traj.first_frame,
                "slots": traj.n_frames,
                "with_fit": int(traj.valid.sum()),
                "gaps": int((~traj.valid).sum()),
                "used": int(self.valid.sum()),
            },
            "drift_um_s": self.drift_um_s.tolist(),
            "measured": {k: asdict(v) for k, v in self.measured.items()},
            "predictions": {
                k: {**asdict(p), "unit": unit, "source": src}
                for k, (p, unit, src) in self.predictions.items()
            },
            "sizes_um": {k: {"value": v, "error": e, "source": s}
                         for k, (v, e, s) in self.sizes.items()},
            "fits": {k: _fit_summary(f) for k, f in self.fits.items()},
            "table": self.rows,
            "notes": self.notes,
        }
        if cl is not None:
            doc["cleaning"] = {
                "head_tail_flips": int(cl.flipped.sum()),
                "flipped_frames": (traj.frames[cl.flipped]).tolist(),
                "rejected_frames": (traj.frames[cl.outliers]).tolist(),
                "d_est_s": cl.estimate.d_est if cl.estimate else None,
                "d_est_source": cl.estimate.source if cl.estimate else None,
                "eps_r_est_rad": cl.estimate.eps_r if cl.estimate else None,
                "probability": self.settings.reject_probability,
                "threshold_rad_by_lag": (
                    {int(k): cl.thresholds(int(k)) for k in (1, 2, 5, 10, 20, 50, 100)
                     if k < traj.n_frames}
                    if cl.thresholds is not None else {}
                ),
                "rejected_pairs_by_lag": {
                    int(k): int(r) for k, r in zip(
                        next(iter(self.stats.values())).lags,
                        next(iter(self.stats.values())).rejected, strict=True)
                    if k in (1, 2, 5, 10, 20, 50, 100)
                },
            }
        return doc


def _fit_summary(f: FitResult) -> dict[str, Any]:
    return {
        "observable": f.observable,
        "model": f.model.formula,
        "parameters": dict(zip(f.model.params, f.values.tolist(), strict=True)),
        "errors": dict(zip(f.model.params, f.errors.tolist(), strict=True)),
        "errors_if_lags_independent": dict(
            zip(f.model.params, f.naive_errors.tolist(), strict=True)
        ),
        "lags_frames": [int(f.lags[0]), int(f.lags[-1])],
        "tau_s": [float(f.tau_s[0]), float(f.tau_s[-1])],
        "chi2_reduced": f.chi2_reduced,
        "error_plateau_found": f.error_converged,
        "converged": f.success,
    }


def _drift(traj: Trajectory) -> NDArray[np.float64]:
    v = np.flatnonzero(traj.valid)
    if v.size < 2:
        return np.zeros(3)
    span = (v[-1] - v[0]) * traj.frame_interval_s
    return (traj.position_um[v[-1]] - traj.position_um[v[0]]) / span


def _range(
    rng: tuple[int, int], n_frames: int, what: str, sparse: bool = False
) -> NDArray[np.int64]:
    """Lags of a fit range; ``sparse``: every lag up to 20, then about 40 log-spaced ones."""
    lo, hi = rng
    hi = min(hi, n_frames - 1)
    if hi - lo + 1 < 2:
        raise ValueError(f"{what} fit range {rng} leaves fewer than 2 lags in {n_frames} frames")
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


def _adaptive_last_lag(noise_sq: float, step_sq: float, n_frames: int) -> int:
    """Last lag of the default fit range from the reduced localisation error.

    ``x = noise_sq / step_sq`` (``eps^2 / (D dt)`` for an MSD ``k (D tau + eps^2)``); the range
    is 1..p with ``p = 2 + 2.5 sqrt(x)`` (at least 3, at most 20 lags), the rule that minimised
    the scatter of this estimator in simulations for x = 0.01-10 (the optimal number of MSD
    points grows with the localisation error, as Michalet, Phys. Rev. E 82, 041914, 2010, found
    for unweighted fits).
    """
    if not step_sq > 0:
        return min(PRELIM_LAGS, n_frames - 1)
    x = max(noise_sq, 0.0) / step_sq
    p = math.floor(P_BASE + P_SLOPE * math.sqrt(x) + 0.5)
    return max(MIN_FIT_LAGS, min(p, P_MAX, n_frames - 1))


def _auto_rotation_range(st: LagStatistics, n_frames: int, rod: bool) -> tuple[int, int]:
    """From lag 1 to the last lag before <|du|^2> exceeds 0.5 (rods) or <p.p'> drops below 0.5."""
    inside = st.mean <= ORIENT_MSD_LIMIT if rod else st.mean >= PROJECTION_LIMIT
    outside = np.flatnonzero(~inside)  # NaN (no pairs) counts as outside
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


def _measure(
    traj: Trajectory,
    s: AnalysisSettings,
    pos: NDArray,
    d_est: float | None,
    eps_r: float | None,
    estimate: RotationEstimate | None,
    lags: NDArray | None,
    ranges: dict[str, tuple[int, int]],
) -> _Core:
    """Cleaning, lag statistics and fits for one choice of ``D_est``."""
    dt = traj.frame_interval_s
    n = traj.n_frames
    cleaning = None
    valid = traj.valid.copy()
    axis = traj.axis
    pair_filter = None
    if s.model != "sphere":
        if axis is None:
            raise ValueError(
                f"{traj.source}: model '{s.model}' needs the orientation (ux, uy, uz or "
                "theta_rad, psi_rad)"
            )
        cleaning = clean_orientations(
            axis, valid, dt, head_tail=bool(s.head_tail), reject=bool(s.reject),
            probability=s.reject_probability, d_est=d_est, eps_r=eps_r, estimate=estimate,
        )
        valid, axis = cleaning.valid, cleaning.axis
        pair_filter = cleaning.pair_mask
    obs = Observables(pos, axis, valid)
    if s.model == "rod":
        names = ["par", "perp", "orient", "lab_x", "lab_y", "lab_z", "lab_3d"]
        rot_name = "orient"
    elif s.model == "janus":
        names, rot_name = ["xy", "proj"], "proj"
    else:
        names, rot_name = ["xy"], None

    if lags is None:
        lags = np.union1d(default_lags(n, s.max_lag), np.arange(1, min(PRELIM_LAGS, n - 1) + 1))
        for given in (s.fit_lags_translation, s.fit_lags_rotation):
            if given is not None:
                lags = np.union1d(lags, _range(given, n, "fit", sparse=True))
    stats = lag_statistics(obs, names, lags, dt, pair_filter)

    fits: dict[str, FitResult] = {}

    def fit(key: str, name: str, model, lag_set) -> FitResult:
        f = fit_lag_statistics(stats[name].at(lag_set), model, obs, pair_filter)
        fits[key] = f
        return f

    if "t" not in ranges:
        if s.fit_lags_translation is not None:
            ranges["t"] = s.fit_lags_translation
        else:
            # preliminary fit for the reduced localisation error x = eps^2 / (D dt)
            name, k = ("lab_3d", 6) if s.model == "rod" else ("xy", 4)
            pre = fit_lag_statistics(
                stats[name].at(_range((1, PRELIM_LAGS), n, "translation")),
                linear_msd_model(k, name), obs, pair_filter,
            )
            ranges["t"] = (1, _adaptive_last_lag(pre.value("eps2"), pre.value("D") * dt, n))
    t_lags = _range(ranges["t"], n, "translation")
    r_lags = None
    if rot_name is not None:
        if "r" not in ranges:
            if s.fit_lags_rotation is not None:
                ranges["r"] = s.fit_lags_rotation
            else:
                limit = _auto_rotation_range(stats[rot_name], n, s.model == "rod")
                ranges["r"] = limit
                if s.model == "rod":
                    pre = fit_lag_statistics(
                        stats["orient"].at(_range((1, min(PRELIM_LAGS, limit[1])), n,
                                                  "rotation")),
                        orientation_msd_model(), obs, pair_filter,
                    )
                    # 4 (D_r tau + eps_r^2 / 2) at short lags: x = (eps_r^2 / 2) / (D_r dt)
                    last = _adaptive_last_lag(0.5 * pre.value("eps2"), pre.value("D") * dt, n)
                    ranges["r"] = (1, min(last, limit[1]))
        r_lags = _range(ranges["r"], n, "rotation", sparse=True)
        missing = np.setdiff1d(r_lags, stats[rot_name].lags)
        if missing.size:
            _merge(stats, lag_statistics(obs, names, missing, dt, pair_filter))

    meas: dict[str, Measurement] = {}

    def eps_nm(f: FitResult) -> Measurement:
        e2, de2 = f.value("eps2"), f.error("eps2")
        if e2 <= 0:
            return Measurement(0.0, 1e3 * math.sqrt(max(de2, 0.0)), "nm")
        e = math.sqrt(e2)
        return Measurement(1e3 * e, 1e3 * de2 / (2 * e), "nm")

    if s.model == "rod":
        fp = fit("par", "par", linear_msd_model(2, "par"), t_lags)
        fq = fit("perp", "perp", linear_msd_model(4, "perp"), t_lags)
        fl = fit("lab_3d", "lab_3d", linear_msd_model(6, "lab_3d"), t_lags)
        fr = fit("orient", "orient", orientation_msd_model(), r_lags)
        dpar, dperp = fp.value("D"), fq.value("D")
        meas["D_par"] = Measurement(dpar, fp.error("D"), "um^2/s")
        meas["D_perp"] = Measurement(dperp, fq.error("D"), "um^2/s")
        dt_val, dt_err = combine(
            [(1 / 3, fp.influence_of("D")), (2 / 3, fq.influence_of("D"))], (dpar + 2 * dperp) / 3
        )
        meas["D_t"] = Measurement(dt_val, dt_err, "um^2/s")
        meas["D_t_lab"] = Measurement(fl.value("D"), fl.error("D"), "um^2/s")
        ratio, ratio_err = combine(
            [(1 / dperp, fp.influence_of("D")), (-dpar / dperp**2, fq.influence_of("D"))],
            dpar / dperp,
        )
        meas["D_par/D_perp"] = Measurement(ratio, ratio_err, "1")
        meas["D_r"] = Measurement(fr.value("D"), fr.error("D"), "1/s")
        meas["eps_par"] = eps_nm(fp)
        meas["eps_perp"] = eps_nm(fq)
        er = eps_nm(fr)
        meas["eps_r"] = Measurement(math.degrees(er.value / 1e3), math.degrees(er.error / 1e3),
                                    "deg")
    else:
        fx = fit("xy", "xy", linear_msd_model(4, "xy"), t_lags)
        meas["D_t"] = Measurement(fx.value("D"), fx.error("D"), "um^2/s")
        meas["eps"] = eps_nm(fx)
        if s.model == "janus":
            fj = fit("proj", "proj", projection_model(s.projection_amplitude), r_lags)
            meas["D_r"] = Measurement(fj.value("D"), fj.error("D"), "1/s")
            if s.projection_amplitude:
                meas["A"] = Measurement(fj.value("A"), fj.error("A"), "1")
            try:
                fit("proj_single_exp", "proj", single_exponential_model(s.projection_amplitude),
                    r_lags)
            except ValueError:
                pass
    return _Core(cleaning, valid, stats, fits, meas)


SENSITIVE = ("D_par", "D_perp", "D_t", "D_t_lab", "D_par/D_perp", "D_r")


def analyze_trajectory(traj: Trajectory, settings: AnalysisSettings) -> AnalysisResult:
    """Diffusion analysis of one trajectory (see the module docstring)."""
    s = settings
    if traj.valid.sum() < 10:
        raise ValueError(f"{traj.source}: only {int(traj.valid.sum())} frames with a fit")
    drift = _drift(traj) if s.subtract_drift else np.zeros(3)
    pos = traj.position_um - np.outer(traj.time_s, drift)
    ranges: dict[str, tuple[int, int]] = {}
    core = _measure(traj, s, pos, s.d_est, s.eps_r_est, None, None, ranges)
    notes: list[str] = []

    if core.cleaning is not None and core.cleaning.estimate is not None and s.reject:
        est = core.cleaning.estimate
        fit_lags = np.union1d(_range(ranges["t"], traj.n_frames, "translation"),
                              _range(ranges["r"], traj.n_frames, "rotation", sparse=True))
        for factor in s.sensitivity_factors:
            alt = _measure(traj, s, pos, est.d_est * factor, est.eps_r, est, fit_lags,
                           dict(ranges))
            for key in SENSITIVE:
                if key in core.measured and key in alt.measured:
                    core.measured[key].sensitivity[f"D_est x {factor:.3g}"] = (
                        alt.measured[key].value
                    )

    for key, f in core.fits.items():
        if not f.success:
            notes.append(f"fit '{key}': the least-squares fit did not converge")
        if not f.error_converged:
            notes.append(
                f"fit '{key}': the block-error plateau was not reached for every parameter "
                "(trajectory short compared with the correlation of its lags); its errors may "
                "be underestimated"
            )

    sizes: dict[str, tuple[float, float, str]] = {}
    a = _size(traj, "a_um", s.a_um, s.a_err_um)
    if a is not None:
        sizes["a_um"] = a
    if s.model == "rod":
        b = _size(traj, "b_um", s.b_um, s.b_err_um)
        if b is not None:
            sizes["b_um"] = b
    predictions = _predictions(s, sizes, notes)
    result = AnalysisResult(
        s, traj, core.valid, drift, core.cleaning, core.stats, core.fits, core.measured,
        predictions, sizes, [], notes,
    )
    _effective_radii(result)
    from holofit.analysis.summary import summary_rows

    result.rows = summary_rows(result)
    return result


def _predictions(
    s: AnalysisSettings, sizes: dict[str, tuple[float, float, str]], notes: list[str]
) -> dict[str, tuple[hd.Prediction, str, str]]:
    out: dict[str, tuple[hd.Prediction, str, str]] = {}
    t, dt_c = s.temperature_c, s.temperature_err_c
    if s.model == "rod":
        if "a_um" not in sizes or "b_um" not in sizes:
            notes.append("no rod sizes (a_um, b_um) in the table or options: no predictions")
            return out
        (a, da, _), (b, db, _) = sizes["a_um"], sizes["b_um"]
        if not b > a:
            notes.append(f"b = {b:g} um is not longer than a = {a:g} um: aspect ratio < 1")
        args = {"a_um": a, "b_um": b}
        errs = {"a_um": da, "b_um": db}
        sc = "spherocylinder (Martchenko 2011 / Yoshizaki & Yamakawa 1980)"
        cy = "cylinder (Tirado et al. 1984)"
        for key, unit, fn, src in (
            ("D_t", "um^2/s", lambda **k: hd.spherocylinder_diffusion(**k)["D_t"], sc),
            ("D_r", "1/s", lambda **k: hd.spherocylinder_diffusion(**k)["D_r"], sc),
            ("cyl D_par", "um^2/s", lambda **k: hd.cylinder_diffusion(**k)["D_par"], cy),
            ("cyl D_perp", "um^2/s", lambda **k: hd.cylinder_diffusion(**k)["D_perp"], cy),
            ("cyl D_t", "um^2/s", lambda **k: hd.cylinder_diffusion(**k)["D_t"], cy),
            ("cyl D_r", "1/s", lambda **k: hd.cylinder_diffusion(**k)["D_r"], cy),
            ("cyl D_par/D_perp", "1", lambda **k: hd.cylinder_diffusion(**k)["D_par/D_perp"],
             cy),
        ):
            out[key] = (hd.predict(fn, t, dt_c, args, errs), unit, src)
    else:
        if "a_um" not in sizes:
            notes.append("no radius (a_um or radius_um) in the table or options: no predictions")
            return out
        a, da, _ = sizes["a_um"]
        src_t = "Stokes-Einstein sphere"
        out["D_t"] = (
            hd.predict(lambda **k: hd.sphere_diffusion(**k)["D_t"], t, dt_c, {"a_um": a},
                       {"a_um": da}), "um^2/s", src_t)
        if s.model == "janus":
            out["D_r"] = (
                hd.predict(lambda **k: hd.sphere_diffusion(**k)["D_r"], t, dt_c, {"a_um": a},
                           {"a_um": da}), "1/s", "Stokes-Einstein-Debye sphere")
    return out


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
        val = fn(m.value, t)
        up, dn = fn(m.value + m.error, t), fn(max(m.value - m.error, 1e-12), t)
        err_d = abs(dn - up) / 2 if math.isfinite(up) and math.isfinite(dn) else float("nan")
        err_t = abs(fn(m.value, t + dt_c) - fn(m.value, t - dt_c)) / 2 if dt_c > 0 else 0.0
        result.measured[name] = Measurement(1e3 * val, 1e3 * math.hypot(err_d, err_t), "nm")
