"""One recipe per particle model: what the diffusion analysis measures for it, and how.

The analysis (:mod:`holofit.analysis.pipeline`), the summary table
(:mod:`holofit.analysis.summary`) and the figures (:mod:`holofit.analysis.plots`) are the
same code for every model; a :class:`Recipe` holds everything that differs:

- the observables whose lag statistics are computed (:mod:`holofit.analysis.msd`);
- the preliminary fit that sets the default translational fit range (the *probe*), and the
  rotational observable with the rule that ends its automatic fit range;
- whether the model has an orientation to clean, and the cleaning defaults;
- the measurement: which curves are fitted over which range and what is derived from them
  (a rod's MSDs along and across its axis are fitted together, with the exact means of a
  turning axis after a lab-frame drift removal, :mod:`holofit.analysis.body_frame`);
- the hydrodynamic predictions and the sizes they need;
- the lines of the summary table and the panels of the MSD figure.

Adding a model is adding a recipe to :data:`RECIPES`.

Models (paper sections 4.2-4.3):

``rod``
    Any head-tail symmetric particle (rods, dimers): MSDs along and across the axis and in the
    lab frame, the orientation MSD ``<|du|^2>``; spherocylinder and cylinder predictions.
``janus``
    A capped sphere: the x-y MSD, and the projected-orientation correlation ``<p . p'>``
    (only x, y and the azimuth psi are used, as in the paper); sphere predictions.
``sphere``
    Translation only: the x-y MSD; the Stokes-Einstein prediction.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

import holofit.analysis.hydrodynamics as hd
from holofit.analysis.consistency import ConsistencyPlan, SizeCheck
from holofit.analysis.errors import AnalysisError
from holofit.analysis.linefit import (
    CurveModel,
    FitResult,
    combine,
    linear_msd_model,
    orientation_msd_model,
    projection_model,
    single_exponential_model,
)
from holofit.analysis.measurement import Measurement

__all__ = [
    "MODELS",
    "ORIENT_MSD_LIMIT",
    "PROJECTION_LIMIT",
    "RECIPES",
    "Compared",
    "Curve",
    "MsdPanel",
    "Probe",
    "Recipe",
    "Reported",
    "Rotation",
    "recipe_for",
]

#: the automatic rotational fit range ends where <|du|^2> reaches this (rods) ...
ORIENT_MSD_LIMIT = 0.5
#: ... or where <p . p'> falls to this (Janus)
PROJECTION_LIMIT = 0.5

NAN = float("nan")


class FitFunction(Protocol):
    """The fits a recipe's measurement may ask for (supplied by the pipeline)."""

    def __call__(self, key: str, observable: str, model: CurveModel,
                 lags: NDArray[np.int64]) -> FitResult:
        """Fit the observable's lag statistics at ``lags`` with ``model``; kept as ``key``."""

    def body_frame(self, lags: NDArray[np.int64]) -> tuple[FitResult, FitResult]:
        """Fit a rod's ``par`` and ``perp`` MSDs together at ``lags`` with their exact
        body-frame models (:mod:`holofit.analysis.body_frame`); kept as ``par``, ``perp``."""

#: sizes: name -> (value um, error um, where it came from)
Sizes = dict[str, tuple[float, float, str]]
#: predictions: key -> (prediction, unit, source)
Predictions = dict[str, tuple[hd.Prediction, str, str]]


class MeasureSettings(Protocol):
    """The settings a measurement reads (:class:`holofit.analysis.settings.AnalysisConfig`)."""

    projection_amplitude: bool
    body_frame: bool


@dataclass(frozen=True)
class Probe:
    """A preliminary fit at short lags that sets where a default fit range ends.

    Its reduced localisation error ``x = noise_factor * eps2 / (D dt)`` gives the last lag
    (``holofit.analysis.pipeline``'s adaptive rule); ``eps2`` less ``resolved_sigma`` of its
    errors (the noise where it is resolved), the range at least ``min_last_lag`` lags
    (default: the pipeline's ``MIN_FIT_LAGS``, 3).
    """

    observable: str
    model: Callable[[], CurveModel]
    noise_factor: float = 1.0
    min_last_lag: int | None = None
    resolved_sigma: float = 0.0


