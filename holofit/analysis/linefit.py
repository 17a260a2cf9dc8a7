"""Fits of lag statistics, with errors that account for the correlations between lags.

The averages at neighbouring lags come from overlapping pairs of the same trajectory and are
strongly correlated, so a fit that treats them as independent points understates the
parameter errors (and weighs the lags badly). Three cases:

* **Generalised least squares** (models with an analytic ``covariance`` and ``gls``: the
  MSDs, :mod:`holofit.analysis.msd_covariance`): the fit minimises
  ``(f(theta) - m)^T C(theta)^-1 (f(theta) - m)`` with the covariance ``C`` of the lag
  averages evaluated at the current parameters (three rounds from a weighted fit), and the
  parameter covariance is ``(J^T C^-1 J)^-1``. This is the best linear unbiased estimator
  for the MSD of diffusion with localisation noise (Michalet, Phys. Rev. E 82, 041914, 2010)
  and its error is exact to first order: no blocking plateau is needed, so short runs get
  errors as right as long ones.
* **Sandwich** (a ``covariance`` but not ``gls``: the projection correlation, whose covariance
  is simulated, :mod:`holofit.analysis.projection_covariance`, and too noisy to invert): the
  fit is weighted by the block errors ``sigma_k`` of the points, and the parameter covariance
  is ``A C A^T`` with ``A = (J^T W J)^-1 J^T W`` the fit's linear response to the data.
  Its sided errors (:func:`sided_errors`) take ``sigma(D)`` with both ``A`` and ``C`` at
  ``D``: the correlation decays faster for a larger ``D_r``, so the same data fix it less well,
  and a ``sigma(D)`` with ``A`` held at the estimate made the upper errors of low estimates
  too small (Janus ``D_r``: mean pull -0.3 at 300 frames; -0.1 with ``A`` at ``D``). The
  interval ends at ``D = 0``.
* **Influence series** (no covariance model): the linearised fit ``theta - theta_hat =
  A (m - m_hat)`` is a sum over time origins of per-origin contributions, and the
  Flyvbjerg-Petersen error of that single series is the parameter's error (it needs the
  blocking plateau, i.e. runs much longer than the lags' correlation time).

``naive_errors`` keeps ``sqrt(diag((J^T W J)^-1))``, which ignores the correlations, for
comparison. Derived quantities (``D_t``, ratios) combine the parameters of independent fits by
the delta method (:func:`combine`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from holofit.analysis.blocking import block_standard_errors
from holofit.analysis.curve_models import (
    CurveModel,
    linear_msd_model,
    orientation_msd_model,
    projection_model,
    single_exponential_model,
)
from holofit.analysis.errors import AnalysisError
from holofit.analysis.msd import (
    LagStatistics,
    Observables,
    PairFilter,
    influence_series,
    pair_mask,
)

__all__ = [
    "CurveModel",
    "FitResult",
    "JointFit",
    "combine",
    "fit_lag_statistics",
    "linear_msd_model",
    "orientation_msd_model",
    "projection_model",
    "sided_errors",
    "sigma_function",
    "single_exponential_model",
    "whitener",
]


@dataclass(frozen=True)
class JointFit:
    """Parameters fitted together for several observables, with their full covariance.

    Attributes
    ----------
    params : tuple of str
        Names of the joint parameters.
    values : ndarray
        Their fitted values.
    covariance : ndarray
        Their covariance matrix (the :class:`FitResult` views hold its diagonal blocks).
    """

    params: tuple[str, ...]
    values: NDArray[np.float64]
    covariance: NDArray[np.float64] = field(repr=False)

    def correlation(self, i: int, j: int) -> float:
        """Correlation coefficient of parameters ``i`` and ``j``."""
        c = self.covariance
        den = math.sqrt(max(c[i, i], 0.0) * max(c[j, j], 0.0))
        return float(c[i, j] / den) if den > 0 else math.nan


@dataclass
class FitResult:
    """A fit of one observable over a lag range.

    ``covariance`` is the parameters' covariance matrix (``errors`` its diagonal's square
    root); ``method`` says how it was found (``gls``, ``sandwich`` or ``influence``, see the
    module docstring). ``sigma`` are the points' error bars (from the covariance model where
    there is one, else the block errors); ``chi2_reduced`` is the generalised chi-square per
    degree of freedom for a GLS fit. A view of a joint fit (:mod:`holofit.analysis.body_frame`)
    has ``joint``, and ``joint_index`` gives the joint parameter of each of its own;
    ``sigma_at`` is ``sigma(D)`` at any ``D`` (:meth:`d_sigma`).
    """

    observable: str
    model: CurveModel
    values: NDArray[np.float64]
    errors: NDArray[np.float64]
    naive_errors: NDArray[np.float64]
    lags: NDArray[np.int64]
    tau_s: NDArray[np.float64]
    data: NDArray[np.float64]
    sigma: NDArray[np.float64]
    chi2_reduced: float
    covariance: NDArray[np.float64] = field(repr=False)
    method: str = "gls"
    error_converged: bool = True
    success: bool = True
    d_errors: tuple[float, float] = (float("nan"), float("nan"))
    joint: JointFit | None = field(default=None, repr=False)
    joint_index: tuple[int, ...] | None = None
    sigma_at: Callable[[float], float] | None = field(default=None, repr=False)

    def d_sigma(self, d: float) -> float:
        """The error ``sigma(D)`` the fit would have if the coefficient were ``d`` (the other
        parameters moved along their regression on it; what a score test of ``D = d`` needs);
        the symmetric error where the fit has no covariance model."""
        if self.sigma_at is None:
            return self.error("D")
        return self.sigma_at(d)

    def d_error_sides(self) -> tuple[float, float]:
        """Errors of ``D`` below and above the value (:func:`sided_errors`; both equal to
        the symmetric error where they were not computed)."""
        e = self.error("D")
        lo, hi = self.d_errors
        return (lo if math.isfinite(lo) else e, hi if math.isfinite(hi) else e)

    def value(self, name: str) -> float:
        """Fitted value of parameter ``name``."""
        return float(self.values[self.model.params.index(name)])

    def error(self, name: str) -> float:
        """1-sigma error of parameter ``name``."""
        return float(self.errors[self.model.params.index(name)])

    def curve(self, tau: NDArray) -> NDArray[np.float64]:
        """The fitted model at lags ``tau`` (s)."""
        return self.model.f(self.values, np.asarray(tau, dtype=float))


def _sum_error(y: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Block-decorrelated standard error of ``sum_t y[:, t]`` for each row."""
    _, sem, _, conv = block_standard_errors(y)
    return sem * y.shape[1], conv


