"""The invariant imbedding T-matrix method for bodies of revolution (one block per ``m``).

``T(r)``, the T-matrix of the part of the particle inside the sphere of radius ``r`` (the
medium outside it), obeys a Riccati equation in ``r`` (Johnson 1988, Appl. Opt. 27, 4861; Bi,
Yang, Kattawar & Mishchenko 2013, JQSRT 116, 169). Derived here in the basis of
:mod:`holofit.scattering.vsw`: with ``E = sum A Y r^ + B Psi + C Phi`` and the same for
``H' = Z H`` (``curl E = i k H'``, ``curl H' = -i k eps E``), the tangential unknowns
``X = (u, v, s, w) = r (B, C, B_H, C_H)`` of one ``m`` obey ``X' = (K_0 + dK) X``, where
``K_0`` is the medium's and

    du' = -(i / k r^2) (Y_r - I) nu^2 s,
    ds' =  i k nu^-2 (<Psi eps Psi> - nu^2) u + i k nu^-2 <Psi eps Phi> v,
    dw' = -i k nu^-2 <Phi eps Psi> u - i k nu^-2 (<Phi eps Phi> - nu^2) v,

with ``nu^2 = n (n + 1)`` and the angular matrices of
:mod:`holofit.scattering.axisym.angular` (Laurent's direct product, or the inverse rule for the
polar field at conical interfaces); ``Y_r - I = (I + Y)^-1 - I`` eliminates the radial field
(``D_r = eps E_r``; Laurent's rule for the product of ``eps`` and the continuous ``E_r`` at a
polar-angle boundary). In the medium the regular and outgoing waves of order ``n`` give
``X = (psi'/k, 0, i psi/k, 0)`` for ``N`` and ``(0, -psi/k, 0, -i psi'/k)`` for ``M``
(``psi = kr j_n``, or ``xi = kr h_n`` for outgoing waves), so ``F = [W_rg, W_out]`` is inverted
per order through the Wronskian ``psi xi' - psi' xi = i``. Writing the field inside ``r`` as
``Z = W_rg + W_out T`` and asking that it be carried by the full equation gives

    T' = (G_out - T G_rg) dK (W_rg + W_out T),    [G_rg; G_out] = F^-1,

started from the Lorenz-Mie T-matrix of the largest homogeneous sphere about the centre
(``T = diag(-a_n, -b_n)``) and integrated outward with the classical Runge-Kutta method in a
variable that makes the square-root ends of the boundary angle ``theta_b(r)`` smooth
(``r = r_0 + (r_1 - r_0)(3 s^2 - 2 s^3)`` per segment), and Richardson's extrapolation of two
step sizes (order 5 and better). (Integrating ``T / (psi_n psi_n')``-like scaled variables
instead makes the decaying components stiff: RK4 then diverges at the step sizes that suffice
for ``T``.) ``T`` stays bounded (``|I + 2T| <= 1`` in the flux-normalised basis), so the
integration is stable at any order, unlike the transfer matrix of the fields themselves.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from holofit.scattering.axisym.angular import angular_matrices
from holofit.scattering.axisym.bessel import riccati_bessel
from holofit.scattering.axisym.profiles import Profile
from holofit.scattering.mie_coefficients import mie_coefficients

__all__ = ["BUCKET_COST", "Groups", "IITMResult", "block_orders", "integrate_profile",
           "m_buckets", "make_groups", "mie_start"]

#: the fixed cost of integrating one run of ``m`` apart (:func:`m_buckets`), in units of
#: the padded work of one group matrix of size 1: that of one group of size 44 (a run's own
#: calls, radial functions and the small products' lower speed; the fastest setting
#: measured for the paper's Janus particle at orders 28 and 36)
BUCKET_COST = 44.0 ** 3


def block_orders(order: int) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Orders ``n[m, i] = max(1, m) + i`` of the padded blocks (``m = 0..L``, ``i < L``) and
    which of them exist (``n <= L``)."""
    L = order
    m = np.arange(L + 1)[:, None]
    n = np.maximum(1, m) + np.arange(L)[None, :]
    return n, n <= L


