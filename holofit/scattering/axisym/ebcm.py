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
is not smooth. Conditioning: ``Q``'s entries span the ratio of ``h_n(k r_min)`` to
``j_n(k r_max)``, so an elongated body loses digits (DESIGN notes: about nine for the paper's
rod at order 42); :func:`ebcm_blocks` reports ``Q``'s condition number per ``m``.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import NDArray
from scipy.special import spherical_jn, spherical_yn

from holofit.scattering.axisym.profiles import Profile
from holofit.scattering.legendre import legendre_tables

__all__ = ["ebcm_blocks", "surface_quadrature"]


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


def _radial_tables(order: int, x: NDArray, outgoing: bool) -> tuple[NDArray, NDArray]:
    """``z_n(x)`` and ``(x z_n(x))'/x`` for ``n = 0..L`` (``j_n``, or ``h_n`` if ``outgoing``)
    at the nodes ``x`` (real or complex); arrays ``[node, n]``, computed once for every ``m``."""
    n = np.arange(order + 1)[None, :]
    xx = x[:, None]
    j = spherical_jn(n, xx)
    dj = spherical_jn(n, xx, derivative=True)
    if outgoing:
        j = j + 1j * spherical_yn(n, xx)
        dj = dj + 1j * spherical_yn(n, xx, derivative=True)
    return j, j / xx + dj


def _waves(n: NDArray, kr: NDArray, radial: tuple[NDArray, NDArray], pb: NDArray,
           dp: NDArray, mp: NDArray, conj: bool) -> tuple[NDArray, NDArray]:
    """``(r, theta, phi)`` components ``[3, node, n]`` of ``M_nm`` and ``N_nm`` at ``phi = 0``
    (angular part conjugated if ``conj``) from the radial tables of :func:`_radial_tables`."""
    z, dz = radial[0][:, n], radial[1][:, n]
    s = -1.0 if conj else 1.0
    nu2 = (n * (n + 1.0))[None, :]
    zero = np.zeros_like(z)
    mm = np.stack([zero, s * 1j * z * mp, -z * dp])
    nn = np.stack([nu2 * z / kr[:, None] * pb, dz * dp, s * 1j * dz * mp])
    return mm, nn


def _cross_integral(x_bar: NDArray, y: NDArray, nr: NDArray, nt: NDArray) -> NDArray:
    """``[n, l] = sum_q (n_r (Y_th X_ph - Y_ph X_th) + n_th (Y_ph X_r - Y_r X_ph))`` with the
    weights folded into ``nr, nt``."""
    xr, xt, xp = x_bar
    yr, yt, yp = y
    out = (xp * nr[:, None]).T @ yt - (xt * nr[:, None]).T @ yp
    out += (xr * nt[:, None]).T @ yp - (xp * nt[:, None]).T @ yr
    return out


def _q_matrix(bm: NDArray, bn: NDArray, in_m: NDArray, in_n: NDArray, nr: NDArray,
              nt: NDArray, m_rel: complex, pref: NDArray) -> NDArray[np.complex128]:
    """``Q`` (outgoing ``bm, bn``) or ``RgQ`` (regular) of one ``m``: rows ``p``/``a`` then
    ``q``/``b``, columns ``c`` then ``d`` (module docstring)."""
    cnt = pref.shape[0]
    q = np.empty((2 * cnt, 2 * cnt), dtype=complex)
    q[:cnt, :cnt] = m_rel * _cross_integral(bn, in_m, nr, nt) + _cross_integral(bm, in_n, nr, nt)
    q[:cnt, cnt:] = m_rel * _cross_integral(bn, in_n, nr, nt) + _cross_integral(bm, in_m, nr, nt)
    q[cnt:, :cnt] = m_rel * _cross_integral(bm, in_m, nr, nt) + _cross_integral(bn, in_n, nr, nt)
    q[cnt:, cnt:] = m_rel * _cross_integral(bm, in_n, nr, nt) + _cross_integral(bn, in_m, nr, nt)
    return q * np.concatenate([pref, pref])