#: rounds of generalised least squares, each with the covariance at the previous optimum
GLS_ROUNDS = 3
#: fixed-point rounds of the sided errors (GLS; sandwich, whose covariance is simulated)
SIDED_ROUNDS = (4, 2)


def sided_errors(
    p: NDArray[np.float64], pcov: NDArray[np.float64],
    pcov_at: Callable[[NDArray[np.float64]], NDArray[np.float64]], rounds: int,
) -> tuple[float, float]:
    """Errors of the first parameter ``D`` below and above its value.

    The error of a diffusion coefficient grows with the coefficient (an MSD's scatter is
    proportional to it), so the error at the estimate is too small when the estimate came out
    low and too large when it came out high: on short runs pulls against the truth are
    skewed. The interval ``{D : |D_hat - D| <= sigma(D)}`` has the right coverage instead;
    its ends solve ``D_+ - D_hat = sigma(D_+)`` and ``D_hat - D_- = sigma(D_-)`` (a score or
    Wilson interval), found by fixed-point iteration with the other parameters moved along
    their regression on ``D``. Quote ``D_hat -sigma_- +sigma_+``; a pull is
    ``(D_hat - D_true) / sigma_+`` when the estimate is below the truth and ``/ sigma_-``
    above.
    """
    var = float(pcov[0, 0])
    if not var > 0:
        return float("nan"), float("nan")
    direction = np.concatenate([[1.0], pcov[1:, 0] / var])
    out = []
    for sign in (-1.0, 1.0):
        sig = math.sqrt(var)
        for _ in range(rounds):
            v = float(pcov_at(p + sign * sig * direction)[0, 0])
            if not v > 0:
                break
            sig = math.sqrt(v)
        out.append(sig)
    return out[0], out[1]


