"""Wigner rotation matrices for rotating multipole expansions.

``D^n_{m m'}(R) = exp(-i m alpha) d^n_{m m'}(beta) exp(-i m' gamma)`` for the active rotation
``R = Rz(alpha) Ry(beta) Rz(gamma)`` (Condon-Shortley phase, ``d^n(beta) = exp(-i beta J_y)``
in the ``|n m>`` basis). If a field has expansion coefficients ``c'_{nm'}`` in a rotated
(particle) frame, its coefficients in the lab frame are ``c_{nm} = sum_m' D^n_{mm'} c'_{nm'}``.
The small-d matrices come from the eigen-decomposition of ``J_y`` (exact unitary, stable for
every n), and so do their exact derivatives ``d'(beta) = -i J_y d(beta)``.

For many rotations of one expansion (a T-matrix seen at every orientation),
:func:`wigner_d_all` gives all orders at once in one compiled pass: the three-term recurrence
in ``n`` of ``d^n_{m m'}`` at fixed ``(m, m')`` (a Jacobi-polynomial recurrence, stable
upward),

    n sqrt((n+1)^2 - m^2) sqrt((n+1)^2 - m'^2) d^{n+1}
        = (2n+1) (n(n+1) cos b - m m') d^n - (n+1) sqrt(n^2 - m^2) sqrt(n^2 - m'^2) d^{n-1},

started at ``n = max(|m|, |m'|)`` from the one-term closed form, and the derivative from the
ladder form of ``-i J_y``.

Improper operations (mirror planes of a dipole lattice) act on the fields of polar vectors:
``S = -R`` with ``R`` proper is the inversion times ``R``, and the inversion multiplies
N-type coefficients (electric multipoles) by ``(-1)^n`` and M-type ones by ``(-1)^(n+1)``
(:func:`operation_blocks`).
"""

from __future__ import annotations

from functools import lru_cache
from math import lgamma
from typing import Literal, overload

import numba
import numpy as np
from numpy.typing import NDArray

from holofit.conventions import euler_zyz_from_matrix

__all__ = [
    "EULER_ANGLES",
    "apply_blocks",
    "operation_blocks",
    "rotate_coefficients",
    "rotation_blocks",
    "wigner_d_all",
    "wigner_small_d",
]

#: names of the zyz Euler angles in :class:`holofit.scattering.theory.Orientation` order
EULER_ANGLES = ("psi", "theta", "phi")


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


