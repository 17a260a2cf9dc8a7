"""An independent extended-precision EBCM for homogeneous bodies of revolution (a reference
for tests and benchmarks only; not used by holofit).

Written apart from :mod:`holofit.scattering.axisym` (its own basis, special functions,
quadrature and linear algebra), in 80-bit long double (``numpy.longdouble``, 64-bit mantissa,
about 19 digits), so that the paper's rod, whose EBCM surface integrals lose about nine digits,
can be taken to higher orders than double precision allows.

Basis (time ``exp(-i w t)``): with ``Pt_n^m = sqrt((n-m)!/(n+m)!) P_n^{|m|}(cos th)`` (no
Condon-Shortley phase), ``pi = m Pt / sin th``, ``tau = d Pt / d th``,

    M_mn = z_n(kr) (i pi th^ - tau ph^) e^{i m ph},
    N_mn = n(n+1) z_n/(kr) Pt e^{i m ph} r^ + [kr z_n]'/(kr) (tau th^ + i pi ph^) e^{i m ph},

vector angular norm ``h_n = 4 pi n(n+1)/(2n+1)``. Incident ``E = sum p RgM + q RgN``, scattered
``sum a M + b N``, internal ``sum c RgM(k1 r) + d RgN(k1 r)``. The Stratton-Chu extinction
theorem with ``G = i k sum [M (x) RgM~ + N (x) RgN~] / h_n`` (``~``: angular part conjugated)
gives ``[a; b] = RgQ [c; d]``, ``-[p; q] = Q [c; d]``, so ``T = -RgQ Q^-1``, with, per ``m``,

    Q_ac = (ik/h_n) (k1 I[M~_n, N1_n'] + k I[N~_n, M1_n']),
    Q_ad = (ik/h_n) (k1 I[M~, M1] + k I[N~, N1]),
    Q_bc = (ik/h_n) (k1 I[N~, N1] + k I[M~, M1]),
    Q_bd = (ik/h_n) (k1 I[N~, M1] + k I[M~, N1]),
    I[X, Y] = 2 pi int_0^pi sin th (r^2 (Y x X)_r - r r_th (Y x X)_th) dth,

outgoing ``X`` (``h_n``) for ``Q``, regular for ``RgQ``. Plane wave of direction ``k^`` and
polarisation ``e``: ``p = 4 pi i^n e.C~(k^) / h_n``, ``q = 4 pi i^(n-1) e.B~(k^) / h_n`` with
``C = (i pi th^ - tau ph^) e^{i m ph}``, ``B = (tau th^ + i pi ph^) e^{i m ph}``. Far field
``kr exp(-ikr) E -> sum a (-i)^(n+1) C + b (-i)^n B``.

The angular integrals run on Gauss-Legendre nodes between the profile's kinks; each ``m`` is
solved by Gaussian elimination with partial pivoting in long double, on an equilibrated ``Q``,
the two parity classes of a mirror-symmetric body apart.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

LD = np.longdouble
CLD = np.clongdouble

_I_POWERS = np.array([1, 1j, -1, -1j], dtype=CLD)  # i^k, k = 0..3

__all__ = ["LongDoubleEBCM", "capsule", "cylinder", "gauss_legendre", "spheroid"]


# -- surfaces r(theta), r'(theta) in long double ----------------------------------------------


@dataclass(frozen=True)
class Surface:
    """A body of revolution's surface ``r(theta)`` with its kinks and mirror symmetry."""

    kind: str
    p1: float
    p2: float

    @property
    def kinks(self) -> list[LD]:
        if self.kind == "spheroid":
            return []
        radius, half = LD(self.p1), LD(self.p2)
        if self.kind == "capsule":
            half = half - radius  # half-length of the cylindrical part
        t = np.arctan2(radius, half)
        return [t, LD(np.pi) - t] if half > 0 else []

    @property
    def r_max(self) -> float:
        if self.kind == "spheroid":
            return max(self.p1, self.p2)
        if self.kind == "capsule":
            return self.p2
        return float(np.hypot(self.p1, self.p2))

    def radius(self, th: NDArray) -> tuple[NDArray, NDArray]:
        """``r(theta)`` and ``dr/dtheta`` (long double)."""
        st, ct = np.sin(th), np.cos(th)
        if self.kind == "spheroid":
            a, c = LD(self.p1), LD(self.p2)
            r = 1 / np.sqrt(st * st / (a * a) + ct * ct / (c * c))
            return r, -r**3 * st * ct * (1 / (a * a) - 1 / (c * c))
        radius, half = LD(self.p1), LD(self.p2)
        if self.kind == "capsule":
            half = half - radius
        side = np.abs(ct) * radius <= st * half  # the cylindrical part
        sgn = np.sign(ct)
        r = np.empty_like(th)
        dr = np.empty_like(th)
        r[side] = radius / st[side]
        dr[side] = -radius * ct[side] / st[side] ** 2
        e = ~side
        if self.kind == "cylinder":
            r[e] = half / np.abs(ct[e])
            dr[e] = sgn[e] * half * st[e] / ct[e] ** 2
        else:  # spherical cap of radius ``radius`` centred at z = +-half
            root = np.sqrt(radius * radius - half * half * st[e] ** 2)
            r[e] = half * np.abs(ct[e]) + root
            dr[e] = -sgn[e] * half * st[e] - half * half * st[e] * ct[e] / root
        return r, dr