def sigma_function(
    p: NDArray[np.float64], pcov: NDArray[np.float64],
    pcov_at: Callable[[NDArray[np.float64]], NDArray[np.float64]],
) -> Callable[[float], float] | None:
    """``sigma(D)`` of the first parameter along the regression of the others on it (the
    function whose fixed points are the sided errors, :func:`sided_errors`)."""
    var = float(pcov[0, 0])
    if not var > 0:
        return None
    direction = np.concatenate([[1.0], pcov[1:, 0] / var])
    p = np.array(p, dtype=float)

    def at(d: float) -> float:
        v = float(pcov_at(p + (d - p[0]) * direction)[0, 0])
        return math.sqrt(v) if v > 0 else float("nan")

    return at


def _solve(resid: Callable, jac: Callable, p0: NDArray, n_points: int, n_par: int,
           lower: tuple[float, ...] | None = None):
    if lower is not None:
        lo = np.asarray(lower, dtype=float)
        fin = np.isfinite(lo)
        p0 = np.where(fin, np.maximum(p0, np.where(fin, lo, 0.0) + 1e-12), p0)
        return least_squares(resid, p0, jac=jac, method="trf", bounds=(lo, np.inf),
                             xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200 * (n_par + 1))
    return least_squares(resid, p0, jac=jac, method="lm" if n_points > n_par else "trf",
                         xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200 * (n_par + 1))


def whitener(cov: NDArray[np.float64]) -> NDArray[np.float64]:
    """``L^-1`` with ``L L^T = cov`` (a tiny ridge keeps a nearly singular covariance usable)."""
    scale = float(np.mean(np.diag(cov))) if cov.size else 1.0
    ridge = 1e-12 * (scale if scale > 0 else 1.0)
    chol = np.linalg.cholesky(cov + ridge * np.eye(cov.shape[0]))
    return np.linalg.inv(chol)



@dataclass(frozen=True)
class _Errors:
    """What an error method returns: the parameters (possibly refitted), their covariance, the
    point errors used for the figure, chi^2 per degree of freedom and the sided errors of D."""

    p: NDArray[np.float64]
    success: bool
    pcov: NDArray[np.float64]
    sigma: NDArray[np.float64]
    chi2: float
    d_errors: tuple[float, float]
    method: str
    converged: bool = True
    sigma_at: Callable[[float], float] | None = None


def _usable(stats: LagStatistics) -> LagStatistics:
    good = np.isfinite(stats.mean) & np.isfinite(stats.sem) & (stats.count >= 2)
    return LagStatistics(
        stats.name, stats.lags[good], stats.tau_s[good], stats.mean[good], stats.sem[good],
        stats.count[good], stats.rejected[good], stats.converged[good],
    )


def _gls_errors(model: CurveModel, tau: NDArray, m: NDArray, p: NDArray, success: bool,
                cov_at: Callable, dof: int) -> _Errors:
    """Generalised least squares with the lag covariance at the current D, iterated."""
    for _ in range(GLS_ROUNDS):
        w = whitener(cov_at(p))

        def gresid(q: NDArray, w: NDArray = w) -> NDArray:
            return w @ (model.f(q, tau) - m)

        def gjac(q: NDArray, w: NDArray = w) -> NDArray:
            return w @ model.jac(q, tau)

        sol = _solve(gresid, gjac, p, tau.size, len(model.params))
        p, success = sol.x, bool(sol.success)

    def gls_pcov(q: NDArray) -> NDArray:
        wq = whitener(cov_at(q))
        jw = wq @ model.jac(q, tau)
        return np.linalg.pinv(jw.T @ jw)

    cov_m = cov_at(p)
    w = whitener(cov_m)
    pcov = gls_pcov(p)
    chi2 = float(np.sum((w @ (model.f(p, tau) - m)) ** 2) / dof)
    d_errors = sided_errors(p, pcov, gls_pcov, SIDED_ROUNDS[0])
    sigma = np.sqrt(np.clip(np.diag(cov_m), 0, None))
    return _Errors(p, success, pcov, sigma, chi2, d_errors, "gls", True,
                   sigma_function(p, pcov, gls_pcov))


