"""The translation-addition theorem for vector spherical waves (holofit's VSWF conventions).

The waves are those of :mod:`holofit.scattering.multipole` (outgoing, ``h_n``) and
:mod:`holofit.scattering.vsw` (regular, ``j_n``): ``M_nm = curl(r psi_nm)``,
``N_nm = curl(M_nm) / k`` with ``psi_nm = z_n(kr) Y_nm`` and orthonormal ``Y_nm``
(Condon-Shortley phase). Coefficient vectors use the flat layout of
:mod:`holofit.scattering.vsw` (N-type block, then M-type; ``n = 1..L``, ``m = -n..n``).

A wave about a source centre is re-expanded about a receiving centre at ``source + d``
(``r_source = r_receiver + d``):

* ``kind = "regular"``: regular waves to regular waves (everywhere), and outgoing waves to
  outgoing waves for ``|r_receiver| > |d|``; built with ``j_p(k|d|)``;
* ``kind = "outgoing"``: outgoing waves to regular waves for ``|r_receiver| < |d|``; built with
  ``h_p(k|d|)``.

Axial translation (``d`` along z)
---------------------------------
The scalar theorem, from the plane-wave expansion ``exp(i k.r) = 4 pi sum i^l j_l(kr)
Y_lm(r^) conj(Y_lm(k^))`` applied to ``psi_nu,mu(r' + d) = (4 pi i^nu)^-1 Int exp(i k.(r'+d))
Y_nu,mu(k^) dk^``, is ``psi_nu,mu(r' + d) = sum_n alpha_{n nu} Rg psi_n,mu(r')`` with

    alpha_{n nu} = 4 pi sum_p i^(n - nu + p) z_p(k|d|) Y_p0(d^) G(n, nu, p; mu),
    G = Int conj(Y_n,mu) Y_nu,mu Y_p0 dOmega = 2 pi Int_-1^1 Pbar_n^mu Pbar_nu^mu Pbar_p^0 dx

(``|n - nu| <= p <= n + nu``, ``n + nu + p`` even; the Gaunt integrals are done exactly by
Gauss-Legendre quadrature and only these ``p`` are summed, so that the large ``h_p`` of the
outgoing kind never meet a quadrature residue). Writing ``M = -r x grad psi`` with
``r = r' + d z^`` and ``z^ x grad Rg psi_nm = -i m k /(n(n+1)) RgN_nm - k a_{n+1,m}/(n+1)
RgM_{n+1,m} - k a_{n,m}/n RgM_{n-1,m}`` (``a_{n,m} = sqrt((n^2 - m^2)/((2n+1)(2n-1)))``, from
``r.F`` and ``r.curl F`` of ``F = z^ x grad psi``) gives the vector coefficients

    M_nu,mu = sum_n A_{n nu} RgM_n,mu + B_{n nu} RgN_n,mu,
    N_nu,mu = sum_n B_{n nu} RgM_n,mu + A_{n nu} RgN_n,mu,
    A_{n nu} = alpha_{n nu} + kd [a_{n,mu}/n alpha_{n-1,nu} + a_{n+1,mu}/(n+1) alpha_{n+1,nu}],
    B_{n nu} = i kd mu / (n(n+1)) alpha_{n nu}        (d signed along z).

Any other direction is the rotation to the axis, the axial translation and the rotation back
(:func:`translation_matrix`, with :mod:`holofit.scattering.wigner`'s matrices).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import spherical_jn, spherical_yn

from holofit.scattering.legendre import legendre_tables
from holofit.scattering.vsw import term_indices
from holofit.scattering.wigner import apply_blocks, rotation_blocks, wigner_d_all

__all__ = [
    "axial_entries",
    "axial_translation",
    "scalar_axial",
    "translation_matrix",
    "wigner_matrix",
]

KINDS = ("regular", "outgoing")


@lru_cache(maxsize=16)
def _gaunt_axial(n_max: int, nu_max: int) -> NDArray[np.float64]:
    """``G[|mu|, n, nu, p]`` for ``n <= n_max``, ``nu <= nu_max``, ``p <= n_max + nu_max``
    (zero outside the selection rules, which are imposed exactly)."""
    p_max = n_max + nu_max
    nodes = (n_max + nu_max + p_max) // 2 + 2
    x, w = np.polynomial.legendre.leggauss(nodes)
    pb, _, _ = legendre_tables(np.ascontiguousarray(x), p_max)  # [i, l, m]
    mu_max = min(n_max, nu_max)
    out = np.zeros((mu_max + 1, n_max + 1, nu_max + 1, p_max + 1))
    n = np.arange(n_max + 1)[:, None, None]
    nu = np.arange(nu_max + 1)[None, :, None]
    p = np.arange(p_max + 1)[None, None, :]
    allowed = (p >= np.abs(n - nu)) & (p <= n + nu) & ((n + nu + p) % 2 == 0)
    p0 = pb[:, :, 0] * w[:, None]  # [i, p]
    for m in range(mu_max + 1):
        a = pb[:, : n_max + 1, m]  # [i, n]
        b = pb[:, : nu_max + 1, m]  # [i, nu]
        prod = (a[:, :, None] * b[:, None, :]).reshape(nodes, -1)  # [i, n*nu]
        g = 2.0 * np.pi * (prod.T @ p0).reshape(n_max + 1, nu_max + 1, p_max + 1)
        out[m] = np.where(allowed & (n >= m) & (nu >= m), g, 0.0)
    out.setflags(write=False)
    return out


def _radial(kind: str, order: int, x: float) -> NDArray[np.complex128]:
    p = np.arange(order + 1)
    if kind == "regular":
        return spherical_jn(p, x).astype(complex)
    if kind == "outgoing":
        if x <= 0.0:
            raise ValueError("an outgoing wave cannot be re-expanded about its own centre")
        return spherical_jn(p, x) + 1j * spherical_yn(p, x)
    raise ValueError(f"translation kind must be one of {KINDS}, got {kind!r}")


def scalar_axial(kd: float, n_max: int, nu_max: int, kind: str) -> NDArray[np.complex128]:
    """Scalar axial coefficients ``alpha[|mu|, n, nu]`` (module docstring) for the signed
    translation ``kd`` (k times the signed distance along z), ``0 <= n <= n_max``,
    ``0 <= nu <= nu_max``."""
    g = _gaunt_axial(n_max, nu_max)
    p_max = n_max + nu_max
    p = np.arange(p_max + 1)
    sign = 1.0 if kd >= 0.0 else -1.0
    ylm = sign**p * np.sqrt((2 * p + 1) / (4.0 * np.pi))  # Y_p0(d^)
    c = 4.0 * np.pi * (1j**p) * _radial(kind, p_max, abs(kd)) * ylm
    alpha = g @ c  # [mu, n, nu]
    n = np.arange(n_max + 1)[:, None]
    nu = np.arange(nu_max + 1)[None, :]
    return alpha * (1j ** ((n - nu) % 4))[None]


def axial_entries(kd: float, order_to: int, order_from: int,
                  kind: str) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.complex128]]:
    """The entries of :func:`axial_translation` that can be non-zero (equal ``m``): flat row
    and column indices and values."""
    alpha = scalar_axial(kd, order_to + 1, order_from, kind)
    rows, cols = _same_m_pairs(order_to, order_from)
    kr, nr, mr = term_indices(order_to)
    ks, ns, _ = term_indices(order_from)
    n, nu, mm = nr[rows], ns[cols], mr[rows]
    m = np.abs(mm)

    def coef(nn: NDArray) -> NDArray:
        return np.sqrt(np.clip(nn**2 - m**2, 0, None) / ((2.0 * nn + 1) * (2.0 * nn - 1)))

    a_val = alpha[m, n, nu] + kd * (coef(n) / n * alpha[m, n - 1, nu]
                                    + coef(n + 1) / (n + 1) * alpha[m, n + 1, nu])
    b_val = 1j * kd * mm / (n * (n + 1.0)) * alpha[m, n, nu]
    return rows, cols, np.where(kr[rows] == ks[cols], a_val, b_val)


@lru_cache(maxsize=32)
def _same_m_pairs(order_to: int, order_from: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Flat (row, column) index pairs of equal ``m``."""
    _, _, mr = term_indices(order_to)
    _, _, ms = term_indices(order_from)
    rows_l, cols_l = [], []
    for m in range(-min(order_to, order_from), min(order_to, order_from) + 1):
        r = np.nonzero(mr == m)[0]
        c = np.nonzero(ms == m)[0]
        rows_l.append(np.repeat(r, c.size))
        cols_l.append(np.tile(c, r.size))
    rows, cols = np.concatenate(rows_l), np.concatenate(cols_l)
    rows.setflags(write=False)
    cols.setflags(write=False)
    return rows, cols