def mie_start(order: int, k: float, radius: float, index_rel: complex) -> NDArray:
    """Padded blocks ``(L + 1, 2L, 2L)`` of a homogeneous sphere's T-matrix."""
    L = order
    n, valid = block_orders(L)
    a, b = mie_coefficients(index_rel, k * radius, L)
    t = np.zeros((L + 1, 2 * L, 2 * L), dtype=complex)
    idx = np.arange(L)
    nn = np.where(valid, n, 1)
    t[:, idx, idx] = np.where(valid, -a[nn - 1], 0.0)
    t[:, L + idx, L + idx] = np.where(valid, -b[nn - 1], 0.0)
    return t


@dataclass(frozen=True)
class Groups:
    """The coupled sets of unknowns the integration runs on.

    Without symmetry a group is one ``m`` (all ``N`` and ``M`` orders). An up-down symmetric
    body also keeps the parity under ``z -> -z``: ``N_n`` with ``n + m`` even couples only to
    ``N`` of the same and ``M`` of the other parity, so each ``m`` splits into two groups of
    half the size (a quarter of the work). Group ``g`` has ``P`` padded ``N`` slots (block
    positions ``pos_n[g]``, orders ``n_n[g]``) and ``Q`` padded ``M`` slots.
    """

    m: NDArray[np.int64]
    n_n: NDArray[np.int64]
    n_m: NDArray[np.int64]
    ok_n: NDArray[np.bool_]
    ok_m: NDArray[np.bool_]
    pos_n: NDArray[np.int64]
    pos_m: NDArray[np.int64]

    @property
    def sizes(self) -> tuple[int, int]:
        return self.n_n.shape[1], self.n_m.shape[1]


def make_groups(order: int, parity: bool, ms: Sequence[int] | None = None) -> Groups:
    """The groups (:class:`Groups`) of order ``L`` for the orders ``m`` in ``ms`` (default
    ``0..L``), split by parity or not."""
    L = order
    rows: list[tuple[int, list[int], list[int]]] = []
    for m in (range(L + 1) if ms is None else ms):
        orders = list(range(max(1, m), L + 1))
        if not parity:
            rows.append((m, orders, orders))
            continue
        even = [n for n in orders if (n + m) % 2 == 0]
        odd = [n for n in orders if (n + m) % 2 == 1]
        rows.append((m, even, odd))
        rows.append((m, odd, even))
    p = max(1, max(len(r[1]) for r in rows))
    q = max(1, max(len(r[2]) for r in rows))
    g = len(rows)
    n_n = np.ones((g, p), dtype=np.int64)
    n_m = np.ones((g, q), dtype=np.int64)
    ok_n = np.zeros((g, p), dtype=bool)
    ok_m = np.zeros((g, q), dtype=bool)
    pos_n = np.zeros((g, p), dtype=np.int64)
    pos_m = np.zeros((g, q), dtype=np.int64)
    for i, (m, on, om) in enumerate(rows):
        n0 = max(1, m)
        n_n[i, : len(on)] = on
        n_m[i, : len(om)] = om
        ok_n[i, : len(on)] = True
        ok_m[i, : len(om)] = True
        pos_n[i, : len(on)] = np.asarray(on, dtype=np.int64) - n0
        pos_m[i, : len(om)] = L + np.asarray(om, dtype=np.int64) - n0
    return Groups(np.array([r[0] for r in rows]), n_n, n_m, ok_n, ok_m, pos_n, pos_m)


def to_groups(padded: NDArray, groups: Groups) -> NDArray:
    """Group matrices ``(G, P + Q, P + Q)`` from padded per-``m`` blocks."""
    pos = np.concatenate([groups.pos_n, groups.pos_m], axis=1)
    ok = np.concatenate([groups.ok_n, groups.ok_m], axis=1)
    out = padded[groups.m[:, None, None], pos[:, :, None], pos[:, None, :]]
    return out * (ok[:, :, None] & ok[:, None, :])


def from_groups(tg: NDArray, groups: Groups, order: int) -> NDArray:
    """Padded per-``m`` blocks ``(L + 1, 2L, 2L)`` from group matrices."""
    L = order
    out = np.zeros((L + 1, 2 * L, 2 * L), dtype=complex)
    pos = np.concatenate([groups.pos_n, groups.pos_m], axis=1)
    ok = np.concatenate([groups.ok_n, groups.ok_m], axis=1)
    for g in range(tg.shape[0]):
        sel = np.nonzero(ok[g])[0]
        p = pos[g, sel]
        out[groups.m[g]][np.ix_(p, p)] += tg[g][np.ix_(sel, sel)]
    return out


