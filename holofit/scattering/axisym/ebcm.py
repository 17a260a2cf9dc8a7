"""The extended boundary condition method (null-field method) for homogeneous bodies of
revolution (Waterman 1971, Phys. Rev. D 3, 825; Mishchenko & Travis 1998, JQSRT 60, 309).

In the basis of :mod:`holofit.scattering.vsw` the free-space dyadic Green's function is
``G(r, r') = i k sum_nm [M_nm(r) (x) RgM~_nm(r') + N_nm(r) (x) RgN~_nm(r')] / (n (n + 1))`` for
``r > r'`` (``~``: the angular part conjugated), and with the internal field
``E = sum c_l RgN_l(k_1 r) + d_l RgM_l(k_1 r)`` (``k_1 = m k``, ``H' = -i m sum c RgM + d RgN``)
the surface integrals give

    [p; q]  = RgQ [c; d],     -[a; b] = Q [c; d],     T = -RgQ Q^-1,

    Q_{N n, N l} = (i k^2 / nu_n^2) S[m N~_n x RgM_l + M~_n x RgN_l], ...

with ``S[X x Y] = int n^ . (Y x X) dS`` over the surface ``r(theta)`` (``n^ dS = r (r r^ -
r_theta theta^) sin(theta) dtheta dphi``), ``N~, M~`` outgoing (``h_n``) for ``Q`` and regular
(``j_n``) for ``RgQ``. The integrals run on Gauss-Legendre nodes in ``theta`` split at the
profile's kinks (the rod's cap-cylinder junction, a cylinder's edges), where the integrand
is not smooth. Each integrand is a sum of products of one table of the outer wave and one of
the inner (:func:`_couplings`), so the integrals of one ``m`` are two matrix products of
node-stacked tables, real for a real index: ``RgQ`` from ``j_n``, and ``Q`` from ``j_n`` and
``y_n`` apart (``h_n = j_n + i y_n`` enters linearly); the vector waves are never formed. For
a mirror-symmetric body the couplings between the two parity classes under ``z -> -z``,
which vanish by symmetry, are set to zero (their integrals would leave only rounding), and
each class is solved apart. The integrals
run over the whole surface although those integrands are even about ``theta = pi / 2``: over
the upper half alone, doubled, the rod's far field at order 58 is 2.5e-4 from the long-double
reference instead of 1.5e-5 (entries of ``Q`` that cancel by fifteen digits come out
differently; measured, ``docs/validation/exact-studies.md``).

The entries of ``Q`` and ``RgQ`` of orders ``n, l <= L`` do not depend on the truncation
``L``: :func:`ebcm_system` computes them once at the highest order an order search may need,
and :func:`ebcm_solve` solves any truncation ``L`` of them. Conditioning: ``Q``'s raw
entries span the ratio of ``h_n(k r_min)`` to ``j_n(k r_max)`` (about 1e33 for the paper's rod
at order 42), which the solve's row and column equilibration removes; what it leaves is the
condition number reported (``1e2 - 1e4`` for the rod at orders 22-66). What limits double
precision at high orders is not the solve but the cancellation in the surface integrals of
the large outgoing waves, which no scaling removes: :mod:`holofit.scattering.axisym.build`
stops raising the order where the order-to-order change stops falling.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypeVar, cast

import numpy as np
from numpy.typing import NDArray
from scipy.special import spherical_jn, spherical_yn

from holofit.scattering.axisym.profiles import Profile
from holofit.scattering.legendre import legendre_tables

__all__ = ["EBCMSystem", "ebcm_blocks", "ebcm_solve", "ebcm_system", "surface_quadrature"]


def surface_quadrature(profile: Profile, nodes: int) -> tuple[NDArray, NDArray]:
    """Gauss-Legendre nodes and weights in ``theta`` on (0, pi), ``nodes`` per piece between
    the profile's kinks."""
    cuts = [0.0, *sorted(profile.surface_kinks()), np.pi]
    gx, gw = np.polynomial.legendre.leggauss(nodes)
    ts, ws = [], []
    for a, b in itertools.pairwise(cuts):
        half = 0.5 * (b - a)
        ts.append(0.5 * (a + b) + half * gx)
        ws.append(half * gw)
    return np.concatenate(ts), np.concatenate(ws)


