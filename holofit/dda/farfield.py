"""Far-field scattering amplitudes of a solved dipole set.

Draine's formula (ADDA ``-scat dr``), with the scattered field
``E_sca(r n) = exp(ikr)/(-ikr) F(n)`` for unit incident amplitude:

    F(n) = -i k^3 (I - n n) . sum_j P_j exp(-i k n . r_j).

The phase origin is the particle centre (``r_j`` are relative to it). The dipole sum over the
lattice is separable, ``exp(-ik n.(o + d(i,j,l))) = exp(-ik n.o) X_i Y_j Z_l``, so it is done as
three contractions over the box axes (the first a matrix product), ``O(N_box N_dir)`` with BLAS.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.dda.lattice import Lattice

__all__ = [
    "dipole_sum",
    "dipole_sum_on_grid",
    "far_field",
    "far_field_on_grid",
]


def dipole_sum(
    lattice: Lattice, P: NDArray[np.complex128], k: float, directions: ArrayLike,
    chunk: int = 4096,
) -> NDArray[np.complex128]:
    """``sum_j P_j exp(-i k n . r_j)`` for unit directions ``n`` (M, 3) in the lattice frame."""
    n_dir = np.atleast_2d(np.asarray(directions, dtype=float))
    nx, ny, nz = lattice.shape
    box = np.zeros((3, nx * ny * nz), dtype=complex)
    box[:, lattice.flat_index] = P.T
    box = box.reshape(3 * nx * ny, nz)
    d = lattice.d
    out = np.empty((n_dir.shape[0], 3), dtype=complex)
    ix, iy, iz = (np.arange(m) for m in lattice.shape)
    for start in range(0, n_dir.shape[0], chunk):
        nd = n_dir[start : start + chunk]
        ez = np.exp(-1j * k * d * np.outer(iz, nd[:, 2]))  # (nz, m)
        ey = np.exp(-1j * k * d * np.outer(iy, nd[:, 1]))  # (ny, m)
        ex = np.exp(-1j * k * d * np.outer(ix, nd[:, 0]))  # (nx, m)
        t = (box @ ez).reshape(3, nx, ny, -1)
        t = np.einsum("cijm,jm->cim", t, ey, optimize=False)
        t = np.einsum("cim,im->cm", t, ex, optimize=False)
        phase = np.exp(-1j * k * (nd @ lattice.origin))
        out[start : start + chunk] = (t * phase).T
    return out


def far_field(
    lattice: Lattice, P: NDArray[np.complex128], k: float, directions: ArrayLike
) -> NDArray[np.complex128]:
    """Far-field amplitude ``F(n)`` (M, 3), lattice frame, phase origin at the particle centre."""
    n_dir = np.atleast_2d(np.asarray(directions, dtype=float))
    s = dipole_sum(lattice, P, k, n_dir)
    s_perp = s - n_dir * np.sum(n_dir * s, axis=1, keepdims=True)
    return -1j * k**3 * s_perp


def dipole_sum_on_grid(
    lattice: Lattice, P: NDArray[np.complex128], k: float, mu: NDArray, phi: NDArray
) -> NDArray[np.complex128]:
    """``sum_j P_j exp(-i k n . r_j)`` on a tensor grid of lattice-frame directions.

    ``n = (sin th cos ph, sin th sin ph, cos th)`` with ``cos th = mu[i]``, ``ph = phi[j]``.
    The z sum is done once per polar angle (one matrix product for all of them) and the x-y
    sum per polar angle as two small products, so the cost is
    ``O(N_box (n_theta + n_theta n_phi / n_z))`` instead of ``O(N_box n_theta n_phi)``.

    Returns
    -------
    ndarray, shape (n_theta, n_phi, 3)
    """
    nx, ny, nz = lattice.shape
    d = lattice.d
    box = np.zeros((3, nx * ny * nz), dtype=complex)
    box[:, lattice.flat_index] = P.T
    box = box.reshape(3 * nx * ny, nz)
    ix, iy, iz = (np.arange(m) for m in lattice.shape)
    ez = np.exp(-1j * k * d * np.outer(iz, mu))  # (nz, n_theta)
    q = (box @ ez).reshape(3, nx, ny, mu.size)
    st = np.sqrt(1.0 - mu**2)
    out = np.empty((mu.size, phi.size, 3), dtype=complex)
    cp, sp = np.cos(phi), np.sin(phi)
    ox, oy, oz = lattice.origin
    for i in range(mu.size):
        kap = k * st[i] * d
        ey = np.exp(-1j * kap * np.outer(iy, sp))  # (ny, n_phi)
        ex = np.exp(-1j * kap * np.outer(ix, cp))  # (nx, n_phi)
        t = (q[..., i].reshape(3 * nx, ny) @ ey).reshape(3, nx, phi.size)
        t = np.einsum("cxj,xj->jc", t, ex)
        phase = np.exp(-1j * k * (st[i] * (cp * ox + sp * oy) + mu[i] * oz))
        out[i] = t * phase[:, None]
    return out


def far_field_on_grid(
    lattice: Lattice, P: NDArray[np.complex128], k: float, mu: NDArray, phi: NDArray
) -> NDArray[np.complex128]:
    """``F(n)`` (n_theta, n_phi, 3) on a tensor grid of lattice-frame directions."""
    s = dipole_sum_on_grid(lattice, P, k, mu, phi)
    st = np.sqrt(1.0 - mu**2)
    n = np.stack([np.outer(st, np.cos(phi)), np.outer(st, np.sin(phi)),
                  np.repeat(mu[:, None], phi.size, axis=1)], axis=-1)
    s_perp = s - n * np.sum(n * s, axis=-1, keepdims=True)
    return -1j * k**3 * s_perp
