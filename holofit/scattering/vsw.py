"""Regular (incident) vector spherical waves: the incident side of a particle's T-matrix.

Basis
-----
The regular waves are those of :mod:`holofit.scattering.multipole` with the spherical Bessel
function ``j_n`` in place of ``h_n``:

    RgM_nm = j_n(kr) [ (i m / sin th) Y_nm e_th - dY_nm/dth e_ph ]  = -j_n(kr) Phi_nm,
    RgN_nm = n(n+1) j_n(kr)/(kr) Y_nm e_r + (kr j_n(kr))'/(kr) Psi_nm,

with the vector spherical harmonics ``Psi_nm = dY_nm/dth e_th + (i m / sin th) Y_nm e_ph`` and
``Phi_nm = r^ x Psi_nm`` (both of norm ``n(n+1)`` on the unit sphere). An incident field is
``E = sum a_nm RgN_nm + b_nm RgM_nm``; the scattered field is ``sum p_nm N_nm + q_nm M_nm``.

Coefficient vectors
-------------------
A T-matrix acts on flat vectors of length ``2 L (L + 2)``: first the N-type coefficients
(``a`` or ``p``), then the M-type ones (``b`` or ``q``), each ordered by ``n = 1..L`` and then
``m = -n..n`` (:func:`pack`, :func:`unpack` convert from and to the ``[n, m + L]`` arrays of
:class:`~holofit.scattering.multipole.MultipoleExpansion`).

Plane wave
----------
``e exp(i k k^.r)`` (``e`` perpendicular to ``k^``) has, from the addition theorem of
``exp(i k.r)`` and the Hermiticity of the angular-momentum operator on the sphere,

    a_nm = -4 pi i^(n+1) e . conj(Psi_nm(k^)) / (n(n+1)),
    b_nm = -4 pi i^n     e . conj(Phi_nm(k^)) / (n(n+1)).

Herglotz synthesis
------------------
Every regular field is a superposition of plane waves, ``E(r) = int g(k^) exp(i k k^.r) dk^``
with a tangential density ``g``; by the formulas above, coefficients ``(a, b)`` come from
``g = sum a_nm Psi_nm / (-4 pi i^(n+1)) + b_nm Phi_nm / (-4 pi i^n)``. The integral is done
with a Gauss-Legendre x uniform quadrature that is exact for the band limit of the integrand
(degree ``L`` of ``g`` plus the ``~kR`` of the plane waves over the lattice), and the sum over
directions is separable on the dipole lattice (the adjoint of
:func:`holofit.dda.farfield.dipole_sum_on_grid`), so the incident field of any coefficient
vector on all dipoles costs a few small matrix products
(:mod:`holofit.dda.tmatrix_incident`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.scattering.multipole import _full_tables

__all__ = [
    "herglotz_density",
    "n_terms",
    "pack",
    "plane_wave_coefficients",
    "term_indices",
    "unpack",
]


def n_terms(order: int) -> int:
    """Length ``2 L (L + 2)`` of a coefficient vector of order ``L``."""
    return 2 * order * (order + 2)


@lru_cache(maxsize=32)
def term_indices(order: int) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """``(kind, n, m)`` of every entry of a coefficient vector (kind 0: N-type, 1: M-type)."""
    n = np.concatenate([np.full(2 * j + 1, j) for j in range(1, order + 1)])
    m = np.concatenate([np.arange(-j, j + 1) for j in range(1, order + 1)])
    half = n.size
    kind = np.repeat([0, 1], half)
    out = (kind, np.tile(n, 2), np.tile(m, 2))
    for a in out:
        a.setflags(write=False)
    return out


def pack(p: NDArray[np.complex128], q: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """Flat coefficient vector from ``[n, m + L]`` arrays of N-type (``p``) and M-type (``q``)."""
    order = p.shape[0] - 1
    _, n, m = term_indices(order)
    half = n.size // 2
    return np.concatenate([p[n[:half], m[:half] + order], q[n[:half], m[:half] + order]])


def unpack(vec: NDArray[np.complex128], order: int) -> tuple[NDArray, NDArray]:
    """``[n, m + L]`` arrays (N-type, M-type) of a flat coefficient vector (or of each column
    of a matrix, then with a trailing axis)."""
    vec = np.asarray(vec)
    _, n, m = term_indices(order)
    half = n.size // 2
    shape = (order + 1, 2 * order + 1, *vec.shape[1:])
    p = np.zeros(shape, dtype=complex)
    q = np.zeros(shape, dtype=complex)
    p[n[:half], m[:half] + order] = vec[:half]
    q[n[:half], m[:half] + order] = vec[half:]
    return p, q


def _spherical_basis(mu: NDArray, phi: NDArray) -> tuple[NDArray, NDArray]:
    """Unit vectors ``e_th``, ``e_ph`` (n_theta, n_phi, 3) of a (cos th, phi) grid."""
    shape = (mu.size, phi.size)
    st = np.broadcast_to(np.sqrt(np.clip(1.0 - mu**2, 0.0, None))[:, None], shape)
    ct = np.broadcast_to(mu[:, None], shape)
    cp = np.broadcast_to(np.cos(phi)[None, :], shape)
    sp = np.broadcast_to(np.sin(phi)[None, :], shape)
    e_t = np.stack([ct * cp, ct * sp, -st], axis=-1)
    e_p = np.stack([-sp, cp, np.zeros(shape)], axis=-1)
    return e_t, e_p


def plane_wave_coefficients(
    direction: ArrayLike, polarization: ArrayLike, order: int
) -> NDArray[np.complex128]:
    """Regular-wave coefficients (flat vector) of the plane wave ``e exp(i k k^.r)``.

    Parameters
    ----------
    direction : array_like, shape (3,)
        Unit propagation direction ``k^``.
    polarization : array_like, shape (3,)
        Polarisation ``e`` (perpendicular to ``k^``; may be complex).
    order : int
        Highest order ``L``.
    """
    k_hat = np.asarray(direction, dtype=float)
    k_hat = k_hat / np.linalg.norm(k_hat)
    e = np.asarray(polarization, dtype=complex)
    mu = np.array([np.clip(k_hat[2], -1.0, 1.0)])
    phi0 = float(np.arctan2(k_hat[1], k_hat[0]))
    _, df, mf = _full_tables(mu, order)
    df, mf = df[0], mf[0]  # [n, m + L]
    e_t, e_p = _spherical_basis(mu, np.array([phi0]))
    et = complex(np.dot(e, e_t[0, 0]))
    ep = complex(np.dot(e, e_p[0, 0]))
    m = np.arange(-order, order + 1)
    n = np.arange(order + 1)[:, None]
    phase = np.exp(-1j * m * phi0)[None, :]
    psi_dot = (df * et - 1j * mf * ep) * phase  # e . conj(Psi_nm)
    phi_dot = (df * ep + 1j * mf * et) * phase  # e . conj(Phi_nm)
    with np.errstate(divide="ignore", invalid="ignore"):
        norm = np.where(n > 0, -4.0 * np.pi / (n * (n + 1.0)), 0.0)
    a = norm * (1j ** (n + 1)) * psi_dot
    b = norm * (1j**n) * phi_dot
    return pack(a, b)


def herglotz_density(
    vec: NDArray[np.complex128], mu: NDArray, phi: NDArray, order: int
) -> NDArray[np.complex128]:
    """Plane-wave density ``g(k^)`` (n_theta, n_phi, 3) of the regular field with coefficients
    ``vec``, on the (cos th, phi) grid ``mu`` x ``phi`` (uniform phi)."""
    a, b = unpack(vec, order)
    n = np.arange(order + 1)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(n > 0, 1.0 / (-4.0 * np.pi), 0.0)
    alpha = a * inv / (1j ** (n + 1))
    beta = b * inv / (1j**n)
    _, df, mf = _full_tables(mu, order)  # [i, n, m + L]
    g_t = np.einsum("nm,inm->im", alpha, df) - 1j * np.einsum("nm,inm->im", beta, mf)
    g_p = 1j * np.einsum("nm,inm->im", alpha, mf) + np.einsum("nm,inm->im", beta, df)
    n_phi = phi.size
    if n_phi < 2 * order + 1:
        raise ValueError(f"{n_phi} azimuths cannot resolve order {order}")
    m = np.arange(-order, order + 1)
    full_t = np.zeros((mu.size, n_phi), dtype=complex)
    full_p = np.zeros((mu.size, n_phi), dtype=complex)
    full_t[:, m % n_phi] = g_t
    full_p[:, m % n_phi] = g_p
    gt = np.fft.ifft(full_t, axis=1, norm="forward")
    gp = np.fft.ifft(full_p, axis=1, norm="forward")
    e_t, e_p = _spherical_basis(mu, phi)
    return gt[..., None] * e_t + gp[..., None] * e_p
