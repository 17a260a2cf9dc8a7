"""The lens image's compiled pixel and spectrum loops against plain numpy formulas: the 8 x 8
Lagrange interpolation of an interleaved polar grid (``polar_pixels``), the pixels' rows and
columns there (``polar_coordinates``) and the azimuthal spectrum's assembly
(``polar_spectrum``)."""

from __future__ import annotations

import numpy as np
import pytest

from holofit.scattering.lens_kernels import (
    POLAR_STENCIL,
    polar_coordinates,
    polar_pixels,
    polar_spectrum,
)


def _lagrange_weights(x: float) -> np.ndarray:
    """Weights of the nodes 0..7 at ``x``: each node's Lagrange basis polynomial, evaluated by
    its product formula."""
    nodes = np.arange(POLAR_STENCIL, dtype=float)
    w = np.ones(POLAR_STENCIL)
    for a in range(POLAR_STENCIL):
        for b in range(POLAR_STENCIL):
            if b != a:
                w[a] *= (x - nodes[b]) / (nodes[a] - nodes[b])
    return w


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_polar_pixels_is_the_tensor_lagrange_stencil(dtype):
    rng = np.random.default_rng(3)
    rows, cols = 30, 26
    g = rng.normal(size=(rows, cols, 4)).astype(dtype)
    n = 200
    t = rng.uniform(3.0, rows - 5.0, n)
    u = rng.uniform(3.0, cols - 5.0, n)
    t[:3] = [3.0, 10.0, rows - 5.0]  # on nodes too
    ex = np.empty(n, dtype=complex)
    ey = np.empty(n, dtype=complex)
    polar_pixels(t, u, g, ex, ey)
    half = POLAR_STENCIL // 2 - 1
    for q in range(n):
        i0 = int(t[q]) - half
        j0 = int(u[q]) - half
        w = np.outer(_lagrange_weights(t[q] - i0), _lagrange_weights(u[q] - j0))
        block = g[i0 : i0 + POLAR_STENCIL, j0 : j0 + POLAR_STENCIL].astype(float)
        v = np.einsum("ab,abc->c", w, block)
        scale = np.abs(block).max()
        assert abs(ex[q] - complex(v[0], v[1])) <= 1e-13 * scale
        assert abs(ey[q] - complex(v[2], v[3])) <= 1e-13 * scale


def test_polar_pixels_reproduces_a_polynomial_of_the_stencils_degree():
    """Degree 7 in each direction is interpolated exactly (to rounding)."""
    rows, cols = 24, 20
    i, j = np.meshgrid(np.arange(rows, dtype=float), np.arange(cols, dtype=float), indexing="ij")
    poly = [lambda x, y: (x / 10) ** 7 - 0.3 * (y / 10) ** 7 + x * y / 100,
            lambda x, y: (x / 10) ** 3 * (y / 10) ** 4, lambda x, y: 1.0 + 0 * x,
            lambda x, y: (y / 10) ** 7 * (x / 10) ** 7]
    g = np.stack([p(i, j) for p in poly], axis=-1)
    rng = np.random.default_rng(5)
    t = rng.uniform(3.0, rows - 5.0, 100)
    u = rng.uniform(3.0, cols - 5.0, 100)
    ex = np.empty(100, dtype=complex)
    ey = np.empty(100, dtype=complex)
    polar_pixels(t, u, g, ex, ey)
    want = [p(t, u) for p in poly]
    np.testing.assert_allclose(ex.real, want[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ex.imag, want[1], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ey.real, want[2], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ey.imag, want[3], rtol=1e-12, atol=1e-12)


def test_polar_spectrum_places_i_power_m_times_each_order():
    rng = np.random.default_rng(6)
    mmax, n_rho, n_f, n_phi = 9, 11, 3, 24
    g = (rng.normal(size=(mmax + 1, n_rho, 4 * n_f))
         + 1j * rng.normal(size=(mmax + 1, n_rho, 4 * n_f))).astype(np.complex64)
    # a strided target, as the padded grid's core
    outer = np.full((n_f, n_rho + 2, n_phi + 4, 2), np.nan + 0j, dtype=np.complex64)
    spec = outer[:, 2:, 2 : 2 + n_phi]
    polar_spectrum(g, mmax, spec)
    want = np.zeros((n_f, n_rho, n_phi, 2), dtype=complex)
    for f in range(n_f):
        for c in range(2):
            for m in range(mmax + 1):
                want[f, :, m, c] = 1j**m * g[m, :, 4 * f + 2 * c]
                if m:
                    want[f, :, n_phi - m, c] = 1j ** (-m) * g[m, :, 4 * f + 2 * c + 1]
    assert np.array_equal(spec, want.astype(np.complex64))
    assert np.isnan(outer[:, :2]).all() and np.isnan(outer[:, :, :2]).all()



def test_polar_coordinates_are_the_array_expressions():
    rng = np.random.default_rng(7)
    dx = rng.normal(size=500) * 3.0
    dy = rng.normal(size=500) * 3.0
    dx[:4] = [0.0, -1.0, 0.0, -2.0]
    dy[:4] = [0.0, 0.0, -1.0, -0.0]
    n_phi, inv_step, pad = 150, 7.3, POLAR_STENCIL
    t = np.empty(500)
    u = np.arctan2(dy, dx)
    polar_coordinates(dx, dy, inv_step, n_phi, pad, t, u)
    want_t = np.sqrt(dx * dx + dy * dy) * inv_step + pad
    want_u = np.arctan2(dy, dx) * (n_phi / (2.0 * np.pi))
    want_u[want_u < 0] += n_phi
    want_u += pad
    assert np.array_equal(t, want_t) and np.array_equal(u, want_u)
    assert (u >= pad).all() and (u <= n_phi + pad).all()
