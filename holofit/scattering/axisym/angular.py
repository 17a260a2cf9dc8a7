"""Exact angular integrals of a piecewise-constant ``eps(theta)`` against spherical harmonics.

For one azimuthal order ``m >= 0`` and orders ``n, l = max(1, m) .. L`` (fully normalised
Legendre functions ``Pbar``, :mod:`holofit.scattering.legendre`), with ``x = cos(theta)``
and the intervals ``[x_lo, x_hi]`` of relative permittivity ``eps_i`` (the medium elsewhere):

    Y[n, l]  = 2 pi sum_i (eps_i - 1) int Pbar_n Pbar_l dx,
    P[n, l]  = 2 pi sum_i (eps_i - 1) int (dPbar_n dPbar_l + m^2 Pbar_n Pbar_l / sin^2) dx,
    C[n, l]  = 2 pi sum_i (eps_i - 1) int m (dPbar_n Pbar_l + Pbar_n dPbar_l) / sin dx,

(``dPbar = dPbar/dtheta``): the deviations from the medium of ``<Y_n, eps Y_l>``,
``<Psi_n, eps Psi_l>`` (equal to ``<Phi_n, eps Phi_l>``) and ``-i <Psi_n, eps Phi_l>`` for the
vector spherical harmonics of :mod:`holofit.scattering.vsw` (:class:`AngularMatrices` keeps
``Y``, the two diagonal blocks and the two couplings; with the inverse rule for the polar
field the diagonal blocks differ, see :func:`angular_matrices`). Every integrand is a polynomial in
``x`` of degree ``n + l <= 2 L``, so ``L + 1`` Gauss-Legendre nodes on each interval integrate it
exactly: the discontinuities of ``eps`` cost no accuracy because the intervals end at them.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from holofit.scattering.legendre import legendre_tables

__all__ = ["AngularMatrices", "angular_matrices", "full_partition", "gauss_nodes",
           "interval_nodes"]


@lru_cache(maxsize=64)
def gauss_nodes(count: int) -> tuple[NDArray, NDArray]:
    """Gauss-Legendre nodes and weights on [-1, 1]."""
    x, w = np.polynomial.legendre.leggauss(count)
    x.setflags(write=False)
    w.setflags(write=False)
    return x, w


def interval_nodes(intervals: list[tuple[float, float, complex]], count: int
                   ) -> tuple[NDArray, NDArray]:
    """Nodes ``x`` and weights ``w (eps_i - 1)`` of ``count``-point Gauss-Legendre rules on each
    interval (empty intervals dropped)."""
    gx, gw = gauss_nodes(count)
    xs, ws = [], []
    for lo, hi, eps in intervals:
        if hi <= lo:
            continue
        half = 0.5 * (hi - lo)
        xs.append(0.5 * (hi + lo) + half * gx)
        ws.append(half * gw * (complex(eps) - 1.0))
    if not xs:
        return np.zeros(0), np.zeros(0, dtype=complex)
    return np.concatenate(xs), np.concatenate(ws)


class AngularMatrices:
    """The angular matrices of one shell for every ``m = 0 .. L``, as deviations from the
    medium, ``[m, i, j]`` with ``i, j`` indexing ``n = max(1, m) + i`` (zero past ``L``).

    Attributes
    ----------
    yy : ndarray (L + 1, L, L)
        ``Y``: ``<Y_n, eps Y_l> - delta``.
    psipsi, phiphi : ndarray (L + 1, L, L)
        ``<Psi_n, eps Psi_l> - nu^2 delta`` and the same for ``Phi``.
    psiphi, phipsi : ndarray (L + 1, L, L)
        ``<Psi_n, eps Phi_l>`` and ``<Phi_n, eps Psi_l>``.
    """

    def __init__(self, yy: NDArray, psipsi: NDArray, phiphi: NDArray, psiphi: NDArray,
                 phipsi: NDArray) -> None:
        self.yy, self.psipsi, self.phiphi = yy, psipsi, phiphi
        self.psiphi, self.phipsi = psiphi, phipsi


def _block_tables(mu: NDArray, order: int) -> tuple[NDArray, NDArray, NDArray]:
    """Tables ``[m, node, i]`` of ``Pbar``, ``dPbar/dtheta`` and ``m Pbar/sin`` for ``n =
    max(1, m) + i`` (zero past ``L``)."""
    L = order
    pb, dp, mp = legendre_tables(np.ascontiguousarray(mu, dtype=float), L)
    npts = mu.size
    tp = np.zeros((L + 1, npts, L))
    td = np.zeros((L + 1, npts, L))
    tm = np.zeros((L + 1, npts, L))
    for m in range(L + 1):
        n0 = max(1, m)
        cnt = L - n0 + 1
        tp[m, :, :cnt] = pb[:, n0:, m]
        td[m, :, :cnt] = dp[:, n0:, m]
        tm[m, :, :cnt] = mp[:, n0:, m]  # m Pbar / sin
    return tp, td, tm


def _gram(a: NDArray, w: NDArray, b: NDArray) -> NDArray:
    """``[m] a^T diag(2 pi w) b`` for tables ``[m, node, i]``."""
    return np.matmul((a * (2.0 * np.pi * w)[None, :, None]).transpose(0, 2, 1), b)


def full_partition(intervals: list[tuple[float, float, complex]]
                   ) -> list[tuple[float, float, complex]]:
    """``intervals`` completed by the medium (``eps = 1``) to a partition of [-1, 1]."""
    out = []
    x = -1.0
    for lo, hi, e in sorted(intervals, key=lambda v: v[0]):
        if hi <= lo:
            continue
        if lo > x:
            out.append((x, lo, 1.0 + 0j))
        out.append((lo, hi, complex(e)))
        x = hi
    if x < 1.0:
        out.append((x, 1.0, 1.0 + 0j))
    return out


#: relative eigenvalue below which a direction of the polar-field space is dropped (inverse rule)
GRAM_CUTOFF = 1e-10


def angular_matrices(intervals: list[tuple[float, float, complex]], order: int,
                     polar_rule: str = "laurent") -> AngularMatrices:
    """The angular matrices (module docstring) of ``intervals`` up to order ``L``.

    ``polar_rule = "inverse"`` forms the polar component's product with ``eps`` by the inverse
    rule (Li 1996, J. Opt. Soc. Am. A 13, 1870): where the interfaces are cones ``theta =
    const`` (a Janus cap's rim plane), ``E_theta`` is normal to them and jumps while
    ``eps E_theta`` is continuous, so ``[[eps E_theta]] = [[1/eps]]^-1 [[E_theta]]`` in the
    space spanned by the polar parts ``dPbar_n``, ``m Pbar_n / sin`` of the tangential waves
    (orthonormalised, directions with Gram eigenvalues below :data:`GRAM_CUTOFF` dropped);
    ``E_phi`` keeps the direct (Laurent) product.
    """
    L = order
    x, w = interval_nodes(intervals, L + 1)
    if x.size == 0:
        z = np.zeros((L + 1, L, L), dtype=complex)
        return AngularMatrices(z, z.copy(), z.copy(), z.copy(), z.copy())
    tp, td, tm = _block_tables(x, L)
    yy = _gram(tp, w, tp)
    dd = _gram(td, w, td)
    mm = _gram(tm, w, tm)
    dm = _gram(td, w, tm)
    md = dm.transpose(0, 2, 1)
    if polar_rule != "inverse":
        return AngularMatrices(yy, dd + mm, dd + mm, -1j * (dm + md), 1j * (dm + md))
    # the polar part by the inverse rule, on the full sphere
    part = full_partition(intervals)
    xf, wf = interval_nodes([(lo, hi, 2.0 + 0j) for lo, hi, _ in part], L + 1)  # weights w
    ef = np.concatenate([np.full(_count(lo, hi, L + 1), complex(e)) for lo, hi, e in part])
    _, fd, fm = _block_tables(xf, L)
    a_dd = np.zeros_like(dd)
    a_dm = np.zeros_like(dd)
    a_mm = np.zeros_like(dd)
    for m in range(L + 1):
        cnt = L - max(1, m) + 1
        g = np.concatenate([fd[m, :, :cnt], fm[m, :, :cnt]], axis=1) if m else fd[m, :, :cnt]
        wt = 2.0 * np.pi * wf.real
        gram = (g * wt[:, None]).T @ g
        inv_eps = (g * (wt / ef)[:, None]).T @ g
        s, u = np.linalg.eigh(gram)
        keep = s > GRAM_CUTOFF * s.max()
        uk, sk = u[:, keep], np.sqrt(s[keep])
        h = (uk / sk).T @ inv_eps @ (uk / sk)
        full = (uk * sk) @ np.linalg.solve(h, (uk * sk).T)
        # deviation from the medium: the medium's own product is the Gram matrix
        dev = full - gram
        a_dd[m, :cnt, :cnt] = dev[:cnt, :cnt]
        if m:
            a_dm[m, :cnt, :cnt] = dev[:cnt, cnt:]
            a_mm[m, :cnt, :cnt] = dev[cnt:, cnt:]
    a_md = a_dm.transpose(0, 2, 1)
    return AngularMatrices(yy, a_dd + mm, a_mm + dd, -1j * (a_dm + md), 1j * (a_md + dm))


def _count(lo: float, hi: float, count: int) -> int:
    return count if hi > lo else 0