def spheroid(a_um: float, c_um: float) -> Surface:
    """Spheroid of equatorial semi-axis ``a`` and polar ``c``, um."""
    return Surface("spheroid", a_um, c_um)


def cylinder(radius_um: float, half_length_um: float) -> Surface:
    """Flat-ended cylinder, um."""
    return Surface("cylinder", radius_um, half_length_um)


def capsule(a_um: float, b_um: float) -> Surface:
    """Spherocylinder of cap radius ``a`` and half tip-to-tip length ``b``, um."""
    return Surface("capsule", a_um, b_um)


# -- special functions in long double ---------------------------------------------------------


def gauss_legendre(n: int) -> tuple[NDArray, NDArray]:
    """Gauss-Legendre nodes and weights on (-1, 1), Newton-refined in long double."""
    x0, _ = np.polynomial.legendre.leggauss(n)
    x = x0.astype(LD)
    for _ in range(4):
        p0, p1 = np.ones_like(x), x.copy()
        for k in range(2, n + 1):
            p0, p1 = p1, ((2 * k - 1) * x * p1 - (k - 1) * p0) / k
        dp = n * (x * p1 - p0) / (x * x - 1)
        x = x - p1 / dp
    p0, p1 = np.ones_like(x), x.copy()
    for k in range(2, n + 1):
        p0, p1 = p1, ((2 * k - 1) * x * p1 - (k - 1) * p0) / k
    dp = n * (x * p1 - p0) / (x * x - 1)
    return x, 2 / ((1 - x * x) * dp * dp)


def angular(x: NDArray, m: int, order: int) -> tuple[NDArray, NDArray, NDArray]:
    """``Pt_n^m``, ``pi_mn`` and ``tau_mn`` (module docstring), arrays ``[n, node]`` for
    ``n = 0..order`` (zero below ``|m|``); nodes off the poles."""
    am = abs(m)
    s = np.sqrt(1 - x * x)
    pt = np.zeros((order + 1, x.size), dtype=LD)
    u = np.zeros_like(pt)  # Pt / sin
    if am == 0:
        pt[0] = 1
        if order >= 1:
            pt[1] = x
        for n in range(2, order + 1):
            pt[n] = ((2 * n - 1) * x * pt[n - 1] - (n - 1) * pt[n - 2]) / n
    else:
        c = np.sqrt(np.prod([LD(2 * i - 1) / LD(2 * i) for i in range(1, am + 1)]))
        u[am] = c * s ** (am - 1)
        if am + 1 <= order:
            u[am + 1] = np.sqrt(LD(2 * am + 1)) * x * u[am]
        for n in range(am + 2, order + 1):
            u[n] = ((2 * n - 1) * x * u[n - 1]
                    - np.sqrt(LD((n - 1) ** 2 - am * am)) * u[n - 2]) / np.sqrt(LD(n * n - am * am))
        pt = s * u
    tau = np.zeros_like(pt)
    if am == 0:  # d Pt_n / d th = -sqrt(n (n+1)) Pt_n^1, finite at the poles
        _, pi1, _ = angular(x, 1, order)
        nn = np.arange(order + 1).astype(LD)[:, None]
        return pt, np.zeros_like(pt), -np.sqrt(nn * (nn + 1)) * s * pi1
    for n in range(max(am, 1), order + 1):
        prev = u[n - 1] if n - 1 >= am else 0
        tau[n] = n * x * u[n] - np.sqrt(LD(n * n - am * am)) * prev
    return pt, m * u, tau


