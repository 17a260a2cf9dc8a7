"""Vector spherical-wave (multipole) expansion of a scattered field, and its fast evaluation
on a camera plane.

Outside the sphere that circumscribes the sources, the scattered field is exactly

    E(r) = sum_{n=1}^{L} sum_{m=-n}^{n} p_nm N_nm(kr) + q_nm M_nm(kr),
    M_nm = h_n(kr) [ (i m / sin th) Y_nm e_th - dY_nm/dth e_ph ],
    N_nm = n(n+1) h_n(kr)/(kr) Y_nm e_r
           + xi_n'(kr)/(kr) [ dY_nm/dth e_th + (i m / sin th) Y_nm e_ph ],

with ``Y_nm`` orthonormal spherical harmonics (Condon-Shortley phase), ``h_n = h_n^(1)`` and
``xi_n(x) = x h_n(x)``; the truncation error falls super-exponentially once ``L`` exceeds
``k R``. The coefficients follow from the far-field pattern ``A(n) = lim kr exp(-ikr) E`` by
projection, ``p_nm = i^n <A, Phi_nm> / (n(n+1))``, ``q_nm = i^(n+1) <A, X_nm> / (n(n+1))``,
done exactly with Gauss-Legendre nodes in ``cos th`` and an FFT in ``phi``.

Camera plane
------------
On the plane ``Z = -z_p`` below the particle the field is ``exp(ikr)/(kr) U(th, phi)`` where
``U`` is smooth and band-limited (degree <= 2L in ``th`` because ``1/(kr) = |cos th|/(k z_p)``,
<= L+1 in ``phi``). ``U`` is computed exactly on a uniform ``(th, phi)`` grid (per ``th`` row:
Legendre tables and radial functions, then an FFT over ``m``), and evaluated at every pixel by
local Lagrange interpolation, oversampled so that the interpolation error is ~1e-9 of the
field; the exact factor ``exp(ikr)/(kr)`` is applied per pixel. A lateral move of the particle
only repeats the interpolation; a change of ``z_p`` also recomputes the grid.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import lru_cache

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.scattering.legendre import legendre_tables
from holofit.scattering.lens_kernels import POLAR_STENCIL, polar_interpolate

__all__ = [
    "NEAR_ZONE",
    "MultipoleExpansion",
    "PlaneGrid",
    "default_order",
    "evaluate_plane",
    "evaluate_plane_at",
    "evaluate_planes_at",
    "expansion_from_far_field",
    "plane_grid",
]

#: points closer to the centre than this multiple of the circumscribing radius are not
#: evaluated from an expansion (its series converges slowly there): the engines use the dipoles
NEAR_ZONE = 2.0


def default_order(k: float, radius_um: float) -> int:
    """Series length for sources within ``radius_um``: ``kR + 6 (kR)^(1/3) + 3``."""
    x = k * radius_um
    return int(np.ceil(x + 6.0 * x ** (1.0 / 3.0) + 3.0))


# -- radial functions -----------------------------------------------------------------------


@numba.njit(cache=True, nogil=True)
def _radial(kr, lmax, far):  # pragma: no cover - compiled
    """h_n(kr), xi_n'(kr)/(kr) and n(n+1) h_n(kr)/(kr) for n = 0..lmax at each kr."""
    npts = kr.shape[0]
    h = np.zeros((npts, lmax + 1), dtype=np.complex128)
    dx = np.zeros((npts, lmax + 1), dtype=np.complex128)
    hk = np.zeros((npts, lmax + 1), dtype=np.complex128)
    for p in range(npts):
        x = kr[p]
        e = np.cos(x) + 1j * np.sin(x)
        if far:
            fac = e / x
            c = -1j  # h_n -> (-i)^(n+1) e/x ; xi'/x -> (-i)^n e/x
            pw = 1.0 + 0j
            for n in range(lmax + 1):
                dx[p, n] = pw * fac
                pw *= c
                h[p, n] = pw * fac
                hk[p, n] = 0.0
            continue
        h0 = -1j * e / x
        h[p, 0] = h0
        if lmax >= 1:
            h[p, 1] = -e * (x + 1j) / (x * x)
        for n in range(1, lmax):
            h[p, n + 1] = (2 * n + 1) / x * h[p, n] - h[p, n - 1]
        dx[p, 0] = h0 + 0.0  # xi_0'(x)/x = (x h_0)'/x; unused (n >= 1)
        for n in range(1, lmax + 1):
            dx[p, n] = h[p, n - 1] - n * h[p, n] / x
            hk[p, n] = n * (n + 1) * h[p, n] / x
    return h, dx, hk


