"""Physical consistency of one track: its hydrodynamic size against its optical size, and
whether it moves like the Brownian particle its analysis assumes.

Tests (each a p-value for a track that obeys the model; :mod:`holofit.analysis.nonbrownian`
for the motion tests):

* **Size** (``size D_t``, ``size D_r``): the measured coefficient against the hydrodynamic
  prediction from the fitted size (Stokes-Einstein(-Debye) for a sphere's radius, the
  spherocylinder for a rod's ``a`` and ``b``), on a log scale, as the score statistic

      z = ln(D_hat / D_th) / sqrt(s^2 + s_th^2 + tol^2),

  all three relative errors. ``s`` is the larger of the error the fit would have if the
  coefficient were the prediction (the fit's covariance moved to ``D_th``, over ``D_th``: a
  diffusion coefficient's error grows with it, and the error at a low estimate would make a
  short, noisy run look inconsistent) and the measurement's log-scale error on the
  prediction's side (``ln((D_hat + sigma_+) / D_hat)`` above, ``ln(D_hat / (D_hat -
  sigma_-))`` below: larger where a nonlinear fit, such as the Janus projection correlation,
  scatters upwards more than its covariance at ``D_th`` says). ``s_th`` is the prediction's
  relative error from the temperature and the optical size errors, propagated through the
  prediction (:func:`holofit.analysis.hydrodynamics.predict`: a rod's ``D_r ~ size^-3``
  carries three times its size's relative error). ``tol`` is the theory's own relative
  uncertainty (:attr:`ConsistencyPlan.tolerance`: walls, the shape model), the same for
  translation and rotation. The log scale is that of the rule ``D ~ size^-e``: a rotational
  coefficient's relative error is large and its distribution skewed, and a factor off (a rod
  that sticks, or one larger than its optical size) is the same distance from the prediction
  whichever way. A measured value that is not positive (and not an upper limit) is tested on
  the linear scale. The
  size the measurement implies is reported as the ratio hydrodynamic / optical,
  ``(D_th / D_hat)^(1/e)`` with ``e = 1`` for translation and 3 for rotation (a sphere's
  Stokes-Einstein radius over its fitted radius; for a rod, the factor by which ``a`` and ``b``
  would both have to grow at a fixed aspect ratio), and as the sizes themselves: the
  hydrodynamic radius against the fitted one for a sphere or a Janus particle (``hydrodynamic
  radius 827 +- 123 nm against the fitted radius 500 +- 0.82 nm``), the rod's ``a`` and ``b``
  scaled by the ratio against the fitted ones. A flagged track's message always ends with
  the sizes (from every size test that ran, failed or not): a sphere that sticks for a third
  of its run is flagged by the diffusivity-change test, and its apparent hydrodynamic radius
  says what that did to ``D``.
* **Motion**: a change of diffusivity (sticking), of drift, a velocity along the particle's
  axis (swimming), heavy-tailed steps, a curved MSD.

A track is *flagged* when any test's p-value is below ``alpha / m`` (``m`` tests run: the
Bonferroni rule, so a Brownian track of the fitted size is flagged with probability at most
``alpha``, 1 % by default); the message names every failing test with its numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from holofit.analysis.hydrodynamics import Prediction
from holofit.analysis.linefit import FitResult
from holofit.analysis.measurement import Measurement
from holofit.analysis.msd import LagStatistics, Observables
from holofit.analysis.nonbrownian import (
    TestResult,
    body_frame_drift,
    consecutive_steps,
    diffusivity_change,
    drift_change,
    increment_kurtosis,
    msd_shape,
)

__all__ = [
    "DEFAULT_ALPHA",
    "Consistency",
    "ConsistencyPlan",
    "SizeCheck",
    "check_consistency",
    "size_test",
]

#: default probability that a Brownian track of the fitted size is flagged
DEFAULT_ALPHA = 0.01


@dataclass(frozen=True)
class SizeCheck:
    """A measured coefficient tested against the prediction from the optical size.

    Attributes
    ----------
    prediction : str
        Key of the recipe's prediction (``D_t``, ``D_r``).
    measured : str
        Key of the measured quantity (``D_t``, ``D_t_lab``, ``D_r``).
    fit : str
        Key of the fit it comes from (its error at the prediction, ``FitResult.d_sigma``).
    exponent : int
        ``D ~ size^-exponent`` at a fixed shape (1: translation, 3: rotation).
    """

    prediction: str
    measured: str
    fit: str
    exponent: int = 1


@dataclass(frozen=True)
class ConsistencyPlan:
    """What a model's consistency check tests (part of its recipe).

    Attributes
    ----------
    sizes : tuple of SizeCheck
        The size tests.
    dims : int
        Coordinates of the translational steps (2: x-y, 3: x, y, z).
    msd : str
        The lab-frame MSD of the shape test (``xy`` or ``lab_3d``).
    noise_fit : str
        The fit whose intercept gives the localisation noise per coordinate.
    axis : str, optional
        ``axis`` (a rod's 3D axis: body-frame steps, rotation tested too) or ``projection``
        (a Janus particle's x-y direction of its axis); None: no axis.
    tolerance : float
        Relative uncertainty of the hydrodynamic theory itself (on the log scale of the size
        tests; translation and rotation alike): a wall a few radii away slows a sphere's
        translation by several per cent (its rotation less: the wall's effect on it falls as
        the cube of the distance); the spherocylinder and cylinder theories of a rod differ
        by ~7 % in D_t. The rotational coefficient's stronger dependence on the size is the
        optical size's error, propagated through the prediction, not a wider tolerance.
    """

    sizes: tuple[SizeCheck, ...]
    dims: int
    msd: str
    noise_fit: str
    axis: str | None = None
    tolerance: float = 0.05


class AnalysedTrack(Protocol):
    """What the check reads from an analysis (:class:`holofit.analysis.results.AnalysisResult`)."""

    valid: NDArray[np.bool_]
    stats: dict[str, LagStatistics]
    fits: dict[str, FitResult]
    measured: dict[str, Measurement]
    predictions: dict[str, tuple[Prediction, str, str]]
    sizes: dict[str, tuple[float, float, str]]


@dataclass
class Consistency:
    """The tests of one track and the verdict.

    Attributes
    ----------
    tests : list of TestResult
        Every test, run or skipped (p = NaN).
    alpha : float
        Probability that a track obeying the model is flagged.
    flagged : bool
        Some test's p-value is below :attr:`threshold`.
    failed : list of str
        The names of the failing tests.
    message : str
        Why the track is flagged, with the numbers ('' when it is not).
    """

    tests: list[TestResult]
    alpha: float
    flagged: bool = False
    failed: list[str] = field(default_factory=list)
    message: str = ""

    @property
    def threshold(self) -> float:
        """Per-test p-value below which a test fails: ``alpha / m``, ``m`` the tests run."""
        m = sum(math.isfinite(t.p_value) for t in self.tests)
        return self.alpha / m if m else math.nan

    def test(self, name: str) -> TestResult | None:
        """The test of that name, if it was run or skipped."""
        return next((t for t in self.tests if t.name == name), None)

    def summary(self) -> dict[str, Any]:
        """A JSON-ready description."""
        return {"alpha": self.alpha, "threshold_p": self.threshold, "flagged": self.flagged,
                "failed": self.failed, "message": self.message,
                "tests": [{"name": t.name, "statistic": t.statistic, "p_value": t.p_value,
                           "detail": t.detail, **t.values} for t in self.tests]}


#: the fitted sizes a size test reports (hydrodynamic against optical), by the recipes' names
_SIZE_LABELS = {"a_um": "a", "b_um": "b"}


def _nm(x: float) -> str:
    return f"{x:.0f}" if abs(x) >= 10 else f"{x:.2g}"


def _size_words(ratio: float, ratio_err: float, sizes: dict[str, tuple[float, float, str]]
                ) -> tuple[str, dict[str, float]]:
    """The hydrodynamic sizes ``ratio`` x the fitted ones, in nm, as words and values."""
    names = [k for k in _SIZE_LABELS if k in sizes]
    if not names or not math.isfinite(ratio):
        return "", {}
    values: dict[str, float] = {}
    parts_h, parts_o = [], []
    single = names == ["a_um"]
    for k in names:
        v, e = 1e3 * sizes[k][0], 1e3 * sizes[k][1]
        h = ratio * v
        h_err = ratio_err * v if math.isfinite(ratio_err) else math.nan
        label = "radius" if single else _SIZE_LABELS[k]
        values[f"hydrodynamic_{_SIZE_LABELS[k]}_nm"] = h
        values[f"hydrodynamic_{_SIZE_LABELS[k]}_err_nm"] = h_err
        values[f"optical_{_SIZE_LABELS[k]}_nm"] = v
        values[f"optical_{_SIZE_LABELS[k]}_err_nm"] = e
        parts_h.append(f"{label} {h:.0f} +- {_nm(h_err)} nm")
        parts_o.append(f"{label} {v:.0f} +- {_nm(e)} nm")
    shape = "" if single else " (at the fitted aspect ratio)"
    return (f"hydrodynamic {', '.join(parts_h)}{shape} against the fitted "
            f"{', '.join(parts_o)}"), values


def _log_errors(measured: Measurement, fit: FitResult | None,
                prediction: Prediction) -> tuple[float, float, float]:
    """The measurement's relative error (the larger of the fit's at the prediction and the
    log-scale error on the prediction's side), the fit's at the prediction alone, and the
    prediction's relative error."""
    d, d_th = measured.value, prediction.value
    lo, hi = measured.sides()
    side = math.log1p(hi / d) if d_th > d else (
        -math.log1p(-lo / d) if lo < d else math.inf)
    at_th = fit.d_sigma(d_th) / d_th if fit is not None else math.nan
    sig = max(at_th, side) if math.isfinite(at_th) else side
    return sig, at_th, prediction.error / d_th


def size_test(check: SizeCheck, measured: Measurement, fit: FitResult | None,
              prediction: Prediction, tolerance: float,
              sizes: dict[str, tuple[float, float, str]] | None = None) -> TestResult:
    """The score test of a measured coefficient against its prediction, on a log scale
    (module docstring).

    Parameters
    ----------
    check : SizeCheck
        What is tested (its exponent converts the ratio to a size ratio).
    measured : Measurement
        The measured coefficient with its sided errors.
    fit : FitResult, optional
        The fit it comes from (its error at the prediction); None: the sided errors alone.
    prediction : Prediction
        The hydrodynamic prediction from the optical size, with its error from the
        temperature and the sizes.
    tolerance : float
        The theory's relative uncertainty.
    sizes : dict, optional
        The fitted sizes (``a_um``, ``b_um``: value, error, source), for the hydrodynamic
        sizes in nm beside the ratio.

    Returns
    -------
    TestResult
        Statistic ``z``; values: ``ratio`` (measured / predicted), ``size_ratio``
        (hydrodynamic / optical) with ``size_ratio_err`` (from the sided errors), ``z``,
        ``sigma`` (the measurement's relative error used), ``sigma_at_prediction`` (the fit's
        at the prediction, relative), ``sigma_prediction`` (the prediction's, relative),
        ``sigma_total`` (the combined relative error), and for each fitted size
        ``hydrodynamic_<a|b>_nm`` and ``optical_<a|b>_nm`` (each with ``_err_nm``); the sizes
        in words in ``detail`` and :attr:`TestResult.sizes`.
    """
    name = f"size {check.prediction}"
    d, d_th = measured.value, prediction.value
    if not (math.isfinite(d) and math.isfinite(d_th) and d_th > 0):
        return TestResult(name, math.nan, math.nan, "not tested: no value or prediction")
    lo, hi = measured.sides()
    if d > 0:
        sig, at_th, s_th = _log_errors(measured, fit, prediction)
        total = math.sqrt(sig**2 + s_th**2 + tolerance**2)
        z = math.log(d / d_th) / total
        scale = "log scale"
    else:  # no log: the linear score, every error relative to the prediction
        at_th = fit.d_sigma(d_th) / d_th if fit is not None else math.nan
        sig = max(at_th, hi / d_th) if math.isfinite(at_th) else hi / d_th
        s_th = prediction.error / d_th
        total = math.sqrt(sig**2 + s_th**2 + tolerance**2)
        z = (d / d_th - 1.0) / total
        scale = "linear scale: the measured value is not positive"
    p = float(2.0 * stats.norm.sf(abs(z)))
    e = check.exponent
    size = (d_th / d) ** (1 / e) if d > 0 else math.inf
    big = (d_th / max(d - lo, 1e-12 * d_th)) ** (1 / e)
    small = (d_th / (d + hi)) ** (1 / e)
    size_err = 0.5 * (big - small) if math.isfinite(big) else math.nan
    words, size_values = _size_words(size, size_err, sizes or {})
    sizes_text = (f"{words} ({size:.3g} +- {size_err:.2g} x the optical, from "
                  f"{check.measured})" if words
                  else f"hydrodynamic size {size:.3g} +- {size_err:.2g} x the optical "
                       f"(from {check.measured})")
    detail = (f"{check.measured} {d:.4g} (-{lo:.2g} +{hi:.2g}) against {d_th:.4g} +- "
              f"{prediction.error:.2g} from the fitted size and temperature: ratio "
              f"{d / d_th:.3f}, combined relative error {100 * total:.0f} % (measurement "
              f"{100 * sig:.0f} %, prediction {100 * s_th:.1f} %, {100 * tolerance:.0f} % "
              f"theory tolerance; {scale}), z = {z:+.2f} (p = {p:.2g}); {sizes_text}")
    return TestResult(name, z, p, detail, {"ratio": d / d_th, "size_ratio": size,
                                           "size_ratio_err": size_err, "z": z,
                                           "sigma": sig, "sigma_at_prediction": at_th,
                                           "sigma_prediction": s_th, "sigma_total": total,
                                           **size_values}, sizes_text)


def _body_components(steps: NDArray, u: NDArray) -> NDArray:
    """Steps along the axis and on two directions across it (rows: steps)."""
    par = np.einsum("ij,ij->i", steps, u)
    ref = np.where(np.abs(u[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]),
                   np.array([[1.0, 0.0, 0.0]]))
    e1 = np.cross(u, ref)
    e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-12)
    e2 = np.cross(u, e1)
    return np.stack([par, np.einsum("ij,ij->i", steps, e1),
                     np.einsum("ij,ij->i", steps, e2)], axis=1)


def _motion_tests(track: AnalysedTrack, plan: ConsistencyPlan, position_um: NDArray,
                  axis: NDArray | None, frame_interval_s: float,
                  duration_s: float | None) -> list[TestResult]:
    valid = track.valid
    fits, meas = track.fits, track.measured
    pos = position_um[:, : plan.dims]
    nf = fits.get(plan.noise_fit)
    noise = max(nf.value("eps2"), 0.0) if nf is not None else 0.0
    steps, start = consecutive_steps(pos, valid)
    tests = [diffusivity_change(steps, start, noise, "diffusivity change"),
             drift_change(pos, valid, "drift change")]
    if plan.axis == "axis" and axis is not None:
        u = axis[start]
        tests.append(increment_kurtosis(_body_components(steps, u)))
        fr = fits.get("orient")
        eps_r2 = max(fr.value("eps2"), 0.0) if fr is not None else 0.0
        du, dstart = consecutive_steps(axis, valid)
        tests.append(diffusivity_change(du, dstart, eps_r2 / 2.0, "rotation change"))
        tests.append(body_frame_drift(
            pos, axis, valid, frame_interval_s, meas["D_par"].value, meas["D_perp"].value,
            noise))
    else:
        tests.append(increment_kurtosis(steps))
        if plan.axis == "projection" and axis is not None:
            p = axis[:, :2] / np.maximum(np.linalg.norm(axis[:, :2], axis=1, keepdims=True),
                                         1e-12)
            d = meas["D_t"].value
            tests.append(body_frame_drift(pos, p, valid, frame_interval_s, d, d, noise))
    st = track.stats.get(plan.msd)
    f_t = fits.get(plan.noise_fit)
    if st is not None and f_t is not None:
        obs = Observables(position_um, None, valid)
        tests.append(msd_shape(st, plan.dims, obs, int(f_t.lags[0]), int(f_t.lags[-1]),
                               duration_s))
    return tests


def check_consistency(
    track: AnalysedTrack, plan: ConsistencyPlan, position_um: NDArray[np.float64],
    axis: NDArray[np.float64] | None, frame_interval_s: float, duration_s: float | None,
    alpha: float = DEFAULT_ALPHA, tolerance: float | None = None,
) -> Consistency:
    """Run a model's consistency tests on an analysed track (module docstring).

    Parameters
    ----------
    track : AnalysedTrack
        The analysis (fits, measurements, predictions, the frames used).
    plan : ConsistencyPlan
        The model's tests.
    position_um : ndarray, shape (N, 3)
        Positions after the drift removal, um.
    axis : ndarray, shape (N, 3), optional
        The cleaned axis (head-tail consistent), for the body-frame tests.
    frame_interval_s : float
        Time between frames, s.
    duration_s : float, optional
        Span of the drift removal, s (None: no drift removed).
    alpha : float
        Probability that a track obeying the model is flagged.
    tolerance : float, optional
        Relative uncertainty of the hydrodynamic theory (default: the plan's).
    """
    tol = plan.tolerance if tolerance is None else tolerance
    tests: list[TestResult] = []
    for check in plan.sizes:
        m = track.measured.get(check.measured)
        pred = track.predictions.get(check.prediction)
        if m is None or pred is None or m.upper_limit:
            tests.append(TestResult(f"size {check.prediction}", math.nan, math.nan,
                                    "not tested: no prediction (no fitted size)"))
            continue
        tests.append(size_test(check, m, track.fits.get(check.fit), pred[0], tol,
                               track.sizes))
    tests += _motion_tests(track, plan, position_um, axis, frame_interval_s, duration_s)
    result = Consistency(tests, alpha)
    limit = result.threshold
    failed = [t for t in tests if math.isfinite(t.p_value) and t.p_value < limit]
    if failed:
        result.flagged = True
        result.failed = [t.name for t in failed]
        sizes = [t.sizes for t in tests
                 if t.name.startswith("size ") and t.sizes and t not in failed]
        result.message = (
            f"not the free Brownian motion of the fitted particle ({len(failed)} of "
            f"{sum(math.isfinite(t.p_value) for t in tests)} tests below p = {limit:.2g}): "
            + "; ".join(f"{t.name}: {t.detail}" for t in failed)
            + "".join(f"; sizes: {s}" for s in sizes))
    return result