def _solve_right(q: NDArray, rgq: NDArray) -> NDArray[np.complex128]:
    """``-RgQ Q^-1`` with ``Q`` equilibrated: columns scaled to unit maximum (``T`` does not
    change), then rows (``T = -RgQ (D Q)^-1 D``), so that partial pivoting sees entries of
    comparable size although they span ``h_n(k r_min) / j_n(k r_max)``."""
    dc = 1.0 / np.abs(q).max(axis=0)
    qs = q * dc[None, :]
    dr = 1.0 / np.abs(qs).max(axis=1)
    qs = qs * dr[:, None]
    x = np.linalg.solve(qs.T, (rgq * dc[None, :]).T).T  # (RgQ Dc) (Dr Q Dc)^-1
    return -x * dr[None, :]


def ebcm_blocks(profile: Profile, order: int, k: float, n_medium: float, nodes: int
                ) -> tuple[NDArray[np.complex128], NDArray[np.float64]]:
    """Padded T-matrix blocks ``(L + 1, 2L, 2L)`` of ``m = 0..L`` (layout of
    :func:`holofit.scattering.axisym.iitm.mie_start`) and the condition number of ``Q`` per
    ``m``, for a homogeneous profile, with ``nodes`` Gauss-Legendre nodes per piece."""
    L = order
    m_rel = complex(profile.index) / n_medium
    theta, w = surface_quadrature(profile, nodes)
    r, dr = profile.surface(theta)
    st = np.sin(theta)
    weight = 2.0 * np.pi * w * st * r
    nr = weight * r
    nt = -weight * dr
    pb, dp, mp = legendre_tables(np.cos(theta), L)
    kr, k1r = k * r, m_rel * k * r
    rad_rg = _radial_tables(L, kr, outgoing=False)
    rad_out = _radial_tables(L, kr, outgoing=True)
    rad_in = _radial_tables(L, k1r, outgoing=False)
    out = np.zeros((L + 1, 2 * L, 2 * L), dtype=complex)
    conds = np.zeros(L + 1)
    for m in range(L + 1):
        n0 = max(1, m)
        n = np.arange(n0, L + 1)
        cnt = n.size
        tabs = (pb[:, n0:, m], dp[:, n0:, m], mp[:, n0:, m])
        rg_m, rg_n = _waves(n, kr, rad_rg, *tabs, conj=True)
        ou_m, ou_n = _waves(n, kr, rad_out, *tabs, conj=True)
        in_m, in_n = _waves(n, k1r, rad_in, *tabs, conj=False)
        pref = (1j * k * k / (n * (n + 1.0)))[:, None]

        rgq = _q_matrix(rg_m, rg_n, in_m, in_n, nr, nt, m_rel, pref)
        q = _q_matrix(ou_m, ou_n, in_m, in_n, nr, nt, m_rel, pref)
        if profile.mirror_symmetric:
            # the parity classes under z -> -z decouple: N_n with n + m even goes with M_n of
            # odd n + m; solved apart, the analytically zero couplings (numerical noise of the
            # large entries) do not enter the solve
            t = np.zeros_like(q)
            parity = np.concatenate([(n + m) % 2, (n + m + 1) % 2])
            cond = 0.0
            for cls in (0, 1):
                sel = np.nonzero(parity == cls)[0]
                if sel.size == 0:
                    continue
                qq, rr = q[np.ix_(sel, sel)], rgq[np.ix_(sel, sel)]
                cond = max(cond, float(np.linalg.cond(qq)))
                t[np.ix_(sel, sel)] = _solve_right(qq, rr)
            conds[m] = cond
        else:
            conds[m] = float(np.linalg.cond(q))
            t = _solve_right(q, rgq)
        sel = np.concatenate([np.arange(cnt), L + np.arange(cnt)])
        out[m][np.ix_(sel, sel)] = t
    return out, conds
