"""MSDs along and across a turning rod's axis after a lab-frame drift removal: exact means
and the joint fit of ``D_par`` and ``D_perp``.

The observables (:mod:`holofit.analysis.msd`) of a pair ``(t, t + k)`` are
``par = (d . u_t)^2`` and ``perp = |d|^2 - (d . u_t)^2`` with ``u_t`` the axis at the start and
``d = r(t + k) - r(t) - k dt v_hat`` the displacement after the removal of the end-to-end
lab-frame drift ``v_hat = (r_b - r_a) / (M dt)`` (``a``, ``b`` the first and last frame with a
fit, ``M = b - a``). A constant drift ``v`` seen along a turning axis, ``v . u(t)``, is not a
constant, so no body-frame constant could remove it; the lab-frame removal does, exactly:
``v_hat - v`` depends on the Brownian steps only, so ``d`` is a zero-mean Gaussian vector
whatever ``v`` is. What is left is the estimate's own error, which a turning rod sees
differently along and across its axis.

Exact means, given the measured axis path. Step ``j`` (frame ``j`` to ``j + 1``) has the lab
covariance ``C_j = 2 dt (D_perp I + (D_par - D_perp) P_j)`` with ``P_j`` the projector on the
axis during the step (the mean of the projectors at its two ends). With ``B = r_b - r_a`` (all
steps ``a <= j < b``), ``d = sum_{j in [t, t+k)} step_j - (k / M) B`` and

    u^T Cov(d) u = (1 - 2k/M) sum_{j in [t, t+k)} u^T C_j u + (k/M)^2 sum_{a <= j < b} u^T C_j u,

so, averaged over the pairs used,

    E[par(k)]  = 2 [D_par a_k + D_perp (kappa_k - a_k)] + 2 eps_par^2,
    E[perp(k)] = 2 [D_par (kappa_k - a_k) + D_perp (kappa_k + a_k)] + 4 eps_perp^2,

with ``kappa_k = k dt (1 - k/M)`` (the Brownian bridge's factor) and ``a_k`` the pair average
of ``dt [(1 - 2k/M) u_t^T (sum_{[t,t+k)} P_j) u_t + (k/M)^2 u_t^T (sum_{[a,b)} P_j) u_t]``. For
an axis that does not turn ``a_k = kappa_k`` and the models are the separate bridged lines
``2 D_par kappa`` and ``4 D_perp kappa``; a turning axis mixes the two coefficients twice: within
a lag (the axis at ``t`` is not the axis of later steps; ``a_k`` falls below ``kappa_k`` by
about ``2 D_r tau`` of it) and through the drift estimate, whose error is spread over every
orientation of the run (a run that turns a lot loses about ``(D_par + 2 D_perp) / 3`` worth
of each MSD to it, not ``D_par`` along and ``D_perp`` across). Without drift removal
``M -> infinity``.

Fit. The two MSDs are fitted together (generalised least squares, the parameters
``(D_par, D_perp, eps_par^2, eps_perp^2)``): the models are linear in them and share the two
coefficients, so the errors of ``D_par`` and ``D_perp`` are correlated, and derived quantities
(``D_t``, the ratio) take that covariance (:func:`holofit.analysis.linefit.combine`). The lag
covariance of each MSD is the analytic one (:mod:`holofit.analysis.msd_covariance`) with the
effective one-frame step variance of its model; the two MSDs are taken as uncorrelated
(components along and across the axis are independent for a rod that turns little in a lag).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from holofit.analysis.errors import AnalysisError
from holofit.analysis.linefit import (
    GLS_ROUNDS,
    SIDED_ROUNDS,
    CurveModel,
    FitResult,
    JointFit,
    sided_errors,
    sigma_function,
    whitener,
)
from holofit.analysis.msd import LagStatistics, Observables, PairFilter, pair_mask
from holofit.analysis.msd_covariance import MsdCovarianceBasis

__all__ = ["BodyFrameCoefficients", "fit_body_frame"]

#: parameters of the joint fit, in order
JOINT_PARAMS = ("D_par", "D_perp", "eps2_par", "eps2_perp")
#: smallest effective coefficient in a covariance, relative to the noise's (a fit may end at 0)
_TINY = 1e-9


def _step_projectors(axis: NDArray[np.float64], valid: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Projector ``u u^T`` on the axis during each step (N - 1, 3, 3); frames without a usable
    axis take it linearly interpolated between the nearest frames that have one."""
    n = axis.shape[0]
    ok = valid & np.all(np.isfinite(axis), axis=1)
    if not ok.any():
        raise AnalysisError("no frame with an axis for the body-frame MSDs")
    idx = np.flatnonzero(ok)
    proj = np.einsum("ni,nj->nij", axis[idx], axis[idx]).reshape(idx.size, 9)
    frames = np.arange(n)
    full = np.stack([np.interp(frames, idx, proj[:, c]) for c in range(9)], axis=1)
    full = full.reshape(n, 3, 3)
    return 0.5 * (full[:-1] + full[1:])


