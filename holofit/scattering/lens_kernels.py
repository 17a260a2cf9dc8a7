"""Compiled inner loops of the objective-lens image (numba).

Kept apart from :mod:`holofit.scattering.lens` so that the physics there reads as array code:

* :func:`bessel_table`: ``J_m(x)`` for ``m = 0..M`` at many arguments (forward recurrence where
  it is stable, ``m <= x``; Miller's backward recurrence above, matched at ``m = floor(x)``),
  and :func:`bessel_planes`, the same stored order-major;
* :func:`sphere_pixels`: the image of a sphere at a list of pixels from two radial tables
  (azimuthal orders 0 and 2 only);
* :func:`polar_interpolate`: any image from its samples on a polar ``(rho, phi)`` grid (an
  8 x 8 Lagrange stencil, :data:`POLAR_STENCIL`), several fields at once, with a factor and a
  mask per point: the multipole plane grid of :mod:`holofit.scattering.multipole`;
  :func:`polar_pixels` is its one-field loop for the lens image (same weights, the four
  planes interleaved: :func:`~holofit.scattering.lens_transform.polar_grids`' layout), with
  :func:`polar_coordinates`, the pixels' fractional rows and columns there, and
  :func:`polar_spectrum`, the grid's azimuthal spectrum before its FFT.

The callers pass each pixel's fractional row ``t = rho / h + n_ext`` (radial tables sampled at
``rho_j = (j - n_ext) h``, rows ``j < n_ext`` holding negative ``rho``, the point reflection, so
that a stencil needs no special case at the centre) and, on the polar grid, its fractional
column. Interpolation is Lagrange on ``stencil`` nodes in each direction.
"""

from __future__ import annotations

import numba
import numpy as np

FASTMATH = {"contract", "reassoc", "nsz", "arcp"}
#: unsigned index type (no negative-index wrap-around in compiled indexing)
_U = np.uint64
#: the polar grid's interpolation stencil, fixed at compile time (:func:`polar_pixels`)
POLAR_STENCIL = 8


@numba.njit(cache=True, nogil=True, inline="always")
def _bessel_point(xv, j0v, j1v, mmax, start, back, col):  # pragma: no cover - compiled
    """``col[m] = J_m(xv)`` for ``m = 0..mmax`` (see :func:`bessel_table`)."""
    col[0] = j0v
    if mmax >= 1:
        col[1] = j1v
    if xv == 0.0:
        for m in range(1, mmax + 1):
            col[m] = 0.0
        return
    m_fwd = min(int(xv), mmax)
    for m in range(1, m_fwd):
        col[m + 1] = 2.0 * m / xv * col[m] - col[m - 1]
    if m_fwd >= mmax:
        return
    # backward from `start` down to m_fwd (>= 0), rescaled to the forward value there
    back[start + 1] = 0.0
    back[start] = 1e-300
    for m in range(start, m_fwd, -1):
        back[m - 1] = 2.0 * m / xv * back[m] - back[m + 1]
        if abs(back[m - 1]) > 1e250:  # rescale to avoid overflow
            for q in range(m - 1, start + 2):
                back[q] *= 1e-250
    scale = col[m_fwd] / back[m_fwd]
    for m in range(m_fwd + 1, mmax + 1):
        col[m] = back[m] * scale


@numba.njit(cache=True, nogil=True)
def bessel_table(x, j0, j1, mmax, out):  # pragma: no cover - compiled
    """``out[p, m] = J_m(x[p])`` for ``m = 0..mmax``, given ``J_0`` and ``J_1`` at ``x >= 0``.

    Forward recurrence ``J_{m+1} = (2m/x) J_m - J_{m-1}`` is stable for ``m < x``; above, the
    backward recurrence from a start order ``mmax + sqrt(160 mmax) + 12`` (any scale) is
    matched to the forward value at ``m = floor(x)``, where ``J_m(x)`` is positive and of order
    ``m^(-1/3)``, far from its zeros.
    """
    start = mmax + int(np.sqrt(160.0 * max(mmax, 1))) + 12
    back = np.empty(start + 2)
    for p in range(x.shape[0]):
        _bessel_point(x[p], j0[p], j1[p], mmax, start, back, out[p])


@numba.njit(cache=True, nogil=True)
def bessel_planes(x, j0, j1, mmax, out):  # pragma: no cover - compiled
    """``out[m, p] = J_m(x[p])``: :func:`bessel_table` in double precision, stored
    order-major in ``out`` of any float type (the lens's single-precision tables)."""
    start = mmax + int(np.sqrt(160.0 * max(mmax, 1))) + 12
    back = np.empty(start + 2)
    col = np.empty(mmax + 1)
    for p in range(x.shape[0]):
        _bessel_point(x[p], j0[p], j1[p], mmax, start, back, col)
        for m in range(mmax + 1):
            out[m, p] = col[m]


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


