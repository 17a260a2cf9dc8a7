"""Weighted fits of lag statistics, with errors that account for the correlations between lags.

The fit minimises ``sum_k ((f(tau_k; theta) - m_k) / sigma_k)^2`` over the lags of the fit
range, ``sigma_k`` being the block-decorrelated error bar of ``m_k``. The averages at
neighbouring lags come from overlapping pairs of the same trajectory and are strongly
correlated, so ``(J^T J)^-1`` (which assumes independent points) understates the parameter
errors. We linearise the fit at the optimum, ``theta - theta_hat = A (m - m_hat)`` with
``A = (J^T J)^-1 J^T diag(1/sigma)``; since every ``m_k`` is a time average, ``theta`` is then a
sum over time origins of per-origin contributions (its *influence series*), and the
Flyvbjerg-Petersen error of that single series is the parameter's error with every
correlation, between lags and in time, included. Derived quantities (``D_t``, ratios) combine
the influence series of their ingredients linearly (delta method) before blocking, so their
covariances are included too. ``naive_errors`` keeps ``sqrt(diag((J^T J)^-1))`` for comparison.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from holofit.analysis.blocking import block_standard_errors
from holofit.analysis.errors import AnalysisError
from holofit.analysis.msd import LagStatistics, Observables, PairFilter, influence_series
from holofit.analysis.projection import (
    projection_correlation,
    projection_correlation_derivative,
)

__all__ = [
    "CurveModel",
    "FitResult",
    "combine",
    "fit_lag_statistics",
    "linear_msd_model",
    "orientation_msd_model",
    "projection_model",
    "single_exponential_model",
]


@dataclass(frozen=True)
class CurveModel:
    """A model ``f(tau; theta)`` with its Jacobian and a starting guess."""

    name: str
    params: tuple[str, ...]
    formula: str
    f: Callable[[NDArray, NDArray], NDArray]
    jac: Callable[[NDArray, NDArray], NDArray]
    guess: Callable[[NDArray, NDArray], NDArray]


def linear_msd_model(k: float, label: str) -> CurveModel:
    """``k (D tau + eps^2)``: the MSD of ``k/2`` Brownian degrees of freedom with noise ``eps``."""

    def f(p: NDArray, tau: NDArray) -> NDArray:
        return k * (p[0] * tau + p[1])

    def jac(p: NDArray, tau: NDArray) -> NDArray:
        return np.stack([k * tau, np.full_like(tau, k)], axis=1)

    def guess(tau: NDArray, m: NDArray) -> NDArray:
        if tau.size >= 2:
            slope, icpt = np.polyfit(tau, m, 1)
            return np.array([slope / k, icpt / k])
        return np.array([m[0] / (k * tau[0]), 0.0])

    return CurveModel(label, ("D", "eps2"), f"{k:g} D tau + {k:g} eps^2", f, jac, guess)


def orientation_msd_model() -> CurveModel:
    """``2 (1 - exp(-2 D_r tau)) + 2 eps_r^2``: MSD of the unit axis."""

    def f(p: NDArray, tau: NDArray) -> NDArray:
        return 2.0 * (1.0 - np.exp(-2.0 * p[0] * tau)) + 2.0 * p[1]

    def jac(p: NDArray, tau: NDArray) -> NDArray:
        return np.stack([4.0 * tau * np.exp(-2.0 * p[0] * tau), np.full_like(tau, 2.0)], axis=1)

    def guess(tau: NDArray, m: NDArray) -> NDArray:
        if tau.size >= 2:
            slope, icpt = np.polyfit(tau[: max(2, tau.size // 3)], m[: max(2, tau.size // 3)], 1)
            return np.array([max(slope / 4.0, 1e-6), max(icpt / 2.0, 0.0)])
        return np.array([m[0] / (4 * tau[0]), 0.0])

    return CurveModel(
        "orientation", ("D", "eps2"), "2 (1 - exp(-2 D_r tau)) + 2 eps_r^2", f, jac, guess
    )


def projection_model(amplitude: bool = True, n_odd: int | None = None) -> CurveModel:
    """Paper appendix series ``A sum_l ... exp(-l(l+1) D_r tau)`` (``n_odd`` terms; all by default).

    ``A`` (free when ``amplitude``) absorbs the loss of correlation from angular noise; ``A = 1``
    without noise.
    """

    def f(p: NDArray, tau: NDArray) -> NDArray:
        amp = p[1] if amplitude else 1.0
        return amp * projection_correlation(p[0], tau, n_odd)

    def jac(p: NDArray, tau: NDArray) -> NDArray:
        amp = p[1] if amplitude else 1.0
        cols = [amp * projection_correlation_derivative(p[0], tau, n_odd)]
        if amplitude:
            cols.append(projection_correlation(p[0], tau, n_odd))
        return np.stack(cols, axis=1)

    def guess(tau: NDArray, m: NDArray) -> NDArray:
        good = m > 0.05
        if good.sum() >= 2:
            slope = np.polyfit(tau[good], np.log(m[good]), 1)[0]
            d = max(-slope / 2.0, 1e-8)
        else:
            d = 1.0 / tau[-1]
        return np.array([d, 1.0]) if amplitude else np.array([d])

    label = "projection" if n_odd is None else f"projection_l{2 * n_odd - 1}"
    params = ("D", "A") if amplitude else ("D",)
    return CurveModel(label, params, "A/4 sum_l odd ... exp(-l(l+1) D_r tau)", f, jac, guess)


def single_exponential_model(amplitude: bool = True) -> CurveModel:
    """``A exp(-2 D_r tau)``: the single-exponential (``l = 1`` shape) approximation."""

    def f(p: NDArray, tau: NDArray) -> NDArray:
        amp = p[1] if amplitude else 1.0
        return amp * np.exp(-2.0 * p[0] * tau)

    def jac(p: NDArray, tau: NDArray) -> NDArray:
        amp = p[1] if amplitude else 1.0
        e = np.exp(-2.0 * p[0] * tau)
        cols = [-2.0 * tau * amp * e]
        if amplitude:
            cols.append(e)
        return np.stack(cols, axis=1)

    def guess(tau: NDArray, m: NDArray) -> NDArray:
        return projection_model(amplitude).guess(tau, m)

    params = ("D", "A") if amplitude else ("D",)
    return CurveModel("single_exponential", params, "A exp(-2 D_r tau)", f, jac, guess)


@dataclass
class FitResult:
    """A weighted fit of one observable over a lag range."""

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
    influence: NDArray[np.float64] = field(repr=False)
    error_converged: bool = True
    success: bool = True

    def value(self, name: str) -> float:
        """Fitted value of parameter ``name``."""
        return float(self.values[self.model.params.index(name)])

    def error(self, name: str) -> float:
        """Block-decorrelated 1-sigma error of parameter ``name``."""
        return float(self.errors[self.model.params.index(name)])

    def influence_of(self, name: str) -> NDArray[np.float64]:
        """Influence series of parameter ``name``."""
        return self.influence[self.model.params.index(name)]

    def curve(self, tau: NDArray) -> NDArray[np.float64]:
        """The fitted model at lags ``tau`` (s)."""
        return self.model.f(self.values, np.asarray(tau, dtype=float))


def _sum_error(y: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Block-decorrelated standard error of ``sum_t y[:, t]`` for each row."""
    _, sem, _, conv = block_standard_errors(y)
    return sem * y.shape[1], conv


