"""Compiled inner loops of the objective-lens image (numba).

Kept apart from :mod:`holofit.scattering.lens` so that the physics there reads as array code:

* :func:`bessel_table`: ``J_m(x)`` for ``m = 0..M`` at many arguments (forward recurrence where
  it is stable, ``m <= x``; Miller's backward recurrence above, matched at ``m = floor(x)``);
* :func:`sphere_pixels`: the image of a sphere at a list of pixels from two radial tables
  (azimuthal orders 0 and 2 only);
* :func:`polar_interpolate`: any image from its samples on a polar ``(rho, phi)`` grid (an
  8 x 8 Lagrange stencil, :data:`POLAR_STENCIL`), several fields at once, with a factor and a
  mask per point: the multipole plane grid of :mod:`holofit.scattering.multipole`;
  :func:`polar_pixels` is its one-field loop for the lens image (same weights and sums).

The callers pass each pixel's fractional row ``t = rho / h + n_ext`` (radial tables sampled at
``rho_j = (j - n_ext) h``, rows ``j < n_ext`` holding negative ``rho``, the point reflection, so
that a stencil needs no special case at the centre) and, on the polar grid, its fractional
column. Interpolation is Lagrange on ``stencil`` nodes in each direction.
"""

from __future__ import annotations

import numba
import numpy as np

FASTMATH = {"contract", "reassoc", "nsz", "arcp"}
#: the polar grid's interpolation stencil, fixed at compile time (:func:`polar_pixels`)
POLAR_STENCIL = 8


@numba.njit(cache=True, nogil=True)
def bessel_table(x, j0, j1, mmax, out):  # pragma: no cover - compiled
    """``out[p, m] = J_m(x[p])`` for ``m = 0..mmax``, given ``J_0`` and ``J_1`` at ``x >= 0``.

    Forward recurrence ``J_{m+1} = (2m/x) J_m - J_{m-1}`` is stable for ``m < x``; above, the
    backward recurrence from a start order ``mmax + sqrt(160 mmax) + 12`` (any scale) is
    matched to the forward value at ``m = floor(x)``, where ``J_m(x)`` is positive and of order
    ``m^(-1/3)``, far from its zeros.
    """
    npts = x.shape[0]
    start = mmax + int(np.sqrt(160.0 * max(mmax, 1))) + 12
    back = np.empty(start + 2)
    for p in range(npts):
        xv = x[p]
        out[p, 0] = j0[p]
        if mmax >= 1:
            out[p, 1] = j1[p]
        if xv == 0.0:
            for m in range(1, mmax + 1):
                out[p, m] = 0.0
            continue
        m_fwd = min(int(xv), mmax)
        for m in range(1, m_fwd):
            out[p, m + 1] = 2.0 * m / xv * out[p, m] - out[p, m - 1]
        if m_fwd >= mmax:
            continue
        # backward from `start` down to m_fwd (>= 0), rescaled to the forward value there
        back[start + 1] = 0.0
        back[start] = 1e-300
        for m in range(start, m_fwd, -1):
            back[m - 1] = 2.0 * m / xv * back[m] - back[m + 1]
            if abs(back[m - 1]) > 1e250:  # rescale to avoid overflow
                for q in range(m - 1, start + 2):
                    back[q] *= 1e-250
        scale = out[p, m_fwd] / back[m_fwd]
        for m in range(m_fwd + 1, mmax + 1):
            out[p, m] = back[m] * scale


@numba.njit(cache=True, nogil=True, inline="always")
def _weights(t, n, c, w):  # pragma: no cover - compiled
    """Lagrange weights at ``t`` for nodes ``0..n-1``: ``w[a] = c[a] prod_{b != a} (t - b)``
    with ``c[a] = 1/prod_{b != a} (a - b)`` (prefix and suffix products, no division)."""
    acc = 1.0
    for a in range(n):
        w[a] = acc
        acc *= t - a
    acc = 1.0
    for a in range(n - 1, -1, -1):
        w[a] *= acc * c[a]
        acc *= t - a


@numba.njit(cache=True, nogil=True)
def _node_factors(n):  # pragma: no cover - compiled
    c = np.empty(n)
    for a in range(n):
        v = 1.0
        for b in range(n):
            if b != a:
                v *= a - b
        c[a] = 1.0 / v
    return c