class _Rhs:
    """The Riccati right-hand side of one profile and order (module docstring)."""

    def __init__(self, profile: Profile, order: int, k: float, n_medium: float,
                 groups: Groups, radial_rule: str = "laurent",
                 polar_rule: str = "laurent",
                 angular_cache: dict[tuple, tuple[NDArray, ...]] | None = None
                 ) -> None:
        self.profile = profile
        self.L = order
        self.k = k
        self.n_medium = n_medium
        self.rule = radial_rule
        self.polar_rule = polar_rule
        self._angular_cache = {} if angular_cache is None else angular_cache
        self._gathered: dict[tuple, tuple[NDArray, ...]] = {}
        self.groups = groups
        n, valid = block_orders(order)
        self.valid = valid
        self.nu2 = np.where(valid, n * (n + 1.0), 1.0)
        self.evaluations = 0
        self.matrix_evaluations = 0
        gm = groups.m
        n0 = np.maximum(1, gm)[:, None]
        self._in = np.where(groups.ok_n, groups.n_n - n0, 0)  # block index of N slots
        self._im = np.where(groups.ok_m, groups.n_m - n0, 0)
        self._mask_nn = groups.ok_n[:, :, None] & groups.ok_n[:, None, :]
        self._mask_mm = groups.ok_m[:, :, None] & groups.ok_m[:, None, :]
        self._mask_nm = groups.ok_n[:, :, None] & groups.ok_m[:, None, :]

    def matrices(self, r: float) -> tuple[NDArray, ...]:
        """Group matrices ``D1`` (N, N), ``D2`` (N, N), ``D5`` (M, M), ``D3`` (N, M) and
        ``D4`` (M, N): ``D1 = -(i/k r^2)(Y_r - I) nu^2``, ``D2 = i k nu^-2 <Psi eps Psi>``,
        ``D3 = i k nu^-2 <Psi eps Phi>``, ``D4 = -i k nu^-2 <Phi eps Psi>``,
        ``D5 = -i k nu^-2 <Phi eps Phi>`` (deviations from the medium)."""
        d1n, d2n, d5m, d3nm, d4mn, _ = self._lookup(r)
        return (-1j / (self.k * r * r)) * d1n, d2n, d5m, d3nm, d4mn

    def _lookup(self, r: float) -> tuple[NDArray, ...]:
        """:meth:`_gather`'s matrices of the intervals at ``r`` (kept per set of intervals)."""
        self.matrix_evaluations += 1
        intervals = self.profile.intervals(r, self.n_medium)
        key = tuple((round(lo, 15), round(hi, 15), e) for lo, hi, e in intervals)
        gathered = self._gathered.get(key)
        if gathered is None:
            gathered = self._gather(key, intervals)
            if len(self._gathered) < 64:
                self._gathered[key] = gathered
        return gathered

    def _gather(self, key: tuple, intervals: list) -> tuple[NDArray, ...]:
        """The group matrices of :meth:`matrices` for one set of intervals, ``D1`` without its
        factor ``-i / (k r^2)`` (the only one that depends on ``r`` itself), and the ``s`` and
        ``w`` rows of ``dK`` assembled, ``[[D2, -D3], [D4, -D5]] / k``."""
        L = self.L
        cached = self._angular_cache.get(key)
        if cached is None:
            mats = angular_matrices(intervals, L, self.polar_rule)
            if self.rule == "inverse":  # Y_r = [[1/eps]]
                yr = angular_matrices([(lo, hi, 1.0 / e) for lo, hi, e in intervals], L).yy
            else:
                eye = np.eye(L)[None]
                yr = np.linalg.inv(eye + mats.yy) - eye
                yr = yr * self.valid[:, :, None] * self.valid[:, None, :]
            k = self.k
            nu2 = self.nu2
            cached = (yr * nu2[:, None, :], (1j * k) * mats.psipsi / nu2[:, :, None],
                      (1j * k) * mats.psiphi / nu2[:, :, None],
                      (-1j * k) * mats.phipsi / nu2[:, :, None],
                      (-1j * k) * mats.phiphi / nu2[:, :, None])
            if len(self._angular_cache) < 64:
                self._angular_cache[key] = cached
        d1, d2, d3, d4, d5 = cached
        k = self.k
        gm = self.groups.m[:, None, None]
        i_n, i_m = self._in, self._im
        d1n = d1[gm, i_n[:, :, None], i_n[:, None, :]] * self._mask_nn
        d2n = d2[gm, i_n[:, :, None], i_n[:, None, :]] * self._mask_nn
        d5m = d5[gm, i_m[:, :, None], i_m[:, None, :]] * self._mask_mm
        d3nm = d3[gm, i_n[:, :, None], i_m[:, None, :]] * self._mask_nm
        d4mn = d4[gm, i_m[:, :, None], i_n[:, None, :]] * self._mask_nm.transpose(0, 2, 1)
        p = d1n.shape[1]
        dsw = np.empty((d1n.shape[0], p + d5m.shape[1], p + d5m.shape[1]), dtype=complex)
        dsw[:, :p, :p] = d2n / k
        dsw[:, :p, p:] = d3nm / -k
        dsw[:, p:, :p] = d4mn / k
        dsw[:, p:, p:] = d5m / -k
        return d1n, d2n, d5m, d3nm, d4mn, dsw

    def radial(self, r: float) -> tuple[NDArray, ...]:
        """``psi, psi', xi, xi'`` at ``k r`` on the N slots and the M slots (zero on padding)."""
        psi, dpsi, xi, dxi = riccati_bessel(self.L, self.k * r)
        g = self.groups
        on = [np.where(g.ok_n, f[g.n_n], 0.0) for f in (psi, dpsi, xi, dxi)]
        om = [np.where(g.ok_m, f[g.n_m], 0.0) for f in (psi, dpsi, xi, dxi)]
        return (*on, *om)

    def prepare(self, r: float, scale: float = 1.0) -> Stage:
        """The products of one radius that every right-hand side at ``r`` shares
        (:class:`Stage`), with ``dT/dr`` scaled by ``scale`` (the smoothing map's
        ``dr/ds``)."""
        d1n, _, _, _, _, dsw = self._lookup(r)
        psi_n, dpsi_n, xi_n, dxi_n, psi_m, _dpsi_m, xi_m, _dxi_m = self.radial(r)
        k = self.k
        # V = [v_u; v_s; v_w] = dK Z with Z = W_rg + W_out T (module docstring):
        # v_u = (i/k) D1 (xi_n T_N + [psi_n, 0]) with D1 = -(i/k r^2) d1n,
        # [v_s; v_w] = dsw ([dxi_n T_N; xi_m T_M] + [dpsi_n, psi_m]) (columns scaled)
        coef = scale / (k * k * r * r)
        e1 = d1n * (coef * xi_n)[:, None, :]
        f = dsw * (scale * np.concatenate([dxi_n, xi_m], axis=1))[:, None, :]
        # dT/dr = A V - T (B V): rows of A and B, per slot (N: from v_u and v_s; M: from v_w)
        return Stage(e1, f, d1n, coef * psi_n, dsw,
                     scale * np.concatenate([dpsi_n, psi_m], axis=1),
                     (-1j * k) * psi_n, k * dpsi_n, k * psi_m,
                     (1j * k) * xi_n, -k * dxi_n, -k * xi_m)

    def __call__(self, t: NDArray, stage: Stage) -> NDArray:
        """``dT/dr`` (times the stage's scale) for group matrices ``t`` at the radius of
        ``stage`` (:meth:`prepare`)."""
        self.evaluations += 1
        p = stage.e1.shape[1]
        vu = np.matmul(stage.e1, t[:, :p])
        vsw = np.matmul(stage.f, t)
        g = np.empty_like(t)
        _constants_and_rows(vu, vsw, stage.d1, stage.c1, stage.dsw, stage.csw, stage.b_u,
                            stage.b_s, stage.b_w, g)
        out = np.matmul(t, g)
        _rows_minus(vu, vsw, stage.a_u, stage.a_s, stage.a_w, out)
        return out