@dataclass(frozen=True)
class Rotation:
    """The rotational observable of a model and the end of its automatic fit range.

    Attributes
    ----------
    observable : str
        ``orient`` (``<|du|^2>``) or ``proj`` (``<p . p'>``).
    usable : callable
        Mean of the observable per lag -> True where the lag may be in the automatic fit range
        (the range ends before the first lag that is not; NaN counts as not usable).
    probe : Probe, optional
        A preliminary fit that may end the range earlier (from the angular noise).
    """

    observable: str
    usable: Callable[[NDArray[np.float64]], NDArray[np.bool_]]
    probe: Probe | None = None


@dataclass(frozen=True)
class Compared:
    """A summary line: a measured quantity beside a prediction (with its D_est sensitivity)."""

    measured: str
    label: str
    prediction: str | None
    unit: str


@dataclass(frozen=True)
class Reported:
    """A summary line: a measured quantity alone (unit from the measurement)."""

    measured: str
    label: str
    source: str
    expected: float = NAN


@dataclass(frozen=True)
class Curve:
    """One observable in an MSD panel; with ``measured``, its fit is drawn and labelled
    ``fit: <symbol> = <value>`` (``symbol`` defaults to the measurement's key)."""

    observable: str
    colour: str
    measured: str | None = None
    symbol: str | None = None


@dataclass(frozen=True)
class MsdPanel:
    """One panel of the MSD figure."""

    title: str | None
    curves: tuple[Curve, ...]


@dataclass(frozen=True)
class Recipe:
    """Everything the analysis does differently for one particle model.

    Attributes
    ----------
    name : str
        The model's name (``--model``).
    observables : tuple of str
        Lag statistics to compute, in order (the first one's rejected-pair counts are the
        ones reported).
    translation_probe : Probe
        Sets the default translational fit range.
    rotation : Rotation, optional
        The rotational observable (None: translation only).
    orientation : bool
        The model uses the particle's orientation (it needs it, and it can be cleaned).
    head_tail, reject : bool
        Default cleaning: head-tail flip correction, rejection of improbable jumps.
    sizes : tuple of str
        Sizes the predictions need (``a_um``, ``b_um``).
    measure : callable
        ``measure(fit, t_lags, r_lags, options) -> {key: Measurement}``: the fits and what is
        derived from them.
    predict : callable
        ``predict(sizes, temperature_c, temperature_err_c, notes) -> {key: (Prediction, unit,
        source)}``; appends to ``notes`` why a prediction is missing.
    summary : tuple
        Lines of the summary table (:class:`Compared`, :class:`Reported`), after the sizes.
    radius_is_hydrodynamic : bool
        The size ``a`` is the hydrodynamic radius (a sphere): effective radii are compared
        with it.
    msd_panels : tuple of MsdPanel
        The MSD figure.
    drop_ambiguous : bool
        Leave out frames the fit flagged ``ambiguous`` by default: for a rod, a frame whose
        mirrored orientation fits as well is a coin toss for its axis; a Janus particle's
        analysis uses x, y and psi only, which the mirror keeps.
    consistency : ConsistencyPlan, optional
        The physical-consistency tests of a track (:mod:`holofit.analysis.consistency`).
    """

    name: str
    observables: tuple[str, ...]
    translation_probe: Probe
    rotation: Rotation | None
    orientation: bool
    head_tail: bool
    reject: bool
    sizes: tuple[str, ...]
    measure: Callable[[FitFunction, NDArray[np.int64], NDArray[np.int64] | None,
                       MeasureSettings], dict[str, Measurement]]
    predict: Callable[[Sizes, float, float, list[str]], Predictions]
    summary: tuple[Compared | Reported, ...]
    radius_is_hydrodynamic: bool
    msd_panels: tuple[MsdPanel, ...]
    drop_ambiguous: bool = False
    consistency: ConsistencyPlan | None = None