# -- the expansion --------------------------------------------------------------------------


def _full_tables(mu: NDArray, lmax: int) -> tuple[NDArray, NDArray, NDArray]:
    """Legendre tables extended to negative m: index [point, n, m + L]."""
    pb, dp, mp = legendre_tables(np.ascontiguousarray(mu, dtype=float), lmax)
    L = lmax
    m = np.arange(1, L + 1)
    sign = (-1.0) ** m
    shape = (pb.shape[0], L + 1, 2 * L + 1)
    pf, df, mf = np.zeros(shape), np.zeros(shape), np.zeros(shape)
    pf[:, :, L:] = pb
    df[:, :, L:] = dp
    mf[:, :, L:] = mp
    # Y_{n,-m} = (-1)^m conj(Y_nm): Pbar^{-m} = (-1)^m Pbar^m,
    # (-m) Pbar^{-m}/sin = -(-1)^m m Pbar^m/sin
    pf[:, :, L - m] = pb[:, :, m] * sign
    df[:, :, L - m] = dp[:, :, m] * sign
    mf[:, :, L - m] = -mp[:, :, m] * sign
    return pf, df, mf


@numba.njit(cache=True, nogil=True)
def _sum_points(p, q, h, dx, hk, pb, dp, mp, phi, out):  # pragma: no cover - compiled
    """``E_r, E_th, E_ph`` at points from the series: ``out[i] = (E_r, E_th, E_ph)``.

    ``p, q`` at ``[n, m + L]``; radial tables ``[i, n]``; Legendre tables ``[i, n, |m|]``
    (m >= 0; ``Y_{n,-m} = (-1)^m conj(Y_nm)``).
    """
    L = p.shape[0] - 1
    for i in range(out.shape[0]):
        er = 0j
        et = 0j
        ep = 0j
        for m in range(-L, L + 1):
            am = abs(m)
            sign = -1.0 if (m < 0 and am % 2 == 1) else 1.0
            msign = -sign if m < 0 else sign
            e = np.cos(m * phi[i]) + 1j * np.sin(m * phi[i])
            sr = 0j
            st = 0j
            sp = 0j
            for n in range(max(am, 1), L + 1):
                pn = p[n, m + L]
                qn = q[n, m + L]
                pf = sign * pb[i, n, am]
                df = sign * dp[i, n, am]
                mf = msign * mp[i, n, am]
                sr += pn * hk[i, n] * pf
                st += pn * dx[i, n] * df + 1j * qn * h[i, n] * mf
                sp += 1j * pn * dx[i, n] * mf - qn * h[i, n] * df
            er += sr * e
            et += st * e
            ep += sp * e
        out[i, 0] = er
        out[i, 1] = et
        out[i, 2] = ep


#: points per block in :meth:`MultipoleExpansion.field_at` (bounds the Legendre tables' memory)
POINT_BLOCK = 512