def _sandwich_errors(model: CurveModel, tau: NDArray, m: NDArray, p: NDArray, cov_at: Callable,
                     floor: float, chi2: float) -> _Errors:
    """Refit weighted by the model's own point errors, then the sandwich covariance."""
    # the block errors of a short run are noisy, and weights that follow the data's
    # fluctuations bias the fit
    sig_m = np.maximum(np.sqrt(np.clip(np.diag(cov_at(p)), 0, None)), floor)

    def wresid(q: NDArray) -> NDArray:
        return (model.f(q, tau) - m) / sig_m

    def wjac(q: NDArray) -> NDArray:
        return model.jac(q, tau) / sig_m[:, None]

    sol = _solve(wresid, wjac, p, tau.size, len(model.params), model.lower)
    p, success = sol.x, bool(sol.success)
    j = wjac(p)
    a = np.linalg.pinv(j.T @ j) @ j.T / sig_m[None, :]
    cov_m = cov_at(p)
    pcov = a @ cov_m @ a.T

    def sandwich_at(q: NDArray) -> NDArray:
        # sigma(D) of the score interval: the estimator's sensitivity (its Jacobian)
        # and the data's covariance both at D (a D >= 0 model is not evaluated below 0)
        q = np.array(q, dtype=float)
        if model.lower is not None:
            q = np.maximum(q, np.where(np.isfinite(model.lower), model.lower, -np.inf))
        jq = model.jac(q, tau) / sig_m[:, None]
        aq = np.linalg.pinv(jq.T @ jq) @ jq.T / sig_m[None, :]
        return aq @ cov_at(q) @ aq.T

    d_errors = sided_errors(p, pcov, sandwich_at, SIDED_ROUNDS[1])
    if model.lower is not None and math.isfinite(model.lower[0]):
        # the interval ends at the bound (D >= 0): no error below reaches past it
        d_errors = (min(d_errors[0], float(p[0] - model.lower[0])), d_errors[1])
    sigma = np.sqrt(np.clip(np.diag(cov_m), 0, None))
    return _Errors(p, success, pcov, sigma, chi2, d_errors, "sandwich", True,
                   sigma_function(p, pcov, sandwich_at))


def _influence_covariance(obs: Observables, st: LagStatistics, a: NDArray, n_par: int,
                          pair_filter: PairFilter | None) -> tuple[NDArray, bool]:
    """Covariance of the parameters from the influence series of the data."""
    infl = influence_series(obs, st.name, st, a, pair_filter)
    err, conv_rows = _sum_error(infl)
    pcov = np.diag(err**2)
    for i in range(n_par):  # covariances from the errors of pairwise sums
        for k in range(i + 1, n_par):
            e_sum, c_sum = _sum_error((infl[i] + infl[k])[None, :])
            pcov[i, k] = pcov[k, i] = 0.5 * (e_sum[0] ** 2 - err[i] ** 2 - err[k] ** 2)
            conv_rows = np.append(conv_rows, c_sum)
    return pcov, bool(np.all(conv_rows))