#: the intercept ``eps^2`` counts as resolved when it lies this many errors above zero ...
RESOLVED_SIGMA = 2.0
#: ... else ``eps`` is reported as the one-sided 95 % upper limit ``sqrt(max(eps^2, 0) + z de2)``
UPPER_LIMIT_Z = 1.645


def _eps(f: FitResult, scale: float, unit: str) -> Measurement:
    """The localisation error ``sqrt(eps2)`` of a fit's intercept, times ``scale``.

    ``sqrt`` of an intercept that is not resolved from zero would report the noise of the fit
    as a localisation error: then the result is an upper limit (docs: validation, "analysis
    pulls").
    """
    e2, de2 = f.value("eps2"), f.error("eps2")
    if not math.isfinite(de2) or e2 > RESOLVED_SIGMA * de2:
        e = math.sqrt(max(e2, 0.0))
        return Measurement(scale * e, scale * de2 / (2 * e) if e > 0 else math.nan, unit)
    limit = math.sqrt(max(e2, 0.0) + UPPER_LIMIT_Z * de2)
    return Measurement(scale * limit, math.nan, unit, upper_limit=True)


def _eps_nm(f: FitResult) -> Measurement:
    """The localisation error of a positional fit's intercept, nm."""
    return _eps(f, 1e3, "nm")


# ---------------------------------------------------------------------------------- rod


def _d(f: FitResult, unit: str) -> Measurement:
    """A fit's diffusion coefficient with its sided errors."""
    lo, hi = f.d_error_sides()
    return Measurement(f.value("D"), f.error("D"), unit, error_below=lo, error_above=hi)


def _rotation_lags(r_lags: NDArray[np.int64] | None) -> NDArray[np.int64]:
    """The rotational fit lags of a model with a rotational observable."""
    if r_lags is None:
        raise AnalysisError("internal: no rotational fit range for a model that has one")
    return r_lags


def _combined(parts: list, value: float, unit: str) -> Measurement:
    v, e, lo, hi = combine(parts, value)
    return Measurement(v, e, unit, error_below=lo, error_above=hi)


def _measure_rod(
    fit: FitFunction, t_lags: NDArray[np.int64], r_lags: NDArray[np.int64] | None,
    options: MeasureSettings,
) -> dict[str, Measurement]:
    meas: dict[str, Measurement] = {}
    if options.body_frame:
        fp, fq = fit.body_frame(t_lags)
    else:  # the separate bridged lines (for comparison)
        fp = fit("par", "par", linear_msd_model(2, "par"), t_lags)
        fq = fit("perp", "perp", linear_msd_model(4, "perp"), t_lags)
    fl = fit("lab_3d", "lab_3d", linear_msd_model(6, "lab_3d"), t_lags)
    fr = fit("orient", "orient", orientation_msd_model(), _rotation_lags(r_lags))
    dpar, dperp = fp.value("D"), fq.value("D")
    meas["D_par"] = _d(fp, "um^2/s")
    meas["D_perp"] = _d(fq, "um^2/s")
    meas["D_t"] = _combined([(1 / 3, fp, "D"), (2 / 3, fq, "D")], (dpar + 2 * dperp) / 3,
                            "um^2/s")
    meas["D_t_lab"] = _d(fl, "um^2/s")
    meas["D_par/D_perp"] = _combined([(1 / dperp, fp, "D"), (-dpar / dperp**2, fq, "D")],
                                     dpar / dperp, "1")
    meas["D_r"] = _d(fr, "1/s")
    meas["eps_par"] = _eps_nm(fp)
    meas["eps_perp"] = _eps_nm(fq)
    meas["eps_r"] = _eps(fr, math.degrees(1.0), "deg")
    return meas


def _predict_rod(sizes: Sizes, t: float, dt_c: float, notes: list[str]) -> Predictions:
    out: Predictions = {}
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
        ("cyl D_par/D_perp", "1", lambda **k: hd.cylinder_diffusion(**k)["D_par/D_perp"], cy),
    ):
        out[key] = (hd.predict(fn, t, dt_c, args, errs), unit, src)
    return out