@dataclass(frozen=True)
class Stage:
    """What the right-hand sides at one radius share (:meth:`_Rhs.prepare`): the ``u`` rows
    of ``V`` are ``e1 T_N + d1 diag(c1)`` (on the ``N`` columns), its ``s`` and ``w`` rows
    ``f T + dsw diag(csw)``; ``a_*`` and ``b_*`` are the row factors of ``A`` and ``B`` in
    ``dT/dr = A V - T B V``."""

    e1: NDArray
    f: NDArray
    d1: NDArray
    c1: NDArray
    dsw: NDArray
    csw: NDArray
    a_u: NDArray
    a_s: NDArray
    a_w: NDArray
    b_u: NDArray
    b_s: NDArray
    b_w: NDArray


@numba.njit(cache=True, nogil=True)
def _constants_and_rows(vu, vsw, d1, c1, dsw, csw, b_u, b_s, b_w, g):  # pragma: no cover
    """Adds the constant parts to ``V`` in place (``vu[:, :, :p] += d1 diag(c1)``, ``vsw +=
    dsw diag(csw)``) and writes ``g = B V``."""
    ng, p, ncol = vu.shape
    q = vsw.shape[1] - p
    for a in range(ng):
        for i in range(p):
            for j in range(p):
                vu[a, i, j] += d1[a, i, j] * c1[a, j]
        for i in range(p + q):
            for j in range(ncol):
                vsw[a, i, j] += dsw[a, i, j] * csw[a, j]
        for i in range(p):
            bu = b_u[a, i]
            bs = b_s[a, i]
            for j in range(ncol):
                g[a, i, j] = bu * vu[a, i, j] + bs * vsw[a, i, j]
        for i in range(q):
            bw = b_w[a, i]
            for j in range(ncol):
                g[a, p + i, j] = bw * vsw[a, p + i, j]


