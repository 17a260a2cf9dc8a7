"""Autocorrelation of the projected orientation of an isotropically rotating particle.

For ``p = (cos psi, sin psi)``, the unit projection of the axis on the lab x-y plane, the paper's
appendix derives (uniform initial orientations)

    <p(t) . p(t + tau)> = 1/4 sum_{l odd} (2l+1)/(l(l+1)) (S_l^1)^2 exp(-l(l+1) D_r tau),

with ``S_l^1 = int_{-1}^{1} P_l^1(x) dx`` (zero for even ``l``), ``S_1^1 = -pi/2`` (Condon-Shortley
phase; only the square enters) and ``S_{l+2}^1 = l(l+2)/((l+1)(l+3)) S_l^1``. The sum is 1 at
``tau = 0``; its terms fall as ``2/l^3``, so at ``tau = 0`` the truncation after ``l = L`` is about
``1/(2 L^2)``. For ``tau > 0`` we keep the terms with ``l(l+1) D_r tau < 40``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "projection_coefficients",
    "projection_correlation",
    "projection_correlation_derivative",
    "s_l1",
]

#: most odd terms ever summed (truncation at tau = 0 about 1e-9)
MAX_TERMS = 12_000


def s_l1(n_odd: int) -> NDArray[np.float64]:
    """``S_l^1`` for the first ``n_odd`` odd ``l`` (1, 3, 5, ...), by the recursion."""
    s = np.empty(n_odd)
    s[0] = -math.pi / 2
    for i in range(1, n_odd):
        l = 2 * i - 1
        s[i] = s[i - 1] * l * (l + 2) / ((l + 1) * (l + 3))
    return s


_L = 2 * np.arange(MAX_TERMS) + 1
_COEF = 0.25 * (2 * _L + 1) / (_L * (_L + 1.0)) * s_l1(MAX_TERMS) ** 2
_EIG = _L * (_L + 1.0)


def projection_coefficients(n_odd: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Odd ``l`` and the weights ``(2l+1)/(4 l(l+1)) (S_l^1)^2`` of the first ``n_odd`` terms."""
    n_odd = min(n_odd, MAX_TERMS)
    return _L[:n_odd].copy(), _COEF[:n_odd].copy()


def _terms_for(x_min: float) -> int:
    if x_min <= 0:
        return MAX_TERMS
    lmax = math.sqrt(40.0 / x_min)
    return min(MAX_TERMS, int(lmax / 2) + 2)


def projection_correlation(
    d_r: float, tau: ArrayLike, n_odd: int | None = None
) -> NDArray[np.float64]:
    """``<p(t) . p(t + tau)>`` for rotational diffusion coefficient ``d_r`` (1/s), lags ``tau`` (s).

    Parameters
    ----------
    n_odd : int, optional
        Number of odd terms to keep (``1`` gives the single exponential ``l = 1``); by default
        enough for the smallest lag.
    """
    t = np.asarray(tau, dtype=float)
    x = d_r * t
    k = n_odd if n_odd is not None else _terms_for(float(np.min(x)) if x.size else 1.0)
    k = min(k, MAX_TERMS)
    out = np.exp(-np.multiply.outer(x.ravel(), _EIG[:k])) @ _COEF[:k]
    return out.reshape(t.shape)


def projection_correlation_derivative(
    d_r: float, tau: ArrayLike, n_odd: int | None = None
) -> NDArray[np.float64]:
    """Derivative of :func:`projection_correlation` with respect to ``d_r`` (s)."""
    t = np.asarray(tau, dtype=float)
    x = d_r * t
    k = n_odd if n_odd is not None else _terms_for(float(np.min(x)) if x.size else 1.0)
    k = min(k, MAX_TERMS)
    e = np.exp(-np.multiply.outer(x.ravel(), _EIG[:k]))
    out = -(e * _EIG[:k]) @ _COEF[:k] * t.ravel()
    return out.reshape(t.shape)