@dataclass
class BodyFrameCoefficients:
    """The coefficients ``a_k`` and ``kappa_k`` (s) of the module docstring for one run.

    Parameters
    ----------
    axis : ndarray, shape (N, 3)
        The (cleaned) unit axis per frame; rows of frames without one are ignored.
    valid : ndarray of bool, shape (N,)
        Frames used.
    frame_interval_s : float
        Time between frames, s.
    pair_filter : callable, optional
        The rejection of improbable angular jumps (pairs it rejects are not averaged).
    drift_span : tuple of int, optional
        ``(a, b)``: the frames whose positions gave the removed drift (None: no drift removed).
    """

    axis: NDArray[np.float64]
    valid: NDArray[np.bool_]
    frame_interval_s: float
    pair_filter: PairFilter | None = None
    drift_span: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        self._proj = _step_projectors(self.axis, self.valid)
        n = self.axis.shape[0]
        self._cum = np.concatenate([np.zeros((1, 3, 3)), np.cumsum(self._proj, axis=0)])
        self._u = np.where(np.isfinite(self.axis), self.axis, 0.0)
        if self.drift_span is not None:
            a, b = self.drift_span
            self._m = float(b - a)
            total = self._cum[b] - self._cum[a]
            self._whole = np.einsum("ni,ij,nj->n", self._u, total, self._u)
        else:
            self._m = math.inf
            self._whole = np.zeros(n)
        self._cache: dict[int, tuple[float, float]] = {}

    def at_lag(self, k: int) -> tuple[float, float]:
        """``(a_k, kappa_k)`` in seconds for lag ``k`` (frames)."""
        k = int(k)
        if k not in self._cache:
            n = self.axis.shape[0]
            mask = pair_mask(self.valid, k, self.pair_filter)
            t = np.flatnonzero(mask)
            dt = self.frame_interval_s
            r = k / self._m if math.isfinite(self._m) else 0.0
            kappa = k * dt * (1.0 - r)
            if t.size == 0 or k >= n:
                self._cache[k] = (kappa, kappa)
            else:
                window = self._cum[t + k] - self._cum[t]
                inside = np.einsum("ni,nij,nj->n", self._u[t], window, self._u[t])
                w = (1.0 - 2.0 * r) * inside + r * r * self._whole[t]
                self._cache[k] = (float(dt * np.mean(w)), kappa)
        return self._cache[k]

    def arrays(self, lags: NDArray[np.int64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``a_k`` and ``kappa_k`` (s) at integer ``lags``."""
        pairs = [self.at_lag(int(k)) for k in lags]
        return np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])

    def interpolated(self, tau_s: NDArray) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``a`` and ``kappa`` at any lag times (for the figures), interpolated between lags."""
        tau = np.asarray(tau_s, dtype=float)
        n = self.axis.shape[0]
        top = max(2, min(n - 1, math.ceil(float(np.max(tau)) / self.frame_interval_s) + 1))
        grid = np.unique(np.round(np.geomspace(1, top, 60)).astype(np.int64))
        a, kappa = self.arrays(grid)
        x = grid * self.frame_interval_s
        return np.interp(tau, x, a), np.interp(tau, x, kappa)


def design(a: NDArray, kappa: NDArray) -> tuple[NDArray, NDArray]:
    """Rows of the linear models (columns: ``JOINT_PARAMS``) for par and for perp."""
    zero, one = np.zeros_like(a), np.ones_like(a)
    par = np.stack([2 * a, 2 * (kappa - a), 2 * one, zero], axis=1)
    perp = np.stack([2 * (kappa - a), 2 * (kappa + a), zero, 4 * one], axis=1)
    return par, perp


def _view_model(which: int, coeffs: BodyFrameCoefficients, theta: NDArray, label: str
                ) -> CurveModel:
    """A two-parameter ``(D, eps2)`` view of the joint model for one observable (the other
    coefficient held at its fitted value): what the figures and summaries draw."""
    other = theta[1 - which]

    def f(p: NDArray, tau: NDArray) -> NDArray:
        a, kappa = coeffs.interpolated(tau)
        if which == 0:
            return 2 * (p[0] * a + other * (kappa - a)) + 2 * p[1]
        return 2 * (other * (kappa - a) + p[0] * (kappa + a)) + 4 * p[1]

    def jac(p: NDArray, tau: NDArray) -> NDArray:
        a, kappa = coeffs.interpolated(tau)
        if which == 0:
            return np.stack([2 * a, np.full_like(a, 2.0)], axis=1)
        return np.stack([2 * (kappa + a), np.full_like(a, 4.0)], axis=1)

    def guess(tau: NDArray, m: NDArray) -> NDArray:
        return np.array([theta[which], theta[2 + which]])

    span = ("" if coeffs.drift_span is None
            else f", drift removed over M = {int(coeffs._m)} frames")
    formula = (
        "2 [D_par a + D_perp (kappa - a)] + 2 eps^2" if which == 0
        else "2 [D_par (kappa - a) + D_perp (kappa + a)] + 4 eps^2"
    ) + f" (body frame of the measured axis path{span})"
    return CurveModel(label, ("D", "eps2"), formula, f, jac, guess)


def _covariance_factory(lags: NDArray, masks: Sequence[NDArray], a1: float, kappa1: float,
                        dt: float, bridge: int | None) -> Callable[[NDArray], NDArray]:
    """Block-diagonal covariance of the stacked (par, perp) lag averages at parameters
    ``theta``: each block the analytic MSD covariance with its model's effective coefficient
    at the first lag (par: ``(D_par a + D_perp (kappa - a)) / kappa``; perp, per component:
    ``(D_par (kappa - a) + D_perp (kappa + a)) / (2 kappa)``), with the common mode of the
    drift estimate's error over ``bridge`` frames."""
    basis = MsdCovarianceBasis(lags, masks, bridge)
    f = a1 / kappa1 if kappa1 > 0 else 1.0
    n = lags.size

    def at(theta: NDArray) -> NDArray:
        d_par, d_perp, e_par, e_perp = (float(v) for v in theta)
        tiny = _TINY * max(abs(e_par), abs(e_perp), 1e-12) / dt
        eff_par = max(d_par * f + d_perp * (1.0 - f), tiny)
        eff_perp = max(0.5 * (d_par * (1.0 - f) + d_perp * (1.0 + f)), tiny)
        out = np.zeros((2 * n, 2 * n))
        out[:n, :n] = basis.covariance(2.0 * eff_par * dt, max(e_par, 0.0), 1.0)
        out[n:, n:] = basis.covariance(2.0 * eff_perp * dt, max(e_perp, 0.0), 2.0)
        return out

    return at


def fit_body_frame(
    par: LagStatistics, perp: LagStatistics, coeffs: BodyFrameCoefficients, obs: Observables,
    pair_filter: PairFilter | None = None,
) -> tuple[FitResult, FitResult]:
    """Fit the par and perp MSDs together (module docstring); returns their two views.

    Parameters
    ----------
    par, perp : LagStatistics
        The two MSDs at the fit lags (the same lags).
    coeffs : BodyFrameCoefficients
        The run's axis path and drift span.
    obs : Observables
        The run's pairs (their validity gives the pair masks of the covariance).

    Raises
    ------
    AnalysisError
        Fewer than three usable lags.
    """
    good = (np.isfinite(par.mean) & np.isfinite(perp.mean) & np.isfinite(par.sem)
            & np.isfinite(perp.sem) & (par.count >= 2))
    lags = par.lags[good]
    if lags.size < 2:
        raise AnalysisError(f"body-frame fit: {lags.size} usable lag(s) for 4 parameters "
                            "(at least 3 lags)")
    tau = par.tau_s[good]
    dt = float(tau[0] / lags[0])
    m = np.concatenate([par.mean[good], perp.mean[good]])
    sem = np.concatenate([par.sem[good], perp.sem[good]])
    a, kappa = coeffs.arrays(lags)
    x_par, x_perp = design(a, kappa)
    x = np.vstack([x_par, x_perp])
    floor = 1e-12 * max(float(np.max(np.abs(m))), 1e-300)
    w0 = 1.0 / np.maximum(sem, floor)
    theta = np.linalg.lstsq(x * w0[:, None], m * w0, rcond=None)[0]
    naive_cov = np.linalg.pinv((x * w0[:, None]).T @ (x * w0[:, None]))
    masks = [pair_mask(obs.valid, int(k), pair_filter) for k in lags]
    bridge = None if coeffs.drift_span is None else coeffs.drift_span[1] - coeffs.drift_span[0]
    cov_at = _covariance_factory(lags, masks, float(a[0]), float(kappa[0]), dt, bridge)
    for _ in range(GLS_ROUNDS):
        w = whitener(cov_at(theta))
        theta = np.linalg.lstsq(w @ x, w @ m, rcond=None)[0]

    def pcov_at(q: NDArray) -> NDArray:
        wq = whitener(cov_at(q))
        xw = wq @ x
        return np.linalg.pinv(xw.T @ xw)

    cov_m = cov_at(theta)
    w = whitener(cov_m)
    pcov = pcov_at(theta)
    dof = max(m.size - 4, 1)
    chi2 = float(np.sum((w @ (x @ theta - m)) ** 2) / dof)
    joint = JointFit(JOINT_PARAMS, theta.copy(), pcov.copy())
    sigma = np.sqrt(np.clip(np.diag(cov_m), 0, None))
    n = lags.size
    views = []
    for which, st in ((0, par), (1, perp)):
        order = [which, 1 - which, 2 + which, 3 - which]
        perm = np.array(order)
        def permuted(q: NDArray, perm: NDArray = perm) -> NDArray:
            return pcov_at(_unpermute(q, perm))[np.ix_(perm, perm)]

        d_errors = sided_errors(theta[perm], pcov[np.ix_(perm, perm)], permuted,
                                SIDED_ROUNDS[0])
        own = np.array([which, 2 + which])
        sub = pcov[np.ix_(own, own)]
        rows = slice(0, n) if which == 0 else slice(n, 2 * n)
        views.append(FitResult(
            st.name, _view_model(which, coeffs, theta, st.name), theta[own].copy(),
            np.sqrt(np.clip(np.diag(sub), 0, None)),
            np.sqrt(np.clip(np.diag(naive_cov)[own], 0, None)), lags, tau, m[rows].copy(),
            sigma[rows].copy(), chi2, sub.copy(), "gls (joint par/perp, body frame)", True,
            True, d_errors, joint=joint, joint_index=(which, 2 + which),
            sigma_at=sigma_function(theta[perm], pcov[np.ix_(perm, perm)], permuted),
        ))
    return views[0], views[1]


def _unpermute(q: NDArray, perm: NDArray) -> NDArray:
    out = np.empty_like(q)
    out[perm] = q
    return out