def axial_translation(kd: float, order_to: int, order_from: int,
                      kind: str) -> NDArray[np.complex128]:
    """Translation matrix (flat layout, ``n_terms(order_to) x n_terms(order_from)``) along z by
    the signed ``kd``: column ``j`` holds the coefficients about the receiving centre of the
    source's wave ``j`` (module docstring)."""
    rows, cols, vals = axial_entries(kd, order_to, order_from, kind)
    out = np.zeros((term_indices(order_to)[0].size, term_indices(order_from)[0].size),
                   dtype=complex)
    out[rows, cols] = vals
    return out


def wigner_matrix(order: int, psi: float, theta: float, phi: float = 0.0
                  ) -> NDArray[np.complex128]:
    """Dense flat-layout matrix of the rotation ``Rz(psi) Ry(theta) Rz(phi)``: particle-frame
    coefficients to lab-frame ones (:mod:`holofit.scattering.wigner`)."""
    d = wigner_d_all(order, psi, theta, phi)
    kind, n, m = term_indices(order)
    same = (kind[:, None] == kind[None, :]) & (n[:, None] == n[None, :])
    out = np.zeros((n.size, n.size), dtype=complex)
    rows, cols = np.nonzero(same)
    out[rows, cols] = d[n[rows], m[rows] + order, m[cols] + order]
    return out


