"""Exact Lorenz-Mie scattering by a homogeneous sphere.

Far-field amplitudes ``S1, S2`` (Bohren & Huffman), cross sections, and the exact scattered
field at arbitrary points with spherical Hankel functions (near-field terms and the radial
component included). Bohren & Huffman's formulas assume light travelling along +z polarised
along x; holofit's light travels along -z with polarisation angle beta, so points and fields are
mapped through the rotation ``M = Rz(beta) Rx(pi)`` (:func:`bh_frame`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.conventions import rotation_z
from holofit.optics import Optics
from holofit.particles import ParticleModel, Sphere
from holofit.scattering.mie_coefficients import mie_coefficients
from holofit.scattering.mie_kernels import angular_pi_tau, field_at_points, field_on_pixels
from holofit.scattering.theory import Orientation, ScatteredWave, ScatteringEngine

if TYPE_CHECKING:
    from holofit.scattering.multipole import MultipoleExpansion

__all__ = [
    "CrossSections",
    "LorenzMie",
    "MieWave",
    "SphereSeriesWave",
    "bh_frame",
    "cross_sections",
    "far_field_amplitudes",
    "series_amplitudes",
    "series_cross_sections",
]


def _series_weights(nmax: int) -> NDArray[np.float64]:
    n = np.arange(1, nmax + 1)
    return (2 * n + 1) / (n * (n + 1.0))


def far_field_amplitudes(
    m: complex, x: float, theta: ArrayLike, nmax: int | None = None
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Amplitude-matrix elements ``S1(theta)``, ``S2(theta)`` of a sphere (B&H eq. 4.74).

    Parameters
    ----------
    m : complex
        Relative refractive index (``Im m > 0`` absorbs; time dependence ``exp(-i omega t)``).
    x : float
        Size parameter ``k a``.
    theta : array_like
        Scattering angles from the forward direction, rad.
    nmax : int, optional
        Number of series terms (:func:`~holofit.scattering.mie_coefficients.n_stop` by
        default).

    Returns
    -------
    S1, S2 : ndarray of complex, shape of ``theta``
    """
    a, b = mie_coefficients(m, x, nmax)
    return series_amplitudes(a, b, theta)


def series_amplitudes(a: NDArray, b: NDArray, theta: ArrayLike) -> tuple[NDArray, NDArray]:
    """``S1, S2`` at scattering angles ``theta`` (rad) from series coefficients ``a_n, b_n``
    (B&H eq. 4.74; homogeneous and coated spheres alike)."""
    theta = np.asarray(theta, dtype=float)
    w = _series_weights(a.size)
    pi, tau = angular_pi_tau(np.ascontiguousarray(np.cos(theta).ravel()), a.size)
    s1 = (w * a) @ pi + (w * b) @ tau
    s2 = (w * a) @ tau + (w * b) @ pi
    return s1.reshape(theta.shape), s2.reshape(theta.shape)


@dataclass(frozen=True)
class CrossSections:
    """Extinction, scattering and absorption cross sections (um^2) and efficiencies."""

    extinction_um2: float
    scattering_um2: float
    absorption_um2: float
    q_extinction: float
    q_scattering: float
    q_absorption: float


def cross_sections(m: complex, radius_um: float, k: float) -> CrossSections:
    """Cross sections of a sphere of radius ``radius_um`` (um) for wavenumber ``k`` (rad/um)."""
    a, b = mie_coefficients(m, k * radius_um)
    return series_cross_sections(a, b, k, radius_um)


def series_cross_sections(a: NDArray, b: NDArray, k: float, radius_um: float) -> CrossSections:
    """Cross sections (um^2) of any sphere-series wave from its coefficients ``a_n, b_n``
    (B&H eqs. 4.61-4.62); efficiencies per ``pi radius_um^2``."""
    n = np.arange(1, a.size + 1)
    cext = 2 * np.pi / k**2 * float(np.sum((2 * n + 1) * (a + b).real))
    csca = 2 * np.pi / k**2 * float(np.sum((2 * n + 1) * (abs(a) ** 2 + abs(b) ** 2)))
    geo = np.pi * radius_um**2
    return CrossSections(cext, csca, cext - csca, cext / geo, csca / geo, (cext - csca) / geo)


def bh_frame(polarization_rad: float) -> NDArray[np.float64]:
    """Rotation from the lab frame to the Bohren & Huffman frame of the sphere.

    In the B&H frame the light travels along +z and is polarised along x. ``p_bh = M @ p_lab``
    and ``E_lab = M.T @ E_bh``.
    """
    return rotation_z(polarization_rad) @ np.diag([1.0, -1.0, -1.0])