def _radial_tables(order: int, x: NDArray, kind: str) -> tuple[NDArray, NDArray]:
    """``z_n(x)`` and ``(x z_n(x))'/x = z_{n-1} - n z_n / x`` for ``n = 0..L`` (``j_n`` for
    ``kind="j"``, ``y_n`` for ``"y"``; ``n = 0``: ``z_0 / x - z_1``) at the nodes ``x`` (real
    or complex; ``y_n`` real only); arrays ``[node, n]``, computed once for every ``m``. The
    outgoing ``h_n = j_n + i y_n`` is never formed: everything it enters is linear in it."""
    n = np.arange(order + 2)[None, :]
    xx = x[:, None]
    z = spherical_jn(n, xx) if kind == "j" else spherical_yn(n, xx)
    dz = np.empty_like(z[:, :-1])
    dz[:, 0] = z[:, 0] / x - z[:, 1]
    dz[:, 1:] = z[:, :-2] - n[:, 1:-1] * z[:, 1:-1] / xx
    return z[:, :-1], dz


Integrals = tuple[NDArray, NDArray, NDArray, NDArray]
Tables = tuple[NDArray, NDArray, NDArray]
Weighted = tuple[NDArray, NDArray, NDArray, NDArray, NDArray]
TablesT = TypeVar("TablesT", Tables, Weighted)


def _orders_from(tables: TablesT, n0: int) -> TablesT:
    """The columns of orders ``n >= n0`` of tables ``[node, n]`` (radial or weighted)."""
    return cast(TablesT, tuple(t[:, n0:] for t in tables))


def _weighted(tables: Tables, nr: NDArray, nt: NDArray) -> Weighted:
    """An outer function's tables with the surface element's components (``nr, nt``, per
    node) as the integrals use them: ``(nr z, nr z', nt nu^2 z / x, nt z, nt z')``, formed
    once for every ``m``."""
    z, dz, zk = tables
    nr_, nt_ = nr[:, None], nt[:, None]
    return nr_ * z, nr_ * dz, nt_ * zk, nt_ * z, nt_ * dz


def _couplings(outers: Sequence[Weighted], inner: Tables,
               angular: tuple[NDArray, NDArray, NDArray]) -> list[Integrals]:
    """The surface integrals ``S[X_n x Y_l]`` (module docstring) of outer waves ``X = M~_n,
    N~_n`` (angular part conjugated) against the inner ``Y = M_l, N_l``, as ``(MM, NM, MN,
    NN)``, each ``[n, l]`` (first letter: the outer wave), for each radial function of
    ``outers``.

    With ``M = (0, +-i z mP, -z dP)`` and ``N = (nu^2 z / x P, z' dP, +-i z' mP)`` in
    ``(r, theta, phi)`` (``P, dP, mP``: the Legendre tables; ``z, z'``: the radial functions
    of :func:`_radial_tables`) the integrand ``n_r (Y_th X_ph - Y_ph X_th) + n_th (Y_ph X_r -
    Y_r X_ph)`` is a sum of products of one outer and one inner table per node, so every
    integral of every outer function is one of two matrix products over the node-stacked
    tables (real where the tables are): far less work than forming the vector waves.

    Parameters
    ----------
    outers : sequence of tuple of ndarray
        Per radial function, :func:`_weighted` tables at the nodes, ``[node, n]``.
    inner : tuple of ndarray
        ``(z, z', nu^2 z / x)`` of the inner ``j_l(m k r)`` (``x = m k r``), ``[node, l]``.
    angular : tuple of ndarray
        ``(P, dP, mP)`` of the ``m`` at the nodes, ``[node, n]``.
    """
    zeta, dzeta, zetak = inner
    pb, dp, mp = angular
    nodes, size = pb.shape
    # u pairs with (zeta mP, zeta dP), v with (dzeta dP, dzeta mP), node-stacked the same way;
    # columns u then v per outer function; the edge terms (z dP, z' mP) pair with zeta_k P
    left = np.empty((2 * nodes, 2 * size * len(outers)))
    edge_left = np.empty((nodes, 2 * size * len(outers)))
    for i, (zr, dzr, zkt, zt, dzt) in enumerate(outers):
        u = left[:, 2 * i * size:(2 * i + 1) * size]
        v = left[:, (2 * i + 1) * size:(2 * i + 2) * size]
        np.multiply(zr, dp, out=u[:nodes])
        np.multiply(zr, mp, out=u[nodes:])
        np.multiply(dzr, mp, out=v[:nodes])
        np.multiply(dzr, dp, out=v[nodes:])
        v[nodes:] -= zkt * pb
        np.multiply(zt, dp, out=edge_left[:, 2 * i * size:(2 * i + 1) * size])
        np.multiply(dzt, mp, out=edge_left[:, (2 * i + 1) * size:(2 * i + 2) * size])
    right = np.empty((2 * nodes, 2 * size), dtype=np.result_type(zeta, pb))
    np.multiply(zeta, mp, out=right[:nodes, :size])
    np.multiply(zeta, dp, out=right[nodes:, :size])
    np.multiply(dzeta, dp, out=right[:nodes, size:])
    np.multiply(dzeta, mp, out=right[nodes:, size:])
    gram = left.T @ right
    edge = edge_left.T @ (zetak * pb)
    out = []
    for i in range(len(outers)):
        # rows of function i: u then v (gram), the (z dP) then (z' mP) edge terms (edge)
        u, v = (gram[(2 * i + j) * size:(2 * i + j + 1) * size] for j in (0, 1))
        e_m, e_n = (edge[(2 * i + j) * size:(2 * i + j + 1) * size] for j in (0, 1))
        out.append((-1j * u[:, :size], v[:, :size], e_m - u[:, size:],
                    1j * (e_n - v[:, size:])))
    return out