@numba.njit(cache=True, nogil=True)
def polar_coordinates(dx, dy, inv_step, n_phi, pad, t, u):  # pragma: no cover - compiled
    """A pixel's fractional row ``t = sqrt(dx^2 + dy^2) inv_step + pad`` and column on a polar
    grid, ``u = (phi mod 2 pi) n_phi / (2 pi) + pad``, given ``u = phi = atan2(dy, dx)`` on
    entry (numpy's vectorised ``arctan2`` is several times faster than the scalar one here):
    the array expressions in one pass (no temporaries, no masked update)."""
    c = n_phi / (2.0 * np.pi)
    for q in range(dx.shape[0]):
        x = dx[q]
        y = dy[q]
        t[q] = np.sqrt(x * x + y * y) * inv_step + pad
        v = u[q] * c
        if v < 0:
            v += n_phi
        u[q] = v + pad


@numba.njit(cache=True, nogil=True)
def polar_spectrum(g, mmax, spec):  # pragma: no cover - compiled
    """The azimuthal spectrum of a polar grid, ``spec[f, j, p, c]`` for field ``f``, radial row
    ``j``, FFT bin ``p`` (order ``m`` at bin ``m mod n_phi``) and component ``c`` (``E_x, E_y``),
    from the radial transforms ``g[|m|, j, 4 f + 2 c + s]`` (``s`` 0: order ``+|m|``, 1:
    ``-|m|``): ``i^m G_m`` at the orders ``-mmax..mmax``, zero at the other bins. The factor
    ``i^m`` is applied as the exact swap and negation of the parts it is.
    """
    n_f, n_rho, n_phi = spec.shape[0], spec.shape[1], spec.shape[2]
    for f in range(n_f):
        for j in range(n_rho):
            for p in range(mmax + 1, n_phi - mmax):
                spec[f, j, p, 0] = 0.0
                spec[f, j, p, 1] = 0.0
    for m in range(mmax + 1):
        for j in range(n_rho):
            for f in range(n_f):
                for c in range(2):
                    col = 4 * f + 2 * c
                    spec[f, j, m, c] = _times_i_power(g[m, j, col], m)
                    if m > 0:
                        spec[f, j, n_phi - m, c] = _times_i_power(g[m, j, col + 1], -m)


@numba.njit(cache=True, nogil=True, inline="always")
def _times_i_power(v, m):  # pragma: no cover - compiled
    """``i^m v``, exactly (a swap of the parts and sign changes)."""
    k = m % 4
    if k == 0:
        return v
    if k == 1:
        return complex(-v.imag, v.real)
    if k == 2:
        return -v
    return complex(v.imag, -v.real)


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
    """Lagrange interpolation (8 x 8 stencil) of one polar grid at fractional rows ``t`` and
    columns ``u`` (columns already padded in ``u``): the lens image's loop, with the weights of
    :func:`polar_interpolate`.

    ``g`` holds the grid with its four real planes interleaved, shape ``(rows, columns, 4)``
    (``Re E_x, Im E_x, Re E_y, Im E_y`` per node; any float type, summed in double precision),
    so that a stencil row is one contiguous run of 32 values and the four planes' sums are
    one 4-wide vector. Rows are summed first (the inner loop), then columns. Indices are taken
    unsigned: numba's negative-index wrap-around select otherwise stops the compiler from
    vectorising the loads (the rows and columns of a stencil are never negative: ``t, u`` are
    offset by the padding). Measured on the rod's and the Janus particle's grids
    (``bench/polar_kernel_ab.py``): 0.55-0.66 of the time of the four separate planes of
    :func:`polar_interpolate`'s layout, whose sums the compiler leaves scalar.
    """
    n = t.shape[0]
    half = POLAR_STENCIL // 2 - 1
    c = _node_factors(POLAR_STENCIL)
    wr = np.empty(POLAR_STENCIL)
    wp = np.empty(POLAR_STENCIL)
    flat = g.reshape(g.shape[0], g.shape[1] * g.shape[2])
    for q in range(n):
        i0 = int(t[q]) - half
        _weights(t[q] - i0, POLAR_STENCIL, c, wr)
        j0 = int(u[q]) - half
        _weights(u[q] - j0, POLAR_STENCIL, c, wp)
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        s3 = 0.0
        for b in range(POLAR_STENCIL):
            k = 4 * (j0 + b)
            r0 = 0.0
            r1 = 0.0
            r2 = 0.0
            r3 = 0.0
            for a in range(POLAR_STENCIL):
                w = wr[a]
                i = _U(i0 + a)
                r0 += w * flat[i, _U(k)]
                r1 += w * flat[i, _U(k + 1)]
                r2 += w * flat[i, _U(k + 2)]
                r3 += w * flat[i, _U(k + 3)]
            w = wp[b]
            s0 += w * r0
            s1 += w * r1
            s2 += w * r2
            s3 += w * r3
        ex[q] = complex(s0, s1)
        ey[q] = complex(s2, s3)