class SphereSeriesWave(ScatteredWave):
    """Scattered wave of any spherically symmetric particle, from its series coefficients.

    The field outside the particle is B&H's series (eq. 4.45) with the coefficients ``a_n``,
    ``b_n`` of a homogeneous sphere (:class:`MieWave`) or of a coated one
    (:class:`holofit.scattering.coated_mie.CoatedSphereWave`); this class holds everything
    that follows from the coefficients: fields, far-field amplitudes, cross sections and the
    outgoing multipole expansion.

    Parameters
    ----------
    a, b : ndarray of complex, shape (nmax,)
        Series coefficients, n = 1..nmax.
    radius_um : float
        Outer radius, um (the series is valid outside it).
    optics : Optics
        Illumination.
    """

    exact_near_field = True
    #: what the error messages call the particle
    _body = "particle"

    def __init__(self, a: NDArray, b: NDArray, radius_um: float, optics: Optics) -> None:
        self.a, self.b = a, b
        self.radius_um = float(radius_um)
        self.optics = optics
        n = np.arange(1, self.a.size + 1)
        e_n = (1j) ** n * (2 * n + 1) / (n * (n + 1.0))
        c1 = 1j * e_n * self.a
        c2 = -e_n * self.b
        c1r, c1i, c2r, c2i = (np.ascontiguousarray(v)
                              for v in (c1.real, c1.imag, c2.real, c2.imag))
        self._coefs = (c1r, c1i, c2r, c2i)
        self._frame = bh_frame(optics.polarization_rad)

    def far_field_amplitudes(self, theta: ArrayLike) -> tuple[NDArray, NDArray]:
        """``S1, S2`` at scattering angles ``theta`` (rad from the propagation direction)."""
        return series_amplitudes(self.a, self.b, theta)

    def cross_sections(self) -> CrossSections:
        """Extinction, scattering and absorption cross sections, um^2."""
        return series_cross_sections(self.a, self.b, self.optics.k, self.radius_um)

    @property
    def expansion(self) -> MultipoleExpansion:
        """The scattered field's outgoing multipole expansion (lab frame,
        :mod:`holofit.scattering.multipole`): ``p = -a_n`` times the plane wave's N-type
        coefficients, ``q = -b_n`` times its M-type ones (what the lens model images)."""
        from holofit.conventions import PROPAGATION_DIRECTION
        from holofit.scattering.multipole import MultipoleExpansion
        from holofit.scattering.vsw import plane_wave_coefficients, term_indices, unpack

        order = self.a.size
        vec = plane_wave_coefficients(PROPAGATION_DIRECTION, self.optics.polarization, order)
        _, n, _ = term_indices(order)
        half = n.size // 2
        vec = vec * np.concatenate([-self.a[n[:half] - 1], -self.b[n[half:] - 1]])
        p, q = unpack(vec, order)
        return MultipoleExpansion(self.optics.k, p, q, self.radius_um)

    def _check_outside(self, distance_um: NDArray) -> None:
        inside = int(np.sum(distance_um <= self.radius_um))
        if inside:
            raise ValueError(
                f"the scattered-field series is valid outside the {self._body} only; {inside} "
                f"point(s) lie within {self.radius_um} um of its centre"
            )

    def field_at(self, points_um: ArrayLike, far_field: bool = False) -> NDArray[np.complex128]:
        pts = np.atleast_2d(np.asarray(points_um, dtype=float))
        self._check_outside(np.linalg.norm(pts, axis=1))
        p_bh = np.ascontiguousarray(pts @ self._frame.T)
        e_bh = np.empty((p_bh.shape[0], 3), dtype=np.complex128)
        field_at_points(p_bh, self.optics.k, *self._coefs, bool(far_field), e_bh)
        return e_bh @ self._frame

    def field_on_pixels(
        self, position_um: ArrayLike, xs_um: ArrayLike, ys_um: ArrayLike, far_field: bool = False
    ) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
        """:meth:`ScatteredWave.field_on_pixels` by the compiled series (B&H frame).

        Raises
        ------
        ValueError
            If the detector plane cuts the particle.
        """
        xp, yp, zp = (float(v) for v in np.asarray(position_um, dtype=float))
        if abs(zp) <= self.radius_um:
            raise ValueError(
                f"|z| = {abs(zp):.4g} um is within the {self._body} radius "
                f"{self.radius_um:.4g} um: the detector plane cuts the {self._body}"
            )
        xs = np.ascontiguousarray(xs_um, dtype=float).ravel()
        ys = np.ascontiguousarray(ys_um, dtype=float).ravel()
        ex = np.empty(xs.shape[0], dtype=complex)
        ey = np.empty(xs.shape[0], dtype=complex)
        field_on_pixels(xs, ys, (float(xp), float(yp), float(zp)), self._frame, self.optics.k,
                        tuple(self._coefs), bool(far_field), ex, ey)
        return ex, ey


class MieWave(SphereSeriesWave):
    """Scattered wave of a sphere, from its Lorenz-Mie coefficients.

    Parameters
    ----------
    sphere : Sphere
        The particle.
    optics : Optics
        Illumination.
    """

    _body = "sphere"

    def __init__(self, sphere: Sphere, optics: Optics) -> None:
        self.sphere = sphere
        self.m = complex(sphere.index) / optics.n_medium
        self.x = optics.k * sphere.radius_um
        super().__init__(*mie_coefficients(self.m, self.x), sphere.radius_um, optics)


class LorenzMie(ScatteringEngine):
    """Exact Lorenz-Mie theory for homogeneous spheres."""

    name = "mie"
    models = (Sphere,)
    handles = "spheres"

    def solve(
        self, model: ParticleModel, optics: Optics, orientation: Orientation | None = None
    ) -> MieWave:
        self.check_model(model)
        assert isinstance(model, Sphere)  # check_model passes only ``models``
        return MieWave(model, optics)
