"""Exact Lorenz-Mie scattering by a coated (concentric two-layer) sphere.

The series coefficients of Aden & Kerker (1951; Bohren & Huffman 1983, section 8.1), computed
with Yang's (2003, Appl. Opt. 42, 1710) recursion, which stays stable for absorbing layers
(the textbook formulas lose all digits once ``Im(m2) k b`` exceeds a few tens: they subtract
exponentially large Bessel functions of the second kind). With ``x = k a`` (core) and
``y = k b`` (outer radius), relative indices ``m1`` (core) and ``m2`` (shell), and

* ``D1_n(z) = psi_n'(z)/psi_n(z)`` (downward recurrence),
* ``D3_n(z) = xi_n'(z)/xi_n(z)`` (upward, through ``psi_n xi_n``),
* ``Q_n = [psi_n(m2 x)/xi_n(m2 x)] / [psi_n(m2 y)/xi_n(m2 y)]`` (its own recurrence),

the core's log-derivatives are carried through the shell,

    G1 = m2 Ha_n(m1 x) - m1 D1_n(m2 x),     G2 = m2 Ha_n(m1 x) - m1 D3_n(m2 x),
    Ha_n(m2 y) = (G2 D1_n(m2 y) - Q_n G1 D3_n(m2 y)) / (G2 - Q_n G1),

(``Hb`` the same with ``m1`` and ``m2`` swapped in ``G1, G2``), ``Ha_n(m1 x) = Hb_n(m1 x) =
D1_n(m1 x)``, and

    a_n = [(Ha/m2 + n/y) psi_n(y) - psi_{n-1}(y)] / [(Ha/m2 + n/y) xi_n(y) - xi_{n-1}(y)],
    b_n = [(m2 Hb + n/y) psi_n(y) - psi_{n-1}(y)] / [(m2 Hb + n/y) xi_n(y) - xi_{n-1}(y)],

the homogeneous-sphere formulas with ``D_n(m y)/m`` replaced by ``Ha/m2``. Time dependence
``exp(-i omega t)``; absorbing layers have ``Im m > 0``. The scattered field outside the sphere
is the homogeneous sphere's series with these coefficients (:class:`CoatedSphereWave`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.optics import Optics
from holofit.particles import CoatedSphere, ParticleModel
from holofit.scattering.mie import (
    CrossSections,
    SphereSeriesWave,
    series_amplitudes,
    series_cross_sections,
)
from holofit.scattering.mie_coefficients import n_stop, riccati_xi
from holofit.scattering.theory import Orientation, ScatteringEngine

__all__ = [
    "CoatedMie",
    "CoatedSphereWave",
    "coated_amplitudes",
    "coated_coefficients",
    "coated_cross_sections",
]


def _d1(z: complex, nmax: int) -> NDArray[np.complex128]:
    """``D1_n(z)``, n = 0..nmax, downward recurrence (started far above ``|z|``)."""
    nstart = int(max(nmax, abs(z)) + 16 + 8.0 * abs(z) ** (1.0 / 3.0))
    d = np.zeros(nstart + 1, dtype=complex)
    for n in range(nstart, 0, -1):
        d[n - 1] = n / z - 1.0 / (d[n] + n / z)
    return d[: nmax + 1]


def _d3(z: complex, d1: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """``D3_n(z)`` from ``D1_n(z)``: ``D3_n = D1_n + i / (psi_n xi_n)``, upward.

    ``psi_n xi_n = psi_{n-1} xi_{n-1} (n/z - D3_{n-1}) / (D1_n + n/z)`` (the ratio forms that
    do not cancel for small ``|z|``).
    """
    nmax = d1.size - 1
    d3 = np.empty(nmax + 1, dtype=complex)
    # psi_0 xi_0 = (1 - exp(2iz)) / 2 with xi_n = psi_n - i chi_n
    psixi = 0.5 * (1.0 - np.exp(2j * z))
    d3[0] = 1j
    for n in range(1, nmax + 1):
        psixi = psixi * (n / z - d3[n - 1]) / (d1[n] + n / z)
        d3[n] = d1[n] + 1j / psixi
    return d3


def _psi_over_xi_ratio(z1: complex, z2: complex, d1_1: NDArray, d3_1: NDArray, d1_2: NDArray,
                       d3_2: NDArray) -> NDArray[np.complex128]:
    """``Q_n = [psi_n/xi_n](z1) / [psi_n/xi_n](z2)``, n = 0..nmax.

    ``psi_0/xi_0 = (1 - exp(-2iz))/2``; ``psi_n/xi_n = psi_{n-1}/xi_{n-1} / ((D1_n + n/z)
    (n/z - D3_{n-1}))``. ``Q_0`` is written with the exponential that cannot overflow.
    """
    nmax = d1_1.size - 1
    q = np.empty(nmax + 1, dtype=complex)
    if z1.imag + z2.imag >= 0:
        # (1 - e^{-2iz1}) / (1 - e^{-2iz2}) = e^{2i(z2 - z1)} (e^{2iz1} - 1) / (e^{2iz2} - 1)
        q[0] = np.exp(2j * (z2 - z1)) * (np.exp(2j * z1) - 1.0) / (np.exp(2j * z2) - 1.0)
    else:  # pragma: no cover - gain media only
        q[0] = (1.0 - np.exp(-2j * z1)) / (1.0 - np.exp(-2j * z2))
    for n in range(1, nmax + 1):
        r1 = (d1_1[n] + n / z1) * (n / z1 - d3_1[n - 1])
        r2 = (d1_2[n] + n / z2) * (n / z2 - d3_2[n - 1])
        q[n] = q[n - 1] * r2 / r1
    return q


def coated_coefficients(
    m_core: complex, m_shell: complex, x: float, y: float, nmax: int | None = None
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Scattering coefficients ``a_n, b_n`` (n = 1..nmax) of a coated sphere.

    Parameters
    ----------
    m_core, m_shell : complex
        Relative refractive indices of core and shell (``Im m >= 0`` absorbs).
    x : float
        Core size parameter ``k a`` (k in the medium, a the core radius); 0 for no core.
    y : float
        Outer size parameter ``k b`` (``b >= a``).
    nmax : int, optional
        Number of terms; :func:`~holofit.scattering.mie_coefficients.n_stop` of ``y``.

    Returns
    -------
    a, b : ndarray of complex, shape (nmax,)
    """
    if y <= 0 or x < 0 or x > y:
        raise ValueError(f"coated sphere needs 0 <= x <= y, y > 0; got x = {x}, y = {y}")
    if nmax is None:
        nmax = n_stop(y)
    m1, m2 = complex(m_core), complex(m_shell)
    n = np.arange(1, nmax + 1)
    z_out = m2 * y
    d1_out = _d1(z_out, nmax)
    if x > 0:
        z_in1, z_in2 = m1 * x, m2 * x
        d1_core = _d1(z_in1, nmax)
        d1_in2 = _d1(z_in2, nmax)
        d3_in2 = _d3(z_in2, d1_in2)
        d3_out = _d3(z_out, d1_out)
        q = _psi_over_xi_ratio(z_in2, z_out, d1_in2, d3_in2, d1_out, d3_out)
        g1 = m2 * d1_core - m1 * d1_in2
        g2 = m2 * d1_core - m1 * d3_in2
        ha = (g2 * d1_out - q * g1 * d3_out) / (g2 - q * g1)
        g1 = m1 * d1_core - m2 * d1_in2
        g2 = m1 * d1_core - m2 * d3_in2
        hb = (g2 * d1_out - q * g1 * d3_out) / (g2 - q * g1)
    else:
        ha = hb = d1_out
    xi = riccati_xi(y, nmax)
    psi = xi.real
    da = ha[1:] / m2 + n / y
    db = hb[1:] * m2 + n / y
    a = (da * psi[1:] - psi[:-1]) / (da * xi[1:] - xi[:-1])
    b = (db * psi[1:] - psi[:-1]) / (db * xi[1:] - xi[:-1])
    return a, b


