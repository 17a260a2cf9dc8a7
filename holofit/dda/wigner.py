"""Wigner rotation matrices for rotating multipole expansions.

``D^n_{m m'}(R) = exp(-i m alpha) d^n_{m m'}(beta) exp(-i m' gamma)`` for the active rotation
``R = Rz(alpha) Ry(beta) Rz(gamma)`` (Condon-Shortley phase, ``d^n(beta) = exp(-i beta J_y)``
in the ``|n m>`` basis). If a field has expansion coefficients ``c'_{nm'}`` in a rotated
(particle) frame, its coefficients in the lab frame are ``c_{nm} = sum_m' D^n_{mm'} c'_{nm'}``.
The small-d matrices come from the eigen-decomposition of ``J_y`` (exact unitary, stable for
every n).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from holofit.conventions import euler_zyz_from_matrix

__all__ = ["rotate_coefficients", "wigner_small_d"]


@lru_cache(maxsize=128)
def _jy_eigen(n: int) -> tuple[NDArray[np.float64], NDArray[np.complex128]]:
    m = np.arange(-n, n)
    raise_ = np.zeros((2 * n + 1, 2 * n + 1))
    raise_[m + n + 1, m + n] = np.sqrt(n * (n + 1) - m * (m + 1))
    jy = (raise_ - raise_.T) / 2j
    w, v = np.linalg.eigh(jy)
    return w, v


def wigner_small_d(n: int, beta: float) -> NDArray[np.float64]:
    """``d^n_{m m'}(beta)``, shape (2n+1, 2n+1), index ``[m + n, m' + n]``."""
    w, v = _jy_eigen(n)
    return ((v * np.exp(-1j * beta * w)) @ v.conj().T).real


def rotate_coefficients(
    coeffs: NDArray[np.complex128], rot: NDArray[np.float64]
) -> NDArray[np.complex128]:
    """Lab-frame coefficients ``[n, m + L]`` from particle-frame ones, ``rot``: particle -> lab."""
    alpha, beta, gamma = (float(v) for v in euler_zyz_from_matrix(rot))
    L = coeffs.shape[0] - 1
    out = np.zeros_like(coeffs)
    for n in range(1, L + 1):
        m = np.arange(-n, n + 1)
        d = wigner_small_d(n, beta)
        big_d = np.exp(-1j * m * alpha)[:, None] * d * np.exp(-1j * m * gamma)[None, :]
        out[n, L - n : L + n + 1] = big_d @ coeffs[n, L - n : L + n + 1]
    return out