@numba.njit(cache=True, nogil=True)
def _rows_minus(vu, vsw, a_u, a_s, a_w, out):  # pragma: no cover - compiled
    """``out = A V - out`` in place (``out`` holding ``T B V``)."""
    ng, p, ncol = vu.shape
    q = vsw.shape[1] - p
    for a in range(ng):
        for i in range(p):
            au = a_u[a, i]
            as_ = a_s[a, i]
            for j in range(ncol):
                out[a, i, j] = au * vu[a, i, j] + as_ * vsw[a, i, j] - out[a, i, j]
        for i in range(q):
            aw = a_w[a, i]
            for j in range(ncol):
                out[a, p + i, j] = aw * vsw[a, p + i, j] - out[a, p + i, j]


@numba.njit(cache=True, nogil=True)
def _axpy(y, a, x):  # pragma: no cover - compiled
    """``y + a x`` (one pass)."""
    return y + a * x


def _rk4_sum(t: NDArray, c: float, k1: NDArray | None, k2: NDArray, k3: NDArray,
             k4: NDArray | None) -> NDArray:
    """``t + c (k1 + 2 k2 + 2 k3 + k4)``, a missing ``k`` being zero."""
    acc = _axpy(k2, 1.0, k3)
    acc *= 2.0
    if k1 is not None:
        acc += k1
    if k4 is not None:
        acc += k4
    return _axpy(t, c, acc)


def _smooth_map(s: float) -> tuple[float, float]:
    """``g(s) = 3 s^2 - 2 s^3`` and ``g'(s)``."""
    return s * s * (3.0 - 2.0 * s), 6.0 * s * (1.0 - s)


def _rk4_segment(rhs: _Rhs, t: NDArray, r0: float, r1: float, steps: int,
                 cache: dict[float, Stage | None]) -> NDArray:
    """Classical Runge-Kutta over one segment in the smoothing variable ``s`` (``cache``: the
    stages of this segment by ``s``, shared by Richardson's two passes)."""
    width = r1 - r0
    h = 1.0 / steps

    def stage(s: float) -> Stage | None:
        key = round(s, 14)
        if key not in cache:
            g, dg = _smooth_map(s)
            cache[key] = None if dg == 0.0 else rhs.prepare(r0 + width * g, width * dg)
        return cache[key]

    for i in range(steps):
        s = i * h
        s0, s_mid, s1 = stage(s), stage(s + h / 2), stage(s + h)
        assert s_mid is not None
        # k1 vanishes at the segment's start (dr/ds = 0) and k4 at its end
        k1 = None if s0 is None else rhs(t, s0)
        k2 = rhs(t if k1 is None else _axpy(t, h / 2, k1), s_mid)
        k3 = rhs(_axpy(t, h / 2, k2), s_mid)
        k4 = None if s1 is None else rhs(_axpy(t, h, k3), s1)
        t = _rk4_sum(t, h / 6.0, k1, k2, k3, k4)
    return t