ROD = Recipe(
    name="rod",
    observables=("par", "perp", "orient", "lab_x", "lab_y", "lab_z", "lab_3d"),
    # the lab-3D probe's range serves the one-component MSD along the axis, whose intercept is
    # the least constrained: a short run's noisy probe intercept chose 4-6 lags for a rod with
    # 3 nm of noise, and D_par's pulls had a 1.2 % tail beyond 4 (s.d. 1.26 at 30 frames over
    # 1000 runs); with the noise counted where resolved at 2 sigma and 2 lags allowed, 0.7 %
    # (s.d. 1.06), longer runs and noisier ones unchanged
    translation_probe=Probe("lab_3d", lambda: linear_msd_model(6, "lab_3d"), min_last_lag=2,
                            resolved_sigma=2.0),
    # <|du|^2> = 4 (D_r tau + eps_r^2 / 2) at short lags: x = (eps_r^2 / 2) / (D_r dt)
    rotation=Rotation("orient", lambda mean: mean <= ORIENT_MSD_LIMIT,
                      Probe("orient", orientation_msd_model, noise_factor=0.5)),
    orientation=True,
    head_tail=True,
    reject=True,
    sizes=("a_um", "b_um"),
    measure=_measure_rod,
    predict=_predict_rod,
    summary=(
        Compared("D_par", "D_par", "cyl D_par", "um^2/s"),
        Compared("D_perp", "D_perp", "cyl D_perp", "um^2/s"),
        Compared("D_t", "D_t = (2 D_perp + D_par)/3", "D_t", "um^2/s"),
        Compared("D_t", "D_t = (2 D_perp + D_par)/3", "cyl D_t", "um^2/s"),
        Compared("D_t_lab", "D_t (lab-frame MSD)", "D_t", "um^2/s"),
        Compared("D_r", "D_r", "D_r", "1/s"),
        Compared("D_r", "D_r", "cyl D_r", "1/s"),
        Compared("D_par/D_perp", "D_par/D_perp", "cyl D_par/D_perp", "1"),
        Reported("eps_par", "eps_par", "fit intercept"),
        Reported("eps_perp", "eps_perp", "fit intercept"),
        Reported("eps_r", "eps_r", "fit intercept"),
    ),
    radius_is_hydrodynamic=False,
    msd_panels=(
        MsdPanel("particle frame", (Curve("par", "C0", "D_par"), Curve("perp", "C3", "D_perp"))),
        MsdPanel("lab frame", (Curve("lab_x", "C0"), Curve("lab_y", "C1"), Curve("lab_z", "C2"),
                               Curve("lab_3d", "k", "D_t_lab", "D_t"))),
    ),
    drop_ambiguous=True,
    # the lab-frame D_t (one fit, whose error at the prediction is known) and D_r against the
    # spherocylinder of the fitted a, b
    consistency=ConsistencyPlan(
        (SizeCheck("D_t", "D_t_lab", "lab_3d", 1), SizeCheck("D_r", "D_r", "orient", 3)),
        dims=3, msd="lab_3d", noise_fit="lab_3d", axis="axis", tolerance=0.10),
)


# ----------------------------------------------------------------------- sphere, janus


def _measure_xy(
    fit: FitFunction, t_lags: NDArray[np.int64], r_lags: NDArray[np.int64] | None,
    options: MeasureSettings,
) -> dict[str, Measurement]:
    fx = fit("xy", "xy", linear_msd_model(4, "xy"), t_lags)
    return {"D_t": _d(fx, "um^2/s"), "eps": _eps_nm(fx)}


