"""Fully normalised associated Legendre functions and the derivatives a vector-spherical-wave
expansion needs, stable at the poles (numba).

With the Condon-Shortley phase, ``Y_nm = Pbar_n^m(cos th) exp(i m phi)`` with
``Pbar_n^m = sqrt((2n+1)/(4 pi) (n-m)!/(n+m)!) P_n^m`` (orthonormal on the sphere). For
``m >= 1`` the recurrences run on ``u_n^m = Pbar_n^m / sin(th)``, which stays finite at the
poles, and give

    dPbar_n^m/dth = n cos(th) u_n^m - c_nm u_{n-1}^m,  c_nm = sqrt((n^2 - m^2)(2n+1)/(2n-1)),
    dPbar_n^0/dth = sqrt(n (n+1)) Pbar_n^1.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def legendre_tables(mu, lmax):  # pragma: no cover - compiled
    """Tables at each ``mu = cos(theta)`` (theta in [0, pi]) for 0 <= m <= n <= lmax.

    Returns
    -------
    pbar : (npts, lmax+1, lmax+1)   Pbar_n^m   (index [p, n, m])
    dpbar : (npts, lmax+1, lmax+1)  dPbar_n^m / dtheta
    mpbar : (npts, lmax+1, lmax+1)  m Pbar_n^m / sin(theta)
    """
    npts = mu.shape[0]
    L = lmax
    pbar = np.zeros((npts, L + 1, L + 1))
    dpbar = np.zeros((npts, L + 1, L + 1))
    mpbar = np.zeros((npts, L + 1, L + 1))
    u = np.zeros((L + 1, L + 1))
    for p in range(npts):
        x = mu[p]
        s = np.sqrt(max(0.0, 1.0 - x * x))
        # m = 0: standard recurrence for Pbar_n^0
        p0 = np.sqrt(1.0 / (4.0 * np.pi))
        pbar[p, 0, 0] = p0
        if L >= 1:
            pbar[p, 1, 0] = np.sqrt(3.0) * x * p0
        for n in range(2, L + 1):
            a = np.sqrt((4.0 * n * n - 1.0) / (n * n))
            b = np.sqrt(((n - 1.0) ** 2) * (2.0 * n + 1.0) / (n * n * (2.0 * n - 3.0)))
            pbar[p, n, 0] = a * x * pbar[p, n - 1, 0] - b * pbar[p, n - 2, 0]
        # m >= 1: u_n^m = Pbar_n^m / sin
        if L >= 1:
            # sectoral: Pbar_m^m = -sqrt((2m+1)/(2m)) s Pbar_{m-1}^{m-1}
            # so u_1^1 = -sqrt(3/2) Pbar_0^0 and u_m^m = -sqrt((2m+1)/(2m)) s u_{m-1}^{m-1}
            u[1, 1] = -np.sqrt(1.5) * p0
            for m in range(2, L + 1):
                u[m, m] = -np.sqrt((2.0 * m + 1.0) / (2.0 * m)) * s * u[m - 1, m - 1]
            for m in range(1, L + 1):
                if m + 1 <= L:
                    u[m + 1, m] = np.sqrt(2.0 * m + 3.0) * x * u[m, m]
                for n in range(m + 2, L + 1):
                    a = np.sqrt((4.0 * n * n - 1.0) / (n * n - m * m))
                    b = np.sqrt(((n - 1.0) ** 2 - m * m) * (2.0 * n + 1.0)
                                / ((n * n - m * m) * (2.0 * n - 3.0)))
                    u[n, m] = a * x * u[n - 1, m] - b * u[n - 2, m]
            for m in range(1, L + 1):
                for n in range(m, L + 1):
                    pbar[p, n, m] = s * u[n, m]
                    mpbar[p, n, m] = m * u[n, m]
                    c = np.sqrt((n * n - m * m) * (2.0 * n + 1.0) / (2.0 * n - 1.0))
                    prev = u[n - 1, m] if n - 1 >= m else 0.0
                    dpbar[p, n, m] = n * x * u[n, m] - c * prev
        for n in range(1, L + 1):
            dpbar[p, n, 0] = np.sqrt(n * (n + 1.0)) * pbar[p, n, 1]
    return pbar, dpbar, mpbar