def fit_lag_statistics(
    stats: LagStatistics,
    model: CurveModel,
    obs: Observables,
    pair_filter: PairFilter | None = None,
) -> FitResult:
    """Weighted least-squares fit of ``stats`` (already restricted to the fit range).

    Raises
    ------
    AnalysisError
        Fewer usable lags than parameters.
    """
    good = np.isfinite(stats.mean) & np.isfinite(stats.sem) & (stats.count >= 2)
    st = LagStatistics(
        stats.name, stats.lags[good], stats.tau_s[good], stats.mean[good], stats.sem[good],
        stats.count[good], stats.rejected[good], stats.converged[good],
    )
    n_par = len(model.params)
    if st.lags.size < n_par:
        raise AnalysisError(
            f"fit of {stats.name}: {st.lags.size} usable lag(s) for {n_par} parameters"
        )
    tau, m = st.tau_s, st.mean
    floor = 1e-12 * max(float(np.max(np.abs(m))), 1e-300)
    sigma = np.maximum(st.sem, floor)

    def resid(p: NDArray) -> NDArray:
        return (model.f(p, tau) - m) / sigma

    def jac(p: NDArray) -> NDArray:
        return model.jac(p, tau) / sigma[:, None]

    p0 = model.guess(tau, m)
    sol = least_squares(resid, p0, jac=jac, method="lm" if tau.size > n_par else "trf",
                        xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200 * (n_par + 1))
    p = sol.x
    j = jac(p)
    jtj_inv = np.linalg.pinv(j.T @ j)
    naive = np.sqrt(np.clip(np.diag(jtj_inv), 0, None))
    a = jtj_inv @ j.T / sigma[None, :]  # d theta / d m
    infl = influence_series(obs, st.name, st, a, pair_filter)
    err, conv = _sum_error(infl)
    dof = max(tau.size - n_par, 1)
    chi2 = float(np.sum(resid(p) ** 2) / dof)
    return FitResult(
        st.name, model, p, err, naive, st.lags, tau, m, sigma, chi2, infl, bool(np.all(conv)),
        bool(sol.success),
    )


def combine(
    parts: Sequence[tuple[float, NDArray[np.float64]]], value: float
) -> tuple[float, float]:
    """Error of a derived quantity ``q(theta_1, theta_2, ...)`` by the delta method.

    Parameters
    ----------
    parts : sequence of (gradient, influence series)
        ``dq/dtheta_i`` and the influence series of ``theta_i``.
    value : float
        ``q`` at the fitted values (returned unchanged).

    Returns
    -------
    value, error : float
    """
    y = np.zeros_like(parts[0][1])
    for grad, series in parts:
        y = y + grad * series
    err, _ = _sum_error(y[None, :])
    return value, float(err[0])