def coated_amplitudes(
    m_core: complex, m_shell: complex, x: float, y: float, theta: ArrayLike
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """``S1(theta), S2(theta)`` of a coated sphere (B&H eq. 4.74 with its coefficients)."""
    a, b = coated_coefficients(m_core, m_shell, x, y)
    return series_amplitudes(a, b, theta)


def coated_cross_sections(m_core: complex, m_shell: complex, core_radius_um: float,
                          outer_radius_um: float, k: float) -> CrossSections:
    """Cross sections (um^2) of a coated sphere; efficiencies per ``pi b^2``."""
    a, b = coated_coefficients(m_core, m_shell, k * core_radius_um, k * outer_radius_um)
    return series_cross_sections(a, b, k, outer_radius_um)


class CoatedSphereWave(SphereSeriesWave):
    """Scattered wave of a coated sphere centred at the origin of the particle frame.

    Parameters
    ----------
    core_radius_um, outer_radius_um : float
        Radii of the core and of the whole particle, um.
    n_core, n_shell : complex
        Absolute refractive indices.
    optics : Optics
        Illumination.
    """

    def __init__(self, core_radius_um: float, outer_radius_um: float, n_core: complex,
                 n_shell: complex, optics: Optics) -> None:
        self.core_radius_um = float(core_radius_um)
        self.outer_radius_um = float(outer_radius_um)
        k = optics.k
        self.m_core = complex(n_core) / optics.n_medium
        self.m_shell = complex(n_shell) / optics.n_medium
        a, b = coated_coefficients(self.m_core, self.m_shell, k * self.core_radius_um,
                                   k * self.outer_radius_um)
        super().__init__(a, b, self.outer_radius_um, optics)


class CoatedMie(ScatteringEngine):
    """Exact Lorenz-Mie theory for coated spheres (:class:`holofit.particles.CoatedSphere`)."""

    name = "coated_sphere"
    models = (CoatedSphere,)
    handles = "coated spheres"

    def __init__(self, **_ignored: object) -> None:
        pass

    def solve(self, model: ParticleModel, optics: Optics,
              orientation: Orientation | None = None) -> CoatedSphereWave:
        self.check_model(model)
        assert isinstance(model, CoatedSphere)  # check_model passes only ``models``
        return CoatedSphereWave(model.radius_um, model.bounding_radius_um, model.index_core,
                                model.index_shell, optics)