@lru_cache(maxsize=16)
def _recurrence_tables(lmax: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``sqrt(n^2 - a^2)`` at ``[n, |a|]`` (n <= L + 1) and ``sqrt(C(2j, j + x))`` at
    ``[j, x + L]``."""
    n = np.arange(lmax + 2)[:, None]
    a = np.arange(lmax + 2)[None, :]
    sq = np.sqrt(np.clip(n * n - a * a, 0, None).astype(float))
    sb = np.zeros((lmax + 1, 2 * lmax + 1))
    for j in range(lmax + 1):
        for x in range(-j, j + 1):
            sb[j, x + lmax] = np.exp(0.5 * (lgamma(2 * j + 1.0) - lgamma(j + x + 1.0)
                                            - lgamma(j - x + 1.0)))
    return sq, sb


@numba.njit(cache=True, nogil=True)
def _wigner_kernel(psi, beta, phi, lmax, sq, sb, want_derivatives, big, d_psi, d_beta,
                   d_phi):  # pragma: no cover - compiled
    """Fill ``D^n_{ab}`` (and its Euler derivatives) at ``[n, a + L, b + L]``, 1 <= n <= L."""
    L = lmax
    cb = np.cos(beta)
    c2 = np.cos(beta / 2.0)
    s2 = np.sin(beta / 2.0)
    pc = np.ones(2 * L + 1)
    ps = np.ones(2 * L + 1)
    for k in range(1, 2 * L + 1):
        pc[k] = pc[k - 1] * c2
        ps[k] = ps[k - 1] * s2
    d = np.zeros((L + 1, 2 * L + 1, 2 * L + 1))
    for a in range(-L, L + 1):
        aa = abs(a)
        for b in range(-L, L + 1):
            bb = abs(b)
            j = max(aa, bb)
            # one-term closed form at n = max(|a|, |b|) (a: row m, b: column m')
            if j == a:
                val = sb[j, b + L] * pc[j + b] * ps[j - b] * (1.0 if (j - b) % 2 == 0 else -1.0)
            elif j == -a:
                val = sb[j, b + L] * pc[j - b] * ps[j + b]
            elif j == b:
                val = sb[j, a + L] * pc[j + a] * ps[j - a]
            else:
                val = sb[j, a + L] * pc[j - a] * ps[j + a] * (1.0 if (j + a) % 2 == 0 else -1.0)
            d[j, a + L, b + L] = val
            if j == 0:
                if L >= 1:
                    d[1, L, L] = cb
                prev = 1.0
                cur = cb
                start = 1
            else:
                prev = 0.0
                cur = val
                start = j
            for n in range(start, L):
                lhs = n * sq[n + 1, aa] * sq[n + 1, bb]
                nxt = ((2.0 * n + 1.0) * (n * (n + 1.0) * cb - a * b) * cur
                       - (n + 1.0) * sq[n, aa] * sq[n, bb] * prev) / lhs
                d[n + 1, a + L, b + L] = nxt
                prev = cur
                cur = nxt
    e_psi = np.empty(2 * L + 1, dtype=np.complex128)
    e_phi = np.empty(2 * L + 1, dtype=np.complex128)
    for a in range(-L, L + 1):
        e_psi[a + L] = np.exp(-1j * a * psi)
        e_phi[a + L] = np.exp(-1j * a * phi)
    for n in range(1, L + 1):
        nn = n * (n + 1.0)
        for a in range(-n, n + 1):
            ea = e_psi[a + L]
            up = np.sqrt(nn - a * (a - 1.0))  # (J+)_{a, a-1}
            down = np.sqrt(nn - a * (a + 1.0))  # (J-)_{a, a+1}
            for b in range(-n, n + 1):
                eb = e_phi[b + L]
                val = ea * d[n, a + L, b + L] * eb
                big[n, a + L, b + L] = val
                if want_derivatives:
                    # d'(beta) = -i J_y d = -(J+ d - J- d) / 2
                    dd = 0.0
                    if a > -n:
                        dd -= 0.5 * up * d[n, a - 1 + L, b + L]
                    if a < n:
                        dd += 0.5 * down * d[n, a + 1 + L, b + L]
                    d_beta[n, a + L, b + L] = ea * dd * eb
                    d_psi[n, a + L, b + L] = -1j * a * val
                    d_phi[n, a + L, b + L] = -1j * b * val


@overload
def wigner_d_all(
    order: int, psi: float, theta: float, phi: float, derivatives: Literal[False] = False
) -> NDArray[np.complex128]: ...
@overload
def wigner_d_all(
    order: int, psi: float, theta: float, phi: float, derivatives: Literal[True]
) -> tuple[NDArray[np.complex128], tuple[NDArray, NDArray, NDArray]]: ...
@overload
def wigner_d_all(
    order: int, psi: float, theta: float, phi: float, derivatives: bool = False
) -> NDArray[np.complex128] | tuple[NDArray[np.complex128], tuple[NDArray, NDArray, NDArray]]: ...
def wigner_d_all(
    order: int, psi: float, theta: float, phi: float, derivatives: bool = False
) -> NDArray[np.complex128] | tuple[NDArray[np.complex128], tuple[NDArray, NDArray, NDArray]]:
    """``D^n_{m m'}`` of ``R = Rz(psi) Ry(theta) Rz(phi)`` for every ``1 <= n <= L`` at once.

    Returns an array ``[n, m + L, m' + L]`` (zero for n = 0 and where ``|m|`` or ``|m'|``
    exceeds n); with ``derivatives``, also ``(dD/dpsi, dD/dtheta, dD/dphi)`` in the same
    layout.
    """
    L = int(order)
    sq, sb = _recurrence_tables(L)
    shape = (L + 1, 2 * L + 1, 2 * L + 1)
    big = np.zeros(shape, dtype=complex)
    if derivatives:
        d_psi, d_theta, d_phi = (np.zeros(shape, dtype=complex) for _ in range(3))
    else:
        d_psi = d_theta = d_phi = np.zeros((1, 1, 1), dtype=complex)
    _wigner_kernel(float(psi), float(theta), float(phi), L, sq, sb, derivatives, big, d_psi,
                   d_theta, d_phi)
    if not derivatives:
        return big
    return big, (d_psi, d_theta, d_phi)


def _small_d_and_derivative(n: int, beta: float) -> tuple[NDArray, NDArray]:
    w, v = _jy_eigen(n)
    e = np.exp(-1j * beta * w)
    vh = v.conj().T
    return ((v * e) @ vh).real, ((v * (-1j * w * e)) @ vh).real


@overload
def rotation_blocks(
    order: int, psi: float, theta: float, phi: float, derivatives: Literal[False] = False
) -> list[NDArray[np.complex128]]: ...
@overload
def rotation_blocks(
    order: int, psi: float, theta: float, phi: float, derivatives: Literal[True]
) -> tuple[list[NDArray], list[tuple[NDArray, NDArray, NDArray]]]: ...
@overload
def rotation_blocks(
    order: int, psi: float, theta: float, phi: float, derivatives: bool = False
) -> (list[NDArray[np.complex128]]
      | tuple[list[NDArray], list[tuple[NDArray, NDArray, NDArray]]]): ...
def rotation_blocks(
    order: int, psi: float, theta: float, phi: float, derivatives: bool = False
) -> list[NDArray[np.complex128]] | tuple[list[NDArray], list[tuple[NDArray, NDArray, NDArray]]]:
    """``D^n(R)`` for ``n = 1..L`` and ``R = Rz(psi) Ry(theta) Rz(phi)`` (list index n - 1).

    With ``derivatives``, also ``(dD/dpsi, dD/dtheta, dD/dphi)`` for each n (exact).
    """
    blocks, derivs = [], []
    for n in range(1, order + 1):
        m = np.arange(-n, n + 1)
        left = np.exp(-1j * m * psi)[:, None]
        right = np.exp(-1j * m * phi)[None, :]
        if derivatives:
            d, dd = _small_d_and_derivative(n, theta)
            big = left * d * right
            derivs.append((-1j * m[:, None] * big, left * dd * right, big * (-1j * m[None, :])))
        else:
            big = left * wigner_small_d(n, theta) * right
        blocks.append(big)
    return (blocks, derivs) if derivatives else blocks


def operation_blocks(op: NDArray, order: int
                     ) -> tuple[list[NDArray[np.complex128]], NDArray, NDArray]:
    """Representation of an orthogonal 3x3 operation (rotation or rotation-reflection) on
    coefficient vectors: ``D^n`` of its proper part for n = 1..L and the signs of the N- and
    M-type blocks (each of length L), so that the field ``S E(S^T r)`` has coefficients
    ``sign_N[n-1] D^n a_n`` and ``sign_M[n-1] D^n b_n``."""
    op = np.asarray(op, dtype=float)
    det = float(np.linalg.det(op))
    proper = op if det > 0 else -op
    psi, theta, phi = (float(v) for v in euler_zyz_from_matrix(proper))
    blocks = rotation_blocks(order, psi, theta, phi)
    n = np.arange(1, order + 1)
    if det > 0:
        return blocks, np.ones(order), np.ones(order)
    return blocks, (-1.0) ** n, (-1.0) ** (n + 1)


def apply_blocks(
    blocks: list[NDArray], vecs: NDArray[np.complex128], order: int,
    sign_n: NDArray | None = None, sign_m: NDArray | None = None, adjoint: bool = False,
) -> NDArray[np.complex128]:
    """Apply a block-diagonal representation (per-n blocks, same for N and M types, optional
    per-n signs) to flat coefficient vectors (:mod:`holofit.scattering.vsw` layout), along
    their first axis; ``adjoint`` applies its conjugate transpose."""
    vecs = np.asarray(vecs)
    out = np.empty(vecs.shape, dtype=complex)
    half = order * (order + 2)
    for kind, signs in ((0, sign_n), (1, sign_m)):
        for n in range(1, order + 1):
            lo = kind * half + n * n - 1
            sl = slice(lo, lo + 2 * n + 1)
            b = blocks[n - 1].conj().T if adjoint else blocks[n - 1]
            s = 1.0 if signs is None else float(signs[n - 1])
            out[sl] = s * (b @ vecs[sl])
    return out


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