def spherical_bessel(x: NDArray, order: int, outgoing: bool) -> tuple[NDArray, NDArray]:
    """``z_n(x)`` and ``[x z_n(x)]' / x`` for ``n = 0..order``, arrays ``[n, node]``, real
    ``x`` in long double: ``j_n`` by Miller's downward recurrence normalised to ``sin x / x``;
    with ``outgoing``, ``h_n = j_n + i y_n``, ``y_n`` by the upward recurrence."""
    x = np.asarray(x, dtype=LD)
    start = order + 30 + int(np.max(x))
    j = np.zeros((start + 2, x.size), dtype=LD)
    j[start + 1] = 0
    j[start] = LD(1e-300)
    for n in range(start, 0, -1):
        j[n - 1] = (2 * n + 1) / x * j[n] - j[n + 1]
        big = np.abs(j[n - 1]) > LD(1e300)
        if np.any(big):
            j[:, big] *= LD(1e-300)
    j0 = np.sin(x) / x
    j1 = np.sin(x) / (x * x) - np.cos(x) / x
    use0 = np.abs(j0) >= np.abs(j1)  # normalise on the larger of j_0, j_1
    j = j[: order + 2] * np.where(use0, j0 / np.where(use0, j[0], 1), j1 / np.where(use0, 1, j[1]))
    z = j.astype(CLD)
    if outgoing:
        y = np.zeros_like(j)
        y[0] = -np.cos(x) / x
        y[1] = -np.cos(x) / (x * x) - np.sin(x) / x
        for n in range(1, order + 1):
            y[n + 1] = (2 * n + 1) / x * y[n] - y[n - 1]
        z = j + 1j * y.astype(CLD)
    n = np.arange(1, order + 1)[:, None]
    dz = np.zeros((order + 1, x.size), dtype=CLD)
    dz[1:] = z[: order] - n * z[1 : order + 1] / x
    dz[0] = -z[1]
    return z[: order + 1], dz


def _solve(a: NDArray, b: NDArray) -> NDArray:
    """``a^-1 b`` by Gaussian elimination with partial pivoting (complex long double)."""
    a = a.copy()
    b = b.copy()
    n = a.shape[0]
    for col in range(n):
        piv = col + int(np.argmax(np.abs(a[col:, col])))
        if piv != col:
            a[[col, piv]] = a[[piv, col]]
            b[[col, piv]] = b[[piv, col]]
        f = a[col + 1 :, col] / a[col, col]
        a[col + 1 :, col:] -= f[:, None] * a[col, col:][None, :]
        b[col + 1 :] -= f[:, None] * b[col][None, :]
    x = np.zeros_like(b)
    for row in range(n - 1, -1, -1):
        x[row] = (b[row] - a[row, row + 1 :] @ x[row + 1 :]) / a[row, row]
    return x


# -- the T-matrix ---------------------------------------------------------------------------