def _q_matrix(m_rel: complex | float, integrals: Integrals,
              pref: NDArray) -> NDArray:
    """``Q`` (or ``RgQ``) of one ``m`` from :func:`_couplings` (rows ``a_n`` then ``b_n``,
    columns ``c_l`` then ``d_l``): ``a`` from ``m_rel N~ x RgM + M~ x RgN`` against ``c``,
    ``m_rel N~ x RgN + M~ x RgM`` against ``d``, and ``b`` with ``M~`` and ``N~`` swapped."""
    mm, nm, mn, nn = integrals
    top = np.concatenate([m_rel * nm + mn, m_rel * nn + mm], axis=1)
    bottom = np.concatenate([m_rel * mm + nn, m_rel * mn + nm], axis=1)
    return np.concatenate([top, bottom]) * pref


@dataclass(frozen=True)
class EBCMSystem:
    """``Q`` and ``RgQ`` of the orders ``m = 0..max_m`` of a homogeneous body at order ``L``.

    Attributes
    ----------
    order : int
        The highest order ``L`` of the rows and columns.
    q, rgq : list of ndarray
        Per ``m``, the ``2 N``-square matrices (``N = L - max(1, m) + 1``; rows ``a`` then
        ``b``, columns ``c`` then ``d``, orders ``n = max(1, m)..L`` in each); for a
        mirror-symmetric body only the entries of its two parity classes are filled.
    mirror_symmetric : bool
        Whether the parity classes decouple (solved apart).
    """

    order: int
    q: list[NDArray[np.complex128]]
    rgq: list[NDArray[np.complex128]]
    mirror_symmetric: bool


def _parity(m: int, n: NDArray) -> NDArray:
    """Parity class (0 or 1) of the rows ``a_n`` then ``b_n``: under ``z -> -z`` the class of
    ``M_n`` with ``n + m`` even is that of ``N_n`` with ``n + m`` odd."""
    return np.concatenate([(n + m) % 2, (n + m + 1) % 2])


def ebcm_system(profile: Profile, order: int, k: float, n_medium: float, nodes: int,
                max_m: int | None = None) -> EBCMSystem:
    """``Q`` and ``RgQ`` (module docstring) of a homogeneous profile at ``order``, with
    ``nodes`` Gauss-Legendre nodes per piece of the surface, for ``m = 0..max_m`` (default
    all); ``k`` in rad/um in the medium of index ``n_medium``."""
    L = order
    m_rel: complex | float = complex(profile.index) / n_medium
    if m_rel.imag == 0.0:
        m_rel = m_rel.real  # real Bessel functions inside: several times faster
    mirror = bool(profile.mirror_symmetric)
    theta, w = surface_quadrature(profile, nodes)
    r, dr = profile.surface(theta)
    weight = 2.0 * np.pi * w * np.sin(theta) * r
    nr, nt = weight * r, -weight * dr
    pb, dp, mp = legendre_tables(np.cos(theta), L)
    kr, k1r = k * r, m_rel * k * r
    nu2 = np.arange(L + 1) * (np.arange(L + 1) + 1.0)

    def tables(x: NDArray, kind: str) -> Tables:
        z, dz = _radial_tables(L, x, kind)
        return z, dz, z * nu2[None, :] / x[:, None]

    # the outgoing h_n = j_n + i y_n: Q from the couplings of j_n and y_n, RgQ from j_n's
    outer_j, outer_y = (_weighted(tables(kr, kind), nr, nt) for kind in ("j", "y"))
    inner_j = tables(k1r, "j")
    qs, rgqs = [], []
    for m in range(L + 1 if max_m is None else min(L, max_m) + 1):
        n0 = max(1, m)
        n = np.arange(n0, L + 1)
        angular = (pb[:, n0:, m], dp[:, n0:, m], mp[:, n0:, m])
        ints_j, ints_y = _couplings([_orders_from(outer_j, n0), _orders_from(outer_y, n0)],
                                    _orders_from(inner_j, n0), angular)
        pref = np.tile(1j * k * k / (n * (n + 1.0)), 2)[:, None]
        rgq = _q_matrix(m_rel, ints_j, pref)
        q = rgq + 1j * _q_matrix(m_rel, ints_y, pref)
        if mirror:
            # the couplings between the two parity classes vanish by symmetry: set to zero
            # rather than left at what their cancellation leaves
            parity = _parity(m, n)
            same = parity[:, None] == parity[None, :]
            q, rgq = q * same, rgq * same
        qs.append(q)
        rgqs.append(rgq)
    return EBCMSystem(L, qs, rgqs, mirror)


