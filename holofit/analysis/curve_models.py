"""Curve models of lag statistics: the MSD lines, the orientation MSD, the projection series.

A :class:`CurveModel` is a function ``f(tau; theta)`` with its Jacobian, a starting guess and,
where one is known, the covariance of the lag averages it describes; the fits are in
:mod:`holofit.analysis.linefit`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from holofit.analysis.msd_covariance import MsdCovarianceBasis
from holofit.analysis.projection import (
    projection_correlation,
    projection_correlation_derivative,
)
from holofit.analysis.projection_covariance import projection_covariance

__all__ = [
    "PROJECTION_D_FLOOR",
    "Covariance",
    "CurveModel",
    "linear_msd_model",
    "orientation_msd_model",
    "projection_model",
    "single_exponential_model",
]


#: ``covariance(lags, masks, frame_interval_s)(theta)``: covariance matrix of the lag averages
#: at ``lags`` (frames) whose usable pairs are ``masks`` (one per lag), for parameters ``theta``
#: (a factory, so that what does not depend on ``theta`` is computed once per fit)
Covariance = Callable[[NDArray, Sequence[NDArray], float], Callable[[NDArray], NDArray]]


@dataclass(frozen=True)
class CurveModel:
    """A model ``f(tau; theta)`` with its Jacobian and a starting guess.

    Attributes
    ----------
    covariance : callable, optional
        Covariance of the lag averages the model describes (:data:`Covariance`).
    gls : bool
        Fit by generalised least squares with ``covariance`` (else: weighted fit, sandwich
        error).
    bridged : callable, optional
        ``bridged(duration_s)``: the model for a trajectory whose end-to-end drift was
        subtracted (:func:`linear_msd_model`).
    lower : tuple of float, optional
        Lower bounds of the parameters (where the model is undefined below them).
    """

    name: str
    params: tuple[str, ...]
    formula: str
    f: Callable[[NDArray, NDArray], NDArray]
    jac: Callable[[NDArray, NDArray], NDArray]
    guess: Callable[[NDArray, NDArray], NDArray]
    covariance: Covariance | None = None
    gls: bool = True
    bridged: Callable[[float], CurveModel] | None = None
    lower: tuple[float, ...] | None = None


#: smallest ``D_r T`` (T the run's duration) at which the projection covariance is simulated
PROJECTION_D_FLOOR = 0.1
#: smallest ``D dt`` relative to the data's scale used in a covariance (a fit may end at 0)
_TINY = 1e-9


def linear_msd_model(k: float, label: str, duration_s: float | None = None) -> CurveModel:
    """``k (D tau + eps^2)``: the MSD of ``k/2`` Brownian degrees of freedom with noise ``eps``.

    With ``duration_s = T`` (the time between the first and last frame), the MSD of the same
    motion after the end-to-end drift ``(r(T) - r(0)) / T`` was subtracted:
    ``k (D tau (1 - tau / T) + eps^2)``. Subtracting the estimated drift turns a Brownian path
    into a Brownian bridge, whose increments are smaller by that factor, exactly, whatever the
    true drift; without the factor a run of 30 frames fitted to lag 3 comes out 10 % low. The
    covariance is that of :func:`holofit.analysis.msd_covariance.msd_covariance` for ``k/2``
    coordinates, with the bridge's common mode when the drift was removed.
    """
    shrink = (lambda tau: 1.0 - tau / duration_s) if duration_s else (lambda tau: 1.0)

    def f(p: NDArray, tau: NDArray) -> NDArray:
        return k * (p[0] * tau * shrink(tau) + p[1])

    def jac(p: NDArray, tau: NDArray) -> NDArray:
        return np.stack([k * tau * shrink(tau), np.full_like(tau, k)], axis=1)

    def covariance(lags: NDArray, masks: Sequence[NDArray], dt: float):
        bridge = round(duration_s / dt) if duration_s else None
        basis = MsdCovarianceBasis(lags, masks, bridge)

        def at(p: NDArray) -> NDArray:
            d = max(p[0], _TINY * max(abs(p[1]), 1e-12) / dt, 0.0)
            return basis.covariance(2.0 * d * dt, max(p[1], 0.0), k / 2.0)

        return at

    def guess(tau: NDArray, m: NDArray) -> NDArray:
        if tau.size >= 2:
            slope, icpt = np.polyfit(tau, m, 1)
            return np.array([slope / k, icpt / k])
        return np.array([m[0] / (k * tau[0]), 0.0])

    if duration_s:
        formula = f"{k:g} D tau (1 - tau/T) + {k:g} eps^2, T = {duration_s:.4g} s"
    else:
        formula = f"{k:g} D tau + {k:g} eps^2"
    return CurveModel(label, ("D", "eps2"), formula, f, jac, guess, covariance, True,
                      lambda t: linear_msd_model(k, label, t))


def orientation_msd_model() -> CurveModel:
    """``2 (1 - exp(-2 D_r tau)) + 2 eps_r^2``: MSD of the unit axis.

    Its covariance is that of two coordinates diffusing with ``D_r`` in the plane tangent to
    the axis, each with noise ``eps_r^2 / 2`` (:mod:`holofit.analysis.msd_covariance`): right
    while the axis turns little within the fit range (``D_r tau << 1``, which the default
    range keeps).
    """

    def covariance(lags: NDArray, masks: Sequence[NDArray], dt: float):
        basis = MsdCovarianceBasis(lags, masks)

        def at(p: NDArray) -> NDArray:
            d = max(p[0], _TINY * max(abs(p[1]), 1e-12) / dt, 0.0)
            return basis.covariance(2.0 * d * dt, max(p[1], 0.0) / 2.0, 2.0)

        return at

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
        "orientation", ("D", "eps2"), "2 (1 - exp(-2 D_r tau)) + 2 eps_r^2", f, jac, guess,
        covariance,
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

    def covariance(lags: NDArray, masks: Sequence[NDArray], dt: float):
        # the simulation has no angular noise: a D_r at 0 would give no scatter at all, so the
        # covariance is taken at D_r T >= 0.1 at least (T the run's duration)
        floor = PROJECTION_D_FLOOR / ((int(lags[0]) + masks[0].size) * dt)
        return lambda p: projection_covariance(max(p[0], floor), dt, lags, masks)

    label = "projection" if n_odd is None else f"projection_l{2 * n_odd - 1}"
    params = ("D", "A") if amplitude else ("D",)
    lower = (0.0, -np.inf) if amplitude else (0.0,)
    return CurveModel(label, params, "A/4 sum_l odd ... exp(-l(l+1) D_r tau)", f, jac, guess,
                      covariance, gls=False, lower=lower)


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