@numba.njit(cache=True, nogil=True, fastmath=FASTMATH)
def sphere_pixels(t, cq, sq, cb, sb, g0, g2, stencil, ex, ey):  # pragma: no cover - compiled
    """``E_x = cb g0(rho) + cq g2(rho)``, ``E_y = sb g0(rho) + sq g2(rho)`` at pixels, by
    Lagrange interpolation of the radial tables at fractional rows ``t`` (``cb, sb`` scalars,
    ``cq, sq`` per pixel)."""
    n = t.shape[0]
    half = stencil // 2 - 1
    c = _node_factors(stencil)
    w = np.empty(stencil)
    for q in range(n):
        i0 = int(t[q]) - half
        _weights(t[q] - i0, stencil, c, w)
        a = 0.0 + 0.0j
        b = 0.0 + 0.0j
        for s in range(stencil):
            a += w[s] * g0[i0 + s]
            b += w[s] * g2[i0 + s]
        ex[q] = cb * a + cq[q] * b
        ey[q] = sb * a + sq[q] * b


@numba.njit(cache=True, nogil=True, fastmath=FASTMATH, inline="always")
def _stencil(plane, i0, j0, wr, wp):  # pragma: no cover - compiled
    """``sum_a wr[a] sum_b wp[b] plane[i0 + a, j0 + b]`` over the fixed 8 x 8 stencil (a
    constant trip count lets the compiler unroll and vectorise the inner sum)."""
    s = 0.0
    for a in range(8):
        r = 0.0
        for b in range(8):
            r += wp[b] * plane[i0 + a, j0 + b]
        s += wr[a] * r
    return s


@numba.njit(cache=True, nogil=True, fastmath=FASTMATH)
def polar_interpolate(gs, t, u, pad, fac, skip, ex, ey):  # pragma: no cover - compiled
    """Lagrange interpolation (8 x 8 stencil) of polar grids at fractional rows ``t`` and
    columns ``u``: the one interpolator of the lens image and of the multipole plane grid.

    ``gs`` holds ``F`` fields of one geometry, each as four real planes ``(Re E_x, Im E_x,
    Re E_y, Im E_y)``, shape ``(F, 4, rows, columns)``: planes of reals let each stencil sum
    run over contiguous doubles (3-4x faster than complex pairs). Columns are padded (the grid
    repeats its period on both sides, ``pad`` columns before column 0 that ``u`` does not
    count), so that a stencil never wraps. The weights are computed once per point for all
    fields. ``fac`` (length 0: none) multiplies each point's result; points where ``skip``
    (length 0: none) is True are left as they are. ``ex, ey`` have shape ``(F, points)``.
    """
    n = t.shape[0]
    half = POLAR_STENCIL // 2 - 1
    c = _node_factors(POLAR_STENCIL)
    wr = np.empty(POLAR_STENCIL)
    wp = np.empty(POLAR_STENCIL)
    has_fac = fac.shape[0] > 0
    has_skip = skip.shape[0] > 0
    for q in range(n):
        if has_skip and skip[q]:
            continue
        i0 = int(t[q]) - half
        _weights(t[q] - i0, POLAR_STENCIL, c, wr)
        j0 = int(u[q]) - half
        _weights(u[q] - j0, POLAR_STENCIL, c, wp)
        j0 += pad
        for f in range(gs.shape[0]):
            vx = complex(_stencil(gs[f, 0], i0, j0, wr, wp), _stencil(gs[f, 1], i0, j0, wr, wp))
            vy = complex(_stencil(gs[f, 2], i0, j0, wr, wp), _stencil(gs[f, 3], i0, j0, wr, wp))
            if has_fac:
                vx *= fac[q]
                vy *= fac[q]
            ex[f, q] = vx
            ey[f, q] = vy


@numba.njit(cache=True, nogil=True, fastmath=FASTMATH)
def polar_pixels(t, u, g, ex, ey):  # pragma: no cover - compiled
    """:func:`polar_interpolate` of one grid ``g`` (shape ``(4, rows, columns)``, columns
    already padded in ``u``), without factor or mask: the lens image's loop, with the same
    weights and stencil sums, its planes taken out of the pixel loop (the several-field loop
    of :func:`polar_interpolate` is 20-25 % slower for one field, measured)."""
    n = t.shape[0]
    half = POLAR_STENCIL // 2 - 1
    c = _node_factors(POLAR_STENCIL)
    wr = np.empty(POLAR_STENCIL)
    wp = np.empty(POLAR_STENCIL)
    g0, g1, g2, g3 = g[0], g[1], g[2], g[3]
    for q in range(n):
        i0 = int(t[q]) - half
        _weights(t[q] - i0, POLAR_STENCIL, c, wr)
        j0 = int(u[q]) - half
        _weights(u[q] - j0, POLAR_STENCIL, c, wp)
        ex[q] = complex(_stencil(g0, i0, j0, wr, wp), _stencil(g1, i0, j0, wr, wp))
        ey[q] = complex(_stencil(g2, i0, j0, wr, wp), _stencil(g3, i0, j0, wr, wp))
