"""The T-matrix's block rotations (batched matrix products) against the plain per-block
products they replace, and the polar grid (several fields at once, interleaved planes in the
tables' precision) against the one-field grid."""

from __future__ import annotations

import numpy as np

from holofit.scattering import lens_transform as lt
from holofit.scattering.tmatrix import _rotate, _rotate_back
from holofit.scattering.wigner import wigner_d_all


def test_block_rotations_equal_per_block_products():
    L = 6
    rng = np.random.default_rng(2)
    d = wigner_d_all(L, 0.4, 1.2, -0.7)
    x = rng.normal(size=(2, L + 1, 2 * L + 1)) + 1j * rng.normal(size=(2, L + 1, 2 * L + 1))
    v = rng.normal(size=(2, L + 1, 2 * L + 1, 3)) + 1j * rng.normal(size=(2, L + 1, 2 * L + 1, 3))
    back = np.array([[d[n].conj().T @ x[k, n] for n in range(L + 1)] for k in range(2)])
    fwd = np.array([[d[n] @ v[k, n] for n in range(L + 1)] for k in range(2)])
    assert np.allclose(_rotate_back(d, x), back, rtol=0, atol=1e-13)
    assert np.allclose(_rotate(d, v), fwd, rtol=0, atol=1e-13)
    assert np.allclose(_rotate(d, v[..., 1]), fwd[..., 1], rtol=0, atol=1e-13)


def test_polar_grids_of_several_fields_equal_each_field_alone():
    rng = np.random.default_rng(4)
    n_nodes, width = 24, 7
    x_step = np.linspace(0.05, 0.5, n_nodes)
    fields = [(rng.normal(size=(n_nodes, width)) + 1j * rng.normal(size=(n_nodes, width)),
               rng.normal(size=(n_nodes, width)) + 1j * rng.normal(size=(n_nodes, width)),
               np.exp(1j * rng.normal(size=n_nodes))) for _ in range(3)]
    many = lt.polar_grids(fields, x_step, 40, ("test-grids", n_nodes))
    assert many.dtype == lt.TABLE_DTYPE and many.shape[0] == 3 and many.shape[3] == 4
    for f, field in enumerate(fields):
        one = lt.polar_grid(*field, x_step, 40, ("test-grids", n_nodes))
        assert one.shape == many[f].shape
        assert np.allclose(many[f], one, rtol=0, atol=1e-5 * np.abs(one).max())