def _measure_janus(
    fit: FitFunction, t_lags: NDArray[np.int64], r_lags: NDArray[np.int64] | None,
    options: MeasureSettings,
) -> dict[str, Measurement]:
    meas = _measure_xy(fit, t_lags, r_lags, options)
    amplitude = options.projection_amplitude
    fj = fit("proj", "proj", projection_model(amplitude), _rotation_lags(r_lags))
    meas["D_r"] = _d(fj, "1/s")
    if amplitude:
        meas["A"] = Measurement(fj.value("A"), fj.error("A"), "1")
    try:  # for comparison only (biased at short lags)
        fit("proj_single_exp", "proj", single_exponential_model(amplitude),
            _rotation_lags(r_lags))
    except ValueError:
        pass
    return meas


def _predict_sphere(
    sizes: Sizes, t: float, dt_c: float, notes: list[str], rotation: bool = False
) -> Predictions:
    out: Predictions = {}
    if "a_um" not in sizes:
        notes.append("no radius (a_um or radius_um) in the table or options: no predictions")
        return out
    a, da, _ = sizes["a_um"]
    out["D_t"] = (
        hd.predict(lambda **k: hd.sphere_diffusion(**k)["D_t"], t, dt_c, {"a_um": a},
                   {"a_um": da}), "um^2/s", "Stokes-Einstein sphere")
    if rotation:
        out["D_r"] = (
            hd.predict(lambda **k: hd.sphere_diffusion(**k)["D_r"], t, dt_c, {"a_um": a},
                       {"a_um": da}), "1/s", "Stokes-Einstein-Debye sphere")
    return out


def _predict_janus(sizes: Sizes, t: float, dt_c: float, notes: list[str]) -> Predictions:
    return _predict_sphere(sizes, t, dt_c, notes, rotation=True)


_XY_PANEL = (MsdPanel(None, (Curve("xy", "C0", "D_t", "D"),)),)
_XY_PROBE = Probe("xy", lambda: linear_msd_model(4, "xy"))
_EPS_XY = Reported("eps", "eps (x-y)", "fit intercept")

JANUS = Recipe(
    name="janus",
    observables=("xy", "proj"),
    translation_probe=_XY_PROBE,
    rotation=Rotation("proj", lambda mean: mean >= PROJECTION_LIMIT),
    orientation=True,
    head_tail=False,
    # psi alone is analysed, which a mirrored polar angle does not change
    reject=False,
    sizes=("a_um",),
    measure=_measure_janus,
    predict=_predict_janus,
    summary=(
        Compared("D_t", "D (x-y MSD)", "D_t", "um^2/s"),
        Compared("D_r", "D_r (projection correlation)", "D_r", "1/s"),
        Reported("A", "A (projection amplitude)", "1 without angular noise", expected=1.0),
        _EPS_XY,
    ),
    radius_is_hydrodynamic=True,
    msd_panels=_XY_PANEL,
    consistency=ConsistencyPlan(
        (SizeCheck("D_t", "D_t", "xy", 1), SizeCheck("D_r", "D_r", "proj", 3)),
        dims=2, msd="xy", noise_fit="xy", axis="projection"),
)

SPHERE = Recipe(
    name="sphere",
    observables=("xy",),
    translation_probe=_XY_PROBE,
    rotation=None,
    orientation=False,
    head_tail=False,
    reject=False,
    sizes=("a_um",),
    measure=_measure_xy,
    predict=_predict_sphere,
    summary=(Compared("D_t", "D (x-y MSD)", "D_t", "um^2/s"), _EPS_XY),
    radius_is_hydrodynamic=True,
    msd_panels=_XY_PANEL,
    consistency=ConsistencyPlan((SizeCheck("D_t", "D_t", "xy", 1),), dims=2, msd="xy",
                                noise_fit="xy"),
)

#: every model, by name
RECIPES: dict[str, Recipe] = {r.name: r for r in (ROD, JANUS, SPHERE)}
MODELS: tuple[str, ...] = tuple(RECIPES)


def recipe_for(model: str) -> Recipe:
    """The recipe of a model (``KeyError`` naming the known models if there is none)."""
    try:
        return RECIPES[model]
    except KeyError:
        raise KeyError(
            f"no analysis recipe for model {model!r}; known: {', '.join(MODELS)}"
        ) from None