@dataclass
class MultipoleExpansion:
    """Coefficients of the outgoing vector spherical-wave expansion of a field (lab frame).

    Attributes
    ----------
    k : float
        Wavenumber in the medium, rad/um.
    p, q : ndarray, shape (L+1, 2L+1)
        Coefficients of ``N_nm`` and ``M_nm`` at ``[n, m + L]`` (row n = 0 unused).
    radius_um : float
        Radius of the sphere about the origin that contains the sources; the expansion is
        valid outside it.
    """

    k: float
    p: NDArray[np.complex128]
    q: NDArray[np.complex128]
    radius_um: float

    @property
    def order(self) -> int:
        return self.p.shape[0] - 1

    def spherical_components(
        self, r: NDArray, theta: NDArray, far: bool = False
    ) -> tuple[NDArray, NDArray, NDArray]:
        """Per-m components ``E_r^m, E_th^m, E_ph^m`` (npts, 2L+1) at (r, theta).

        The field is ``sum_m E^m exp(i m phi)``. With ``far`` the asymptotic radial forms are
        used (and ``E_r = 0``); the factor ``exp(ikr)/(kr)`` is then included as well.
        """
        L = self.order
        kr = self.k * np.asarray(r, dtype=float)
        h, dx, hk = _radial(np.ascontiguousarray(kr), L, far)
        pf, df, mf = _full_tables(np.cos(theta), L)
        n_idx = slice(1, L + 1)
        p, q = self.p[n_idx], self.q[n_idx]  # (L, 2L+1)
        h, dx, hk = h[:, n_idx, None], dx[:, n_idx, None], hk[:, n_idx, None]
        pf, df, mf = pf[:, n_idx], df[:, n_idx], mf[:, n_idx]
        e_r = np.sum(p * hk * pf, axis=1)
        e_t = np.sum(p * dx * df + 1j * q * h * mf, axis=1)
        e_p = np.sum(1j * p * dx * mf - q * h * df, axis=1)
        return e_r, e_t, e_p

    def field_at(self, points: NDArray, far: bool = False) -> NDArray[np.complex128]:
        """Field (N, 3), lab Cartesian, at points (N, 3) relative to the expansion centre
        (compiled series sum, blocks of ``POINT_BLOCK`` points: O(N L^2))."""
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        r = np.linalg.norm(pts, axis=1)
        theta = np.arccos(np.clip(pts[:, 2] / r, -1.0, 1.0))
        phi = np.arctan2(pts[:, 1], pts[:, 0])
        L = self.order
        sph = np.empty((pts.shape[0], 3), dtype=complex)
        p, q = np.ascontiguousarray(self.p), np.ascontiguousarray(self.q)
        for start in range(0, pts.shape[0], POINT_BLOCK):
            sl = slice(start, start + POINT_BLOCK)
            h, dx, hk = _radial(np.ascontiguousarray(self.k * r[sl]), L, far)
            pb, dp, mp = legendre_tables(np.ascontiguousarray(np.cos(theta[sl])), L)
            _sum_points(p, q, h, dx, hk, pb, dp, mp, np.ascontiguousarray(phi[sl]), sph[sl])
        er, et, ep = sph[:, 0], sph[:, 1], sph[:, 2]
        st, ct, sp, cp = np.sin(theta), np.cos(theta), np.sin(phi), np.cos(phi)
        return np.stack(
            [er * st * cp + et * ct * cp - ep * sp,
             er * st * sp + et * ct * sp + ep * cp,
             er * ct - et * st],
            axis=1,
        )

    def far_amplitude(self, directions: ArrayLike) -> NDArray[np.complex128]:
        """Far-field pattern ``A(n) = lim kr exp(-ikr) E(r n)`` (N, 3) at unit directions."""
        d = np.atleast_2d(np.asarray(directions, dtype=float))
        r = 1.0 / self.k  # kr = 1: the far form then carries exp(i)/1
        e = self.field_at(d * r, far=True)
        return e * np.exp(-1j)


def quadrature(lmax: int, extra: int = 6) -> tuple[NDArray, NDArray, NDArray]:
    """Gauss-Legendre nodes/weights in cos(theta) and uniform phi, exact to degree ~2L."""
    n_theta = lmax + 1 + extra
    n_phi = 2 * lmax + 2 + 2 * extra
    mu, w = np.polynomial.legendre.leggauss(n_theta)
    phi = 2.0 * np.pi * np.arange(n_phi) / n_phi
    return mu, w, phi


def quadrature_directions(mu: NDArray, phi: NDArray) -> NDArray[np.float64]:
    """Unit directions of the (theta, phi) quadrature grid, shape (n_theta * n_phi, 3)."""
    st = np.sqrt(1.0 - mu**2)
    return np.stack(
        [np.outer(st, np.cos(phi)), np.outer(st, np.sin(phi)),
         np.repeat(mu[:, None], phi.size, axis=1)], axis=-1
    ).reshape(-1, 3)