class LongDoubleEBCM:
    """T-matrix of a homogeneous body of revolution, per ``m``, in the module's basis.

    Parameters
    ----------
    surface : Surface
        :func:`spheroid`, :func:`cylinder` or :func:`capsule`.
    m_rel : float
        Relative refractive index (real).
    k : float
        Wavenumber in the medium, rad/um.
    order : int
        Truncation ``n <= L``.
    nodes : int, optional
        Gauss-Legendre nodes per piece between kinks (default ``2 L + 40``).
    blocks : list of ndarray, optional
        The blocks of ``m = 0..L`` of an earlier build of the same body (a cache), instead of
        building them.
    """

    def __init__(self, surface: Surface, m_rel: float, k: float, order: int,
                 nodes: int | None = None, blocks: list[NDArray] | None = None) -> None:
        self.surface, self.order = surface, int(order)
        self.k, self.m_rel = float(k), float(m_rel)
        self.nodes = int(nodes or 2 * order + 40)
        self.mirror = surface.kind in ("spheroid", "cylinder", "capsule")
        self.blocks = blocks or [self._block(m) for m in range(self.order + 1)]

    def _quadrature(self) -> tuple[NDArray, NDArray]:
        cuts = [LD(0), *self.surface.kinks, LD(np.pi)]
        gx, gw = gauss_legendre(self.nodes)
        th, w = [], []
        for a, b in itertools.pairwise(cuts):
            th.append((a + b) / 2 + (b - a) / 2 * gx)
            w.append((b - a) / 2 * gw)
        return np.concatenate(th), np.concatenate(w)

    def _block(self, m: int) -> NDArray:
        L, k = self.order, LD(self.k)
        k1 = k * LD(self.m_rel)
        th, w = self._quadrature()
        r, dr = self.surface.radius(th)
        st = np.sin(th)
        wr = 2 * LD(np.pi) * w * st * r * r  # weight of the radial component of n dS
        wt = -2 * LD(np.pi) * w * st * r * dr  # of the polar component
        pt, pi_, tau = angular(np.cos(th), m, L)
        n = np.arange(max(1, m), L + 1)
        nn = (n * (n + 1)).astype(LD)[:, None]
        pt, pi_, tau = pt[n], pi_[n], tau[n]

        def waves(z, dz, kr, conj):
            s = -1 if conj else 1
            zz, dd = z[n], dz[n]
            mw = (np.zeros_like(zz), s * 1j * pi_ * zz, -tau * zz)
            nw = (nn * zz / kr * pt, dd * tau, s * 1j * dd * pi_)
            return mw, nw

        def integral(x, y):
            xr, xt, xp = x
            yr, yt, yp = y
            cross_r = yt[None, :, :] * xp[:, None, :] - yp[None, :, :] * xt[:, None, :]
            cross_t = yp[None, :, :] * xr[:, None, :] - yr[None, :, :] * xp[:, None, :]
            return (cross_r * wr + cross_t * wt).sum(axis=2)  # [n_out, n_in]

        kr, k1r = k * r, k1 * r
        inner_m, inner_n = waves(*spherical_bessel(k1r, L + 1, False), k1r, False)
        mats = []
        for outgoing in (False, True):
            om, on = waves(*spherical_bessel(kr, L + 1, outgoing), kr, True)
            top = np.hstack([k1 * integral(om, inner_n) + k * integral(on, inner_m),
                             k1 * integral(om, inner_m) + k * integral(on, inner_n)])
            bottom = np.hstack([k1 * integral(on, inner_n) + k * integral(om, inner_m),
                                k1 * integral(on, inner_m) + k * integral(om, inner_n)])
            h = 4 * LD(np.pi) * nn[:, 0] / (2 * n + 1)
            pref = np.concatenate([1j * k / h, 1j * k / h])
            mats.append(pref[:, None] * np.vstack([top, bottom]))
        rgq, q = mats
        return self._t_of(q, rgq, n, m)

    def _t_of(self, q: NDArray, rgq: NDArray, n: NDArray, m: int) -> NDArray:
        """``-RgQ Q^-1``, equilibrated, by parity class for mirror-symmetric bodies."""
        cnt = n.size
        t = np.zeros_like(q)
        classes = [np.arange(2 * cnt)]
        if self.mirror:
            parity = np.concatenate([(n + m) % 2, (n + m + 1) % 2])
            classes = [np.flatnonzero(parity == c) for c in (0, 1)]
        for sel in classes:
            if sel.size == 0:
                continue
            qq, rr = q[np.ix_(sel, sel)], rgq[np.ix_(sel, sel)]
            dc = 1 / np.abs(qq).max(axis=0)
            qs = qq * dc[None, :]
            dr_ = 1 / np.abs(qs).max(axis=1)
            qs = qs * dr_[:, None]
            # T = -RgQ Q^-1 = -(RgQ Dc)(Dr Q Dc)^-1 Dr: solve (Dr Q Dc)^T X^T = (RgQ Dc)^T
            x = _solve(qs.T, (rr * dc[None, :]).T).T
            t[np.ix_(sel, sel)] = -x * dr_[None, :]
        return t

    def block(self, m: int) -> NDArray:
        """The block of ``m`` (rows and columns: ``M``-type ``n = max(1,|m|)..L``, then
        ``N``-type), complex long double; ``-m`` by the body's mirror symmetry in ``y = 0``
        (the ``M``-``N`` couplings change sign)."""
        b = self.blocks[abs(m)]
        if m >= 0:
            return b
        out = b.copy()
        h = b.shape[0] // 2
        out[:h, h:] *= -1
        out[h:, :h] *= -1
        return out

    # -- plane waves and the far field (particle frame) --------------------------------------

    def _vectors(self, dirs: NDArray, m: int) -> tuple[NDArray, NDArray, NDArray]:
        """``C`` and ``B`` (``[n, point, 3]``, Cartesian) of order ``m`` at unit ``dirs``."""
        d = np.asarray(dirs, dtype=LD)
        th = np.arccos(np.clip(d[:, 2], -1, 1))
        ph = np.arctan2(d[:, 1], d[:, 0])
        _, pi_, tau = angular(np.cos(th), m, self.order)
        n = np.arange(max(1, abs(m)), self.order + 1)
        pi_, tau = pi_[n], tau[n]
        ct, st, cp, sp = np.cos(th), np.sin(th), np.cos(ph), np.sin(ph)
        th_hat = np.stack([ct * cp, ct * sp, -st], axis=-1)
        ph_hat = np.stack([-sp, cp, np.zeros_like(sp)], axis=-1)
        e = np.exp(1j * m * ph.astype(CLD))[None, :, None]
        c = (1j * pi_[..., None] * th_hat - tau[..., None] * ph_hat) * e
        b = (tau[..., None] * th_hat + 1j * pi_[..., None] * ph_hat) * e
        return c, b, n

    def amplitude(self, k_in: NDArray, e_in: NDArray, dirs: NDArray) -> NDArray:
        """``lim kr exp(-ikr) E_s`` (Cartesian, ``(N, 3)``, complex128) at unit ``dirs`` for
        the plane wave ``e_in exp(i k k_in . r)``, all in the particle frame."""
        k_in = np.asarray(k_in, dtype=LD)[None, :]
        e_in = np.asarray(e_in, dtype=CLD)
        out = np.zeros((len(dirs), 3), dtype=CLD)
        for m in range(-self.order, self.order + 1):
            ci, bi, n = self._vectors(k_in, m)
            h = 4 * LD(np.pi) * (n * (n + 1)).astype(LD) / (2 * n + 1)
            i_n = _I_POWERS[n % 4]
            p = 4 * LD(np.pi) * i_n * (np.conj(ci[:, 0]) @ e_in) / h
            q = 4 * LD(np.pi) * i_n / 1j * (np.conj(bi[:, 0]) @ e_in) / h
            ab = self.block(m) @ np.concatenate([p, q])
            cnt = n.size
            co, bo, _ = self._vectors(dirs, m)
            mi = _I_POWERS[(3 * (n + 1)) % 4]  # (-i)^(n+1)
            ni = _I_POWERS[(3 * n) % 4]
            out += np.einsum("n,npc->pc", ab[:cnt] * mi, co)
            out += np.einsum("n,npc->pc", ab[cnt:] * ni, bo)
        return out.astype(np.complex128)