def _solve_right(q: NDArray, rgq: NDArray, condition: bool = True
                 ) -> tuple[NDArray[np.complex128], float]:
    """``-RgQ Q^-1`` with ``Q`` equilibrated: columns scaled to unit maximum (``T`` does not
    change), then rows (``T = -RgQ (D Q)^-1 D``), so that partial pivoting sees entries of
    comparable size although they span ``h_n(k r_min) / j_n(k r_max)``; and the condition
    number of the equilibrated ``Q`` (NaN unless ``condition``: an SVD, a third of the
    solve's time)."""
    dc = 1.0 / np.abs(q).max(axis=0)
    qs = q * dc[None, :]
    dr = 1.0 / np.abs(qs).max(axis=1)
    qs = qs * dr[:, None]
    x = np.linalg.solve(qs.T, (rgq * dc[None, :]).T).T  # (RgQ Dc) (Dr Q Dc)^-1
    return -x * dr[None, :], float(np.linalg.cond(qs)) if condition else math.nan


def ebcm_solve(system: EBCMSystem, order: int, out_order: int | None = None,
               condition: bool = True) -> tuple[NDArray[np.complex128], NDArray[np.float64]]:
    """Padded T-matrix blocks ``(L' + 1, 2L', 2L')`` of ``m = 0..L'`` (layout of
    :func:`holofit.scattering.axisym.iitm.mie_start`) solved at a truncation
    ``L <= system.order`` and kept at ``L' = out_order <= L`` (default ``L``: the sub-blocks
    of orders ``n, l <= L'``), and the condition number of the equilibrated ``Q`` per ``m``
    (NaN unless ``condition``)."""
    L = int(order)
    out = L if out_order is None else min(int(out_order), L)
    if not 1 <= L <= system.order or out + 1 > len(system.q):
        raise ValueError(f"EBCM order {L} (kept at {out}) outside the computed system "
                         f"(order {system.order}, m <= {len(system.q) - 1})")
    blocks = np.zeros((out + 1, 2 * out, 2 * out), dtype=complex)
    conds = np.zeros(out + 1)
    for m in range(out + 1):
        n0 = max(1, m)
        full = system.order - n0 + 1
        cnt = L - n0 + 1
        keep = np.concatenate([np.arange(cnt), full + np.arange(cnt)])
        q = system.q[m][np.ix_(keep, keep)]
        rgq = system.rgq[m][np.ix_(keep, keep)]
        n = np.arange(n0, L + 1)
        classes = ([np.flatnonzero(_parity(m, n) == c) for c in (0, 1)]
                   if system.mirror_symmetric else [np.arange(2 * cnt)])
        t = np.zeros_like(q)
        for sel in classes:
            if sel.size == 0:
                continue
            t[np.ix_(sel, sel)], cond = _solve_right(q[np.ix_(sel, sel)], rgq[np.ix_(sel, sel)],
                                                     condition)
            conds[m] = max(conds[m], cond) if condition else math.nan
        c_out = out - n0 + 1
        src = np.concatenate([np.arange(c_out), cnt + np.arange(c_out)])
        dst = np.concatenate([np.arange(c_out), out + np.arange(c_out)])
        blocks[m][np.ix_(dst, dst)] = t[np.ix_(src, src)]
    return blocks, conds


def ebcm_blocks(profile: Profile, order: int, k: float, n_medium: float, nodes: int
                ) -> tuple[NDArray[np.complex128], NDArray[np.float64]]:
    """:func:`ebcm_solve` of :func:`ebcm_system` at one ``order``: padded T-matrix blocks
    and the equilibrated condition number of ``Q`` per ``m``."""
    return ebcm_solve(ebcm_system(profile, order, k, n_medium, nodes), order)
