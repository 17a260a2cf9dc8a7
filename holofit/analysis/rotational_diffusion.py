"""Isotropic rotational diffusion of a unit vector: the distribution of the angle it turns.

After a lag ``tau`` a unit vector diffusing on the sphere with coefficient ``D`` (rad^2/s) has
turned by an angle ``theta`` with probability density (Fung & Manoharan, Phys. Rev. E 88,
020302, 2013; the heat kernel on the sphere expanded in Legendre polynomials)

    p(theta) = sum_l (2l + 1)/2 P_l(cos theta) exp(-l(l+1) D tau) sin theta,

and its tail (the probability of turning by ``theta`` or more) follows by integrating term by
term with ``int P_l = (P_{l+1} - P_{l-1}) / (2l + 1)``:

    P(Theta >= theta) = (1 + cos theta)/2
                        + sum_{l>=1} exp(-l(l+1) D tau) (P_{l+1}(cos theta) - P_{l-1}(cos theta))/2.

The series needs ``l`` up to about ``sqrt(46 / (D tau))`` for a truncation below 1e-20; for
``D tau < 1e-7`` (thousands of terms) we use the planar limit ``exp(-theta^2 / (4 D tau))``,
whose relative error is of order ``D tau``. Only the product ``x = D tau`` matters; localisation
noise with an rms angular error ``eps`` per frame acts, to first order, like an extra
``x += eps^2 / 2`` for the angle between two frames.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["angle_pdf", "angle_tail", "angle_threshold", "n_terms"]

#: below this ``D tau`` the planar (Rayleigh) limit replaces the Legendre series
PLANAR_LIMIT = 1e-7


def n_terms(x: float) -> int:
    """Number of Legendre terms for ``exp(-l(l+1) x) < 1e-20`` beyond the last."""
    return math.ceil(math.sqrt(46.0 / max(x, PLANAR_LIMIT))) + 4


@numba.njit(cache=True)
def _tail(c: float, x: float, lmax: int) -> float:
    # Legendre recurrence for P_{l-1}, P_l, P_{l+1} at c; accumulates the tail series.
    p_prev = 1.0  # P_0
    p_cur = c  # P_1
    total = 0.5 * (1.0 + c)
    for l in range(1, lmax + 1):
        p_next = ((2 * l + 1) * c * p_cur - l * p_prev) / (l + 1)
        total += math.exp(-l * (l + 1) * x) * 0.5 * (p_next - p_prev)
        p_prev = p_cur
        p_cur = p_next
    return total


@numba.njit(cache=True)
def _pdf(c: float, s: float, x: float, lmax: int) -> float:
    p_prev = 1.0
    p_cur = c
    total = 0.5
    for l in range(1, lmax + 1):
        total += (2 * l + 1) * 0.5 * p_cur * math.exp(-l * (l + 1) * x)
        p_next = ((2 * l + 1) * c * p_cur - l * p_prev) / (l + 1)
        p_prev = p_cur
        p_cur = p_next
    return total * s


@numba.njit(cache=True)
def _tail_array(theta: np.ndarray, x: float, lmax: int) -> np.ndarray:
    out = np.empty(theta.size)
    for i in range(theta.size):
        out[i] = _tail(math.cos(theta[i]), x, lmax)
    return out


@numba.njit(cache=True)
def _threshold(x: float, p: float, lmax: int) -> float:
    # bisection on the monotonically decreasing tail
    lo = 0.0
    hi = math.pi
    if _tail(-1.0 + 1e-300, x, lmax) >= p:
        return math.pi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _tail(math.cos(mid), x, lmax) > p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def angle_pdf(theta: ArrayLike, d_tau: float) -> NDArray[np.float64]:
    """Probability density of the turning angle ``theta`` (rad) after ``D tau = d_tau``."""
    th = np.asarray(theta, dtype=float)
    if d_tau < PLANAR_LIMIT:
        return th / (2 * d_tau) * np.exp(-(th**2) / (4 * d_tau))
    lmax = n_terms(d_tau)
    flat = th.ravel()
    out = np.array([_pdf(math.cos(t), math.sin(t), d_tau, lmax) for t in flat])
    return out.reshape(th.shape)


def angle_tail(theta: ArrayLike, d_tau: float) -> NDArray[np.float64]:
    """Probability that the axis turns by ``theta`` (rad) or more after ``D tau = d_tau``."""
    th = np.asarray(theta, dtype=float)
    if d_tau < PLANAR_LIMIT:
        return np.exp(-(th**2) / (4 * d_tau))
    out = _tail_array(np.ascontiguousarray(th.ravel()), float(d_tau), n_terms(d_tau))
    return np.clip(out, 0.0, 1.0).reshape(th.shape)


def angle_threshold(d_tau: float, probability: float) -> float:
    """Angle (rad) beyond which turning has tail probability ``probability``.

    Returns ``pi`` when even a half turn is more probable than ``probability`` (long lags).
    """
    if not 0 < probability < 1:
        raise ValueError(f"probability must lie in (0, 1), got {probability}")
    if d_tau <= 0:
        return 0.0
    if d_tau < PLANAR_LIMIT:
        return min(math.sqrt(-4.0 * d_tau * math.log(probability)), math.pi)
    return float(_threshold(float(d_tau), float(probability), n_terms(d_tau)))