def translation_matrix(d_um: ArrayLike, k: float, order_to: int, order_from: int,
                       kind: str) -> NDArray[np.complex128]:
    """Translation matrix for the vector ``d_um`` (receiving centre = source centre + d, um).

    Parameters
    ----------
    d_um : array_like, shape (3,)
        Displacement from the source centre to the receiving centre, um.
    k : float
        Wavenumber in the medium, rad/um.
    order_to, order_from : int
        Orders of the receiving and source expansions.
    kind : {"regular", "outgoing"}
        See the module docstring.

    Returns
    -------
    ndarray, shape (n_terms(order_to), n_terms(order_from))
    """
    d = np.asarray(d_um, dtype=float)
    dist = float(np.linalg.norm(d))
    if dist == 0.0:
        return axial_translation(0.0, order_to, order_from, kind)
    rho = float(np.hypot(d[0], d[1]))
    if rho <= 1e-14 * dist:
        return axial_translation(k * float(np.sign(d[2])) * dist, order_to, order_from, kind)
    theta = float(np.arctan2(rho, d[2]))
    psi = float(np.arctan2(d[1], d[0]))
    axial = axial_translation(k * dist, order_to, order_from, kind)
    # D_to A D_from^H with the per-n blocks of the rotations (never as dense products)
    half = apply_blocks(rotation_blocks(order_from, psi, theta, 0.0), axial.conj().T, order_from)
    return apply_blocks(rotation_blocks(order_to, psi, theta, 0.0), half.conj().T, order_to)


