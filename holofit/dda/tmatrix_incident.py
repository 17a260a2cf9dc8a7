"""Regular waves on a dipole lattice by Herglotz synthesis: the incident side of a T-matrix build.

The basis and the Herglotz density are in :mod:`holofit.scattering.vsw`; this module samples
the density on a quadrature and sums the plane waves over the lattice (the adjoint of
:func:`holofit.dda.farfield.dipole_sum_on_grid`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from holofit.dda.lattice import Lattice
from holofit.scattering.vsw import herglotz_density, n_terms

__all__ = ["incident_on_lattice", "incident_quadrature"]


def incident_quadrature(order: int, k: float, radius_um: float) -> tuple[NDArray, NDArray,
                                                                            NDArray]:
    """Gauss-Legendre x uniform directions for the Herglotz sum over points within
    ``radius_um``: exact for the degree ``L + K`` of the integrand, ``K = kR + 6 (kR)^(1/3) +
    10`` (the effective band limit of ``exp(i k k^.r)`` for ``|r| <= R``).

    Returns ``mu, weights, phi`` (weights include the ``2 pi / n_phi`` of the azimuths).
    """
    x = k * radius_um
    band = order + int(np.ceil(x + 6.0 * x ** (1.0 / 3.0) + 10.0))
    n_theta = band // 2 + 2
    n_phi = band + 2
    n_phi += n_phi % 2
    mu, w = np.polynomial.legendre.leggauss(n_theta)
    phi = 2.0 * np.pi * np.arange(n_phi) / n_phi
    return mu, w * (2.0 * np.pi / n_phi), phi


def incident_on_lattice(
    lattice: Lattice, vecs: NDArray[np.complex128], k: float, order: int,
) -> NDArray[np.complex128]:
    """Incident field at every dipole of the regular waves with coefficients ``vecs``.

    Parameters
    ----------
    lattice : Lattice
        The dipoles (particle frame, positions relative to the expansion centre).
    vecs : ndarray, shape (n_terms,) or (n_terms, n_fields)
        Coefficient vector(s).
    k : float
        Wavenumber in the medium, rad/um.
    order : int
        ``L`` of the vectors.

    Returns
    -------
    ndarray, shape (N, 3) or (n_fields, N, 3)
    """
    single = np.ndim(vecs) == 1
    vecs = np.asarray(vecs, dtype=complex).reshape(n_terms(order), -1)
    radius = float(np.sqrt((lattice.positions**2).sum(axis=1)).max())
    mu, w, phi = incident_quadrature(order, k, radius)
    nx, ny, nz = lattice.shape
    d = lattice.d
    ix, iy, iz = (np.arange(s) for s in lattice.shape)
    st = np.sqrt(1.0 - mu**2)
    cp, sp = np.cos(phi), np.sin(phi)
    ox, oy, oz = lattice.origin
    n_f = vecs.shape[1]
    # s[i, x, y, f, c]: the x-y sums per polar angle
    s = np.empty((mu.size, nx, ny, n_f, 3), dtype=complex)
    dens = np.stack([herglotz_density(vecs[:, f], mu, phi, order) for f in range(n_f)],
                    axis=2)  # (n_theta, n_phi, n_f, 3)
    for i in range(mu.size):
        kap = k * st[i] * d
        ex = np.exp(1j * kap * np.outer(ix, cp))  # (nx, n_phi)
        ey = np.exp(1j * kap * np.outer(iy, sp))  # (ny, n_phi)
        phase = w[i] * np.exp(1j * k * (st[i] * (cp * ox + sp * oy) + mu[i] * oz))
        h = (dens[i] * phase[:, None, None]).reshape(phi.size, -1)  # (n_phi, n_f*3)
        t = ey.T[:, :, None] * h[:, None, :]  # (n_phi, ny, n_f*3)
        s[i] = (ex @ t.reshape(phi.size, -1)).reshape(nx, ny, n_f, 3)
    ez = np.exp(1j * k * d * np.outer(iz, mu))  # (nz, n_theta)
    box = (ez @ s.reshape(mu.size, -1)).reshape(nz, nx, ny, n_f, 3)
    box = box.transpose(3, 1, 2, 0, 4).reshape(n_f, nx * ny * nz, 3)
    out = box[:, lattice.flat_index]
    return out[0] if single else out