def fit_lag_statistics(
    stats: LagStatistics,
    model: CurveModel,
    obs: Observables,
    pair_filter: PairFilter | None = None,
) -> FitResult:
    """Fit ``stats`` (already restricted to the fit range) with ``model``.

    Raises
    ------
    AnalysisError
        Fewer usable lags than parameters.
    """
    st = _usable(stats)
    n_par = len(model.params)
    if st.lags.size < n_par:
        raise AnalysisError(
            f"fit of {stats.name}: {st.lags.size} usable lag(s) for {n_par} parameters"
        )
    tau, m = st.tau_s, st.mean
    dt = float(tau[0] / st.lags[0])
    floor = 1e-12 * max(float(np.max(np.abs(m))), 1e-300)
    sigma = np.maximum(st.sem, floor)

    def resid(p: NDArray) -> NDArray:
        return (model.f(p, tau) - m) / sigma

    def jac(p: NDArray) -> NDArray:
        return model.jac(p, tau) / sigma[:, None]

    sol = _solve(resid, jac, model.guess(tau, m), tau.size, n_par, model.lower)
    p, success = sol.x, bool(sol.success)
    j = jac(p)
    jtj_inv = np.linalg.pinv(j.T @ j)
    naive = np.sqrt(np.clip(np.diag(jtj_inv), 0, None))
    dof = max(tau.size - n_par, 1)
    chi2 = float(np.sum(resid(p) ** 2) / dof)
    if model.covariance is not None and model.params[0] == "D":
        masks = [pair_mask(obs.valid, int(k), pair_filter) for k in st.lags]
        cov_at = model.covariance(st.lags, masks, dt)
        if model.gls:
            res = _gls_errors(model, tau, m, p, success, cov_at, dof)
        else:
            res = _sandwich_errors(model, tau, m, p, cov_at, floor, chi2)
    else:
        a = jtj_inv @ j.T / sigma[None, :]  # d theta / d m of the weighted fit
        pcov, conv = _influence_covariance(obs, st, a, n_par, pair_filter)
        res = _Errors(p, success, pcov, sigma, chi2, (float("nan"), float("nan")), "influence",
                      conv)
    errors = np.sqrt(np.clip(np.diag(res.pcov), 0, None))
    return FitResult(
        st.name, model, res.p, errors, naive, st.lags, tau, m, res.sigma, res.chi2,
        np.atleast_2d(res.pcov), res.method, res.converged, res.success, res.d_errors,
        sigma_at=res.sigma_at,
    )


def combine(
    parts: Sequence[tuple[float, FitResult, str]], value: float
) -> tuple[float, float, float, float]:
    """Error of a derived quantity ``q(theta_1, theta_2, ...)`` by the delta method.

    Parameters of the same fit, or of the same joint fit (:class:`JointFit`, e.g. ``D_par``
    and ``D_perp`` of :func:`holofit.analysis.body_frame.fit_body_frame`), are combined with
    their covariance; different fits are independent (they fit different data, or
    coordinates whose fluctuations are independent). The sided errors scale each ``D``'s
    fluctuation by the ratio of its sided error to its symmetric one, the side that moves
    ``q`` the same way, because a diffusion coefficient's error grows with it.

    Parameters
    ----------
    parts : sequence of (gradient, fit, parameter name)
        ``dq/dtheta_i`` and where ``theta_i`` comes from.
    value : float
        ``q`` at the fitted values (returned unchanged).

    Returns
    -------
    value, error, error_below, error_above : float
    """
    groups: dict[int, tuple[NDArray, NDArray, NDArray, NDArray]] = {}
    for grad, fit, name in parts:
        own = fit.model.params.index(name)
        if fit.joint is not None and fit.joint_index is not None:
            key, size, cov, idx = id(fit.joint), len(fit.joint.params), fit.joint.covariance, \
                fit.joint_index[own]
        else:
            key, size, cov, idx = id(fit), len(fit.model.params), fit.covariance, own
        g, lo_f, hi_f, _ = groups.setdefault(
            key, (np.zeros(size), np.ones(size), np.ones(size), cov))
        g[idx] += grad
        if name == "D":
            e = fit.error("D")
            lo, hi = fit.d_error_sides()
            lo_f[idx] = lo / e if e > 0 else 1.0
            hi_f[idx] = hi / e if e > 0 else 1.0
    var = np.zeros(3)
    for g, lo_f, hi_f, cov in groups.values():
        rising = g >= 0
        below = g * np.where(rising, lo_f, hi_f)
        above = g * np.where(rising, hi_f, lo_f)
        var += [float(g @ cov @ g), float(below @ cov @ below), float(above @ cov @ above)]
    err = np.sqrt(np.clip(var, 0.0, None))
    return value, float(err[0]), float(err[1]), float(err[2])