@dataclass
class IITMResult:
    """Blocks ``(L + 1, 2L, 2L)`` for ``m = 0..L`` and what the integration did."""

    blocks: NDArray[np.complex128]
    steps: list[int]
    evaluations: int
    matrix_evaluations: int
    richardson_change: float


def integrate_profile(profile: Profile, order: int, k: float, n_medium: float,
                      steps: Callable[[float, float], int] | list[int],
                      richardson: bool = True, radial_rule: str = "laurent",
                      parity: bool | None = None, polar_rule: str = "laurent") -> IITMResult:
    """The T-matrix blocks of ``profile`` by invariant imbedding.

    Parameters
    ----------
    profile : Profile
        The body.
    order : int
        Truncation order ``L``.
    k : float
        Wavenumber in the medium, rad/um.
    n_medium : float
        Refractive index of the medium.
    steps : callable or list of int
        Runge-Kutta steps of each segment (``steps(r0, r1)`` or one number per segment).
    richardson : bool
        Also integrate with half the steps and extrapolate (``(16 T_h - T_2h) / 15``).
    radial_rule : {"laurent", "inverse"}
        How the radial field is eliminated (module docstring).
    parity : bool, optional
        Split by the parity under ``z -> -z`` (:class:`Groups`); by default when the profile
        is mirror-symmetric.
    """
    L = order
    split = bool(profile.mirror_symmetric) if parity is None else parity
    start = mie_start(L, k, profile.r_start, complex(profile.index_start) / n_medium)
    segs = list(itertools.pairwise(profile.breaks()))
    counts = ([int(steps(a, b)) for a, b in segs] if callable(steps)
              else [int(v) for v in steps])
    if richardson:
        counts = [c + (c % 2) for c in counts]
    blocks = np.zeros_like(start)
    angular: dict[tuple, tuple[NDArray, ...]] = {}
    change, evaluations, matrix_evaluations = 0.0, 0, 0
    for ms in m_buckets(L, split):
        groups = make_groups(L, split, ms)
        rhs = _Rhs(profile, L, k, n_medium, groups, radial_rule, polar_rule, angular)
        fine = coarse = to_groups(start, groups)
        for (a, b), c in zip(segs, counts, strict=True):
            cache: dict[float, Stage | None] = {}
            fine = _rk4_segment(rhs, fine, a, b, c, cache)
            if richardson:
                coarse = _rk4_segment(rhs, coarse, a, b, c // 2, cache)
        out = fine
        if richardson and segs:
            out = fine + (fine - coarse) / 15.0
            change = max(change, float(np.abs(out - fine).max()))
        blocks += from_groups(out, groups, L)
        evaluations += rhs.evaluations
        matrix_evaluations += rhs.matrix_evaluations
    return IITMResult(blocks, counts, evaluations, matrix_evaluations, change)


def m_buckets(order: int, parity: bool = False) -> list[range]:
    """The orders ``m = 0..L`` in runs integrated apart: the ``m`` are independent, and a
    run's matrices are padded only to its own largest block (``2 (L - max(1, m) + 1)``, the
    run's first ``m``), not to ``2 L``. The runs minimise the padded work, the sum over runs
    of their groups times the cube of their largest size, plus :data:`BUCKET_COST` per run
    (the fixed cost of a run's calls, in the same units), by dynamic programming."""
    L = order
    per_m = 2 if parity else 1
    size = [2 * (L - max(1, m) + 1) // per_m for m in range(L + 1)]
    # best[b]: least cost of m = 0..b-1; cut[b]: where its last run starts
    best = [0.0] + [math.inf] * (L + 1)
    cut = [0] * (L + 2)
    for b in range(1, L + 2):
        for a in range(b):
            cost = best[a] + per_m * (b - a) * float(size[a]) ** 3 + BUCKET_COST
            if cost < best[b]:
                best[b], cut[b] = cost, a
    runs = []
    b = L + 1
    while b > 0:
        runs.append(range(cut[b], b))
        b = cut[b]
    return runs[::-1]