def project_far_field(
    a: NDArray[np.complex128], mu: NDArray, w: NDArray, phi: NDArray, lmax: int
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Coefficients ``p, q`` ([n, m + L]) of a far-field pattern sampled on the quadrature grid.

    Parameters
    ----------
    a : ndarray, shape (n_theta, n_phi, 3)
        ``A(n)`` (Cartesian) at the directions of :func:`quadrature_directions`.
    mu, w, phi : ndarray
        The grid of :func:`quadrature`.
    lmax : int
        Highest order.
    """
    n_t, n_p = mu.size, phi.size
    st = np.sqrt(1.0 - mu**2)
    cp, sp = np.cos(phi), np.sin(phi)
    e_t = np.stack([np.outer(mu, cp), np.outer(mu, sp), np.repeat(-st[:, None], n_p, 1)], -1)
    e_p = np.stack([np.repeat(-sp[None, :], n_t, 0), np.repeat(cp[None, :], n_t, 0),
                    np.zeros((n_t, n_p))], -1)
    a_t = np.sum(a * e_t, axis=-1)
    a_p = np.sum(a * e_p, axis=-1)
    # Fourier coefficients over phi: f^m = (1/N) sum_j f_j exp(-i m phi_j)
    ft = np.fft.fft(a_t, axis=1) / n_p
    fp = np.fft.fft(a_p, axis=1) / n_p
    L = lmax
    m = np.arange(-L, L + 1)
    ft_m, fp_m = ft[:, m % n_p], fp[:, m % n_p]  # (n_t, 2L+1)
    _, df, mf = _full_tables(mu, L)  # (n_t, L+1, 2L+1)
    wt = 2.0 * np.pi * w[:, None, None]
    phi_proj = np.sum(wt * (ft_m[:, None, :] * df - fp_m[:, None, :] * 1j * mf), axis=0)
    x_proj = np.sum(wt * (-ft_m[:, None, :] * 1j * mf - fp_m[:, None, :] * df), axis=0)
    n = np.arange(L + 1)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        norm = np.where(n > 0, 1.0 / (n * (n + 1.0)), 0.0)
    p = (1j**n) * norm * phi_proj
    q = (1j ** (n + 1)) * norm * x_proj
    valid = np.abs(m)[None, :] <= n
    p = np.where(valid, p, 0.0)
    q = np.where(valid, q, 0.0)
    p[0] = 0.0
    q[0] = 0.0
    return p, q


def expansion_from_far_field(
    amplitude: Callable[[NDArray], NDArray], k: float, lmax: int, radius_um: float,
) -> MultipoleExpansion:
    """Project a far-field pattern onto vector spherical harmonics.

    Parameters
    ----------
    amplitude : callable
        ``directions (M, 3) -> A (M, 3)``: ``A(n) = lim kr exp(-ikr) E(r n)``.
    k : float
        Wavenumber, rad/um.
    lmax : int
        Highest order kept.
    radius_um : float
        Radius of the sources' circumscribing sphere (recorded for validity checks).
    """
    mu, w, phi = quadrature(lmax)
    a = amplitude(quadrature_directions(mu, phi)).reshape(mu.size, phi.size, 3)
    p, q = project_far_field(a, mu, w, phi, lmax)
    return MultipoleExpansion(k=k, p=p, q=q, radius_um=radius_um)


# -- fast evaluation on a camera plane -------------------------------------------------------

#: Lagrange stencil (points per axis) and grid step as a fraction of the shortest period of the
#: band-limited U (degree 2L+2 in theta, L+1 in phi): 8 points at 0.7 keep the interpolation
#: far below the solvers' tolerance (docs: validation, "the DDA"). The
#: interpolation kernel (:func:`holofit.scattering.lens_kernels.polar_interpolate`, shared with
#: the lens image) is compiled for 8 (a constant trip count is what makes it fast).
STENCIL = POLAR_STENCIL
STEP_FACTOR = 0.7


@dataclass
class PlaneGrid:
    """``U = kr exp(-ikr) E_{x,y}`` of a field on a plane, sampled on a (delta, phi) grid.

    ``delta`` is the angle from the downward (or upward, for ``z_p < 0``) vertical through the
    expansion centre; row ``i`` holds ``delta = (i - n_ext) * step`` (rows ``< n_ext`` are the
    reflection through the pole, ``U(-delta, phi) = U(delta, phi + pi)``).
    """

    ux: NDArray[np.complex128]
    uy: NDArray[np.complex128]
    step: float
    delta_max: float
    stencil: int
    n_phi: int
    n_ext: int
    z_p: float
    k: float

    @property
    def packed(self) -> NDArray[np.float64]:
        """``(Re U_x, Im U_x, Re U_y, Im U_y)`` as four real planes, shape
        (4, rows, n_phi + 2 stencil), columns shifted by ``stencil`` and wrapped, so that
        interpolation needs no modulo (planes of reals: each stencil sum runs over contiguous
        doubles)."""
        cached = self.__dict__.get("_packed")
        if cached is None:
            pad = self.stencil
            cols = (np.arange(self.n_phi + 2 * pad) - pad) % self.n_phi
            cached = np.empty((4, self.ux.shape[0], cols.size))
            for c, u in enumerate((self.ux, self.uy)):
                wrapped = u[:, cols]
                cached[2 * c] = wrapped.real
                cached[2 * c + 1] = wrapped.imag
            self.__dict__["_packed"] = cached
        return cached


@lru_cache(maxsize=16)
def _legendre_coefficients(lmax: int) -> tuple[NDArray, ...]:
    """Recurrence coefficients of :func:`holofit.scattering.legendre.legendre_tables` (per
    order)."""
    L = lmax
    a = np.zeros((L + 1, L + 1))
    b = np.zeros((L + 1, L + 1))
    c = np.zeros((L + 1, L + 1))
    for n in range(2, L + 1):
        a[n, 0] = np.sqrt((4.0 * n * n - 1.0) / (n * n))
        b[n, 0] = np.sqrt(((n - 1.0) ** 2) * (2.0 * n + 1.0) / (n * n * (2.0 * n - 3.0)))
    for m in range(1, L + 1):
        for n in range(m + 2, L + 1):
            a[n, m] = np.sqrt((4.0 * n * n - 1.0) / (n * n - m * m))
            b[n, m] = np.sqrt(((n - 1.0) ** 2 - m * m) * (2.0 * n + 1.0)
                              / ((n * n - m * m) * (2.0 * n - 3.0)))
        for n in range(m, L + 1):
            c[n, m] = np.sqrt((n * n - m * m) * (2.0 * n + 1.0) / (2.0 * n - 1.0))
    ms = np.arange(L + 1)
    sect = np.zeros(L + 1)
    sect[1:] = -np.sqrt((2.0 * ms[1:] + 1.0) / (2.0 * ms[1:]))
    return a, b, c, sect


@numba.njit(cache=True, nogil=True)
def _plane_fourier(p, q, mu, radial, recurrences, n_ext, n_phi, out_x,
                   out_y):  # pragma: no cover - compiled
    """Fourier coefficients over phi of ``U_x, U_y`` on every grid row (and the reflected
    rows ``i < n_ext``), from the expansion ``p, q`` ([n, m + L]); ``radial`` is ``(h, dx,
    hk, fac)`` per row, ``recurrences`` the Legendre coefficients ``(a, b, c, sect)``.

    Per row: the Legendre recurrences at ``mu = cos th``; the per-m spherical components
    ``E_r, E_th, E_ph``; then ``E_x = rho cos ph - E_ph sin ph``, ``E_y = rho sin ph +
    E_ph cos ph`` (``rho = E_r sin th + E_th cos th``) as shifts ``m -> m +- 1``.
    """
    h, dx, hk, fac = radial
    rec_a, rec_b, rec_c, sect = recurrences
    L = p.shape[0] - 1
    pb = np.zeros((L + 1, L + 1))
    dp = np.zeros((L + 1, L + 1))
    mp = np.zeros((L + 1, L + 1))
    u = np.zeros((L + 2, L + 1))
    rho = np.zeros(2 * L + 3, dtype=np.complex128)
    eph = np.zeros(2 * L + 3, dtype=np.complex128)
    p0 = np.sqrt(1.0 / (4.0 * np.pi))
    for i in range(mu.shape[0]):
        x = mu[i]
        s = np.sqrt(max(0.0, 1.0 - x * x))
        # Legendre tables (Condon-Shortley, orthonormal), as holofit.scattering.legendre
        pb[0, 0] = p0
        if L >= 1:
            pb[1, 0] = np.sqrt(3.0) * x * p0
        for n in range(2, L + 1):
            pb[n, 0] = rec_a[n, 0] * x * pb[n - 1, 0] - rec_b[n, 0] * pb[n - 2, 0]
        if L >= 1:
            u[1, 1] = -np.sqrt(1.5) * p0
            for m in range(2, L + 1):
                u[m, m] = sect[m] * s * u[m - 1, m - 1]
            for m in range(1, L + 1):
                if m + 1 <= L:
                    u[m + 1, m] = np.sqrt(2.0 * m + 3.0) * x * u[m, m]
                for n in range(m + 2, L + 1):
                    u[n, m] = rec_a[n, m] * x * u[n - 1, m] - rec_b[n, m] * u[n - 2, m]
            for m in range(1, L + 1):
                for n in range(m, L + 1):
                    pb[n, m] = s * u[n, m]
                    mp[n, m] = m * u[n, m]
                    prev = u[n - 1, m] if n - 1 >= m else 0.0
                    dp[n, m] = n * x * u[n, m] - rec_c[n, m] * prev
            for n in range(1, L + 1):
                dp[n, 0] = np.sqrt(n * (n + 1.0)) * pb[n, 1]
        # per-m spherical components, combined into rho and E_ph at index m + L + 1
        for m in range(-L, L + 1):
            mm = abs(m)
            sign = 1.0 if (m >= 0 or mm % 2 == 0) else -1.0
            msign = sign if m >= 0 else -sign
            ar = 0.0 + 0.0j
            at = 0.0 + 0.0j
            ap = 0.0 + 0.0j
            for n in range(max(1, mm), L + 1):
                pc = p[n, m + L]
                qc = q[n, m + L]
                pf = sign * pb[n, mm]
                df = sign * dp[n, mm]
                mf = msign * mp[n, mm]
                ar += pc * hk[i, n] * pf
                pdx = pc * dx[i, n]
                qh = qc * h[i, n]
                at += pdx * df + 1j * qh * mf
                ap += 1j * pdx * mf - qh * df
            rho[m + L + 1] = ar * s + at * x
            eph[m + L + 1] = ap
        f = fac[i]
        for m in range(-L - 1, L + 2):
            k = m + L + 1
            rm = rho[k - 1] if k >= 1 else 0.0j
            rp = rho[k + 1] if k + 1 <= 2 * L + 2 else 0.0j
            em = eph[k - 1] if k >= 1 else 0.0j
            ep = eph[k + 1] if k + 1 <= 2 * L + 2 else 0.0j
            ux = (0.5 * (rm + rp) + 0.5j * (em - ep)) * f
            uy = (-0.5j * (rm - rp) + 0.5 * (em + ep)) * f
            col = m % n_phi
            out_x[n_ext + i, col] = ux
            out_y[n_ext + i, col] = uy
            if 1 <= i <= n_ext:
                sgn = 1.0 if m % 2 == 0 else -1.0
                out_x[n_ext - i, col] = sgn * ux
                out_y[n_ext - i, col] = sgn * uy


def plane_grid(
    expansion: MultipoleExpansion, z_p: float, delta_max: float, far: bool = False
) -> PlaneGrid:
    """Sample ``U`` on the plane ``Z = -z_p`` (relative to the expansion centre).

    Parameters
    ----------
    expansion : MultipoleExpansion
        The field.
    z_p : float
        Height of the expansion centre above the plane, um (non-zero; negative: below).
    delta_max : float
        Largest angle from the vertical that the pixels need, rad.
    far : bool
        Use the asymptotic (far-field) radial dependence.
    """
    if z_p == 0:
        raise ValueError("the particle centre lies in the detector plane (z = 0)")
    L = expansion.order
    k = expansion.k
    if delta_max >= np.pi / 2 - 1e-3:
        raise ValueError(
            f"pixels up to {np.degrees(delta_max):.2f} deg off the vertical through the particle:"
            " too close to grazing for the plane grid"
        )
    # grid step: the band-limit rule, finer if needed to keep the stencil rows below 90 deg
    step = min(STEP_FACTOR / (2 * L + 2), (np.pi / 2 - delta_max) / (STENCIL // 2 + 3))
    n_phi = int(np.ceil(2 * np.pi * (L + 1) / STEP_FACTOR / 2.0)) * 2
    n_ext = STENCIL
    # rows 1..n_ext also feed the reflected rows below the pole
    n_rows = max(int(np.ceil(delta_max / step)) + STENCIL // 2 + 2, n_ext + 1)
    delta = np.arange(n_rows) * step
    r = abs(z_p) / np.cos(delta)
    mu = -np.cos(delta) if z_p > 0 else np.cos(delta)  # cos(theta), theta = pi -+ delta
    h, dxr, hk = _radial(np.ascontiguousarray(k * r), L, far)
    # U = kr exp(-ikr) E: smooth (the far mode's radial factors carry exp(ikr)/(kr) too)
    fac = k * r * np.exp(-1j * k * r)
    ux = np.zeros((n_ext + n_rows, n_phi), dtype=complex)
    uy = np.zeros_like(ux)
    _plane_fourier(np.ascontiguousarray(expansion.p), np.ascontiguousarray(expansion.q), mu,
                   (h, dxr, hk, fac), _legendre_coefficients(L), n_ext, n_phi, ux, uy)
    ux = np.fft.ifft(ux, axis=1, norm="forward")
    uy = np.fft.ifft(uy, axis=1, norm="forward")
    return PlaneGrid(ux=ux, uy=uy, step=step, delta_max=float(delta_max), stencil=STENCIL,
                     n_phi=n_phi, n_ext=n_ext, z_p=float(z_p), k=k)


def evaluate_plane(
    grid: PlaneGrid, xs: NDArray, ys: NDArray, xp: float, yp: float,
    phase: complex = 1.0, skip: NDArray | None = None,
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Transverse field ``(E_x, E_y)`` at pixel centres (columns ``xs``, rows ``ys``, um).

    ``(xp, yp)`` is the lateral position of the expansion centre; ``phase`` multiplies the
    result (the incident phase at the particle); pixels where ``skip`` is True are left 0.
    """
    dx = np.broadcast_to(np.asarray(xs, dtype=float)[None, :] - xp, (ys.size, xs.size))
    dy = np.broadcast_to(np.asarray(ys, dtype=float)[:, None] - yp, (ys.size, xs.size))
    return evaluate_plane_at(grid, dx, dy, phase, skip)


def evaluate_plane_at(
    grid: PlaneGrid, dx: NDArray, dy: NDArray, phase: complex = 1.0,
    skip: NDArray | None = None,
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Transverse field ``(E_x, E_y)`` at arbitrary points of the plane.

    ``dx, dy`` (any equal shapes) are the lateral offsets of the points from the expansion
    centre, um; ``phase`` multiplies the result; points where ``skip`` is True are left 0.
    """
    return evaluate_planes_at([grid], dx, dy, phase, skip)[0]


def evaluate_planes_at(
    grids: Sequence[PlaneGrid], dx: NDArray, dy: NDArray, phase: complex = 1.0,
    skip: NDArray | None = None,
) -> list[tuple[NDArray[np.complex128], NDArray[np.complex128]]]:
    """:func:`evaluate_plane_at` for several fields whose grids share one geometry (same
    plane, step, azimuths and rows: expansions of one order, built for the same ``z_p`` and
    ``delta_max``), in one pass over the points."""
    g0 = grids[0]
    for g in grids[1:]:
        if (g.ux.shape, g.step, g.n_phi, g.n_ext, g.z_p, g.k, g.stencil) != (
                g0.ux.shape, g0.step, g0.n_phi, g0.n_ext, g0.z_p, g0.k, g0.stencil):
            raise ValueError("plane grids of different geometry cannot be evaluated together")
    shape = np.shape(dx)
    dx1 = np.ascontiguousarray(dx, dtype=float).ravel()
    dy1 = np.ascontiguousarray(dy, dtype=float).ravel()
    ex = np.zeros((len(grids), dx1.size), dtype=complex)
    ey = np.zeros_like(ex)
    skip1 = (np.zeros(dx1.size, dtype=np.bool_) if skip is None
             else np.ascontiguousarray(skip, dtype=np.bool_).ravel())
    gs = g0.packed[None] if len(grids) == 1 else np.stack([g.packed for g in grids])
    # per-point angles and the exact exp(ikr)/kr (vectorised transcendental functions)
    az = abs(g0.z_p)
    rho2 = dx1 * dx1 + dy1 * dy1
    delta = np.arctan2(np.sqrt(rho2), az)
    phi = np.arctan2(dy1, dx1)
    phi[phi < 0.0] += 2.0 * np.pi
    kr = g0.k * np.sqrt(rho2 + az * az)
    fac = (np.cos(kr) + 1j * np.sin(kr)) * (complex(phase) / kr)
    t = delta / g0.step + g0.n_ext
    u = phi / (2.0 * np.pi / g0.n_phi)
    polar_interpolate(gs, t, u, g0.stencil, fac, skip1, ex, ey)
    return [(ex[f].reshape(shape), ey[f].reshape(shape)) for f in range(len(grids))]
