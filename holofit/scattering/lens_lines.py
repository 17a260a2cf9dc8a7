"""Spheres' lens images along two radial lines, for many heights and many spheres at once.

The prefit's start estimator (:mod:`holofit.prefit.profile`) needs the field of each sphere of a
grid along the polarisation and across it, at the same radii, for hundreds of heights. Through
the lens (:mod:`holofit.scattering.lens`) the image of a sphere has azimuthal orders 0 and 2
only; in the frame of the polarisation (azimuth ``ph'`` from it)

    E_par(rho, ph') = -G_0(rho) + G_2(rho) cos 2ph',
    G_m(rho) = sum_i w_i sin th_i t_m(th_i) exp(i k z (cos th_i - 1)) J_m(k rho sin th_i),

with ``t_0 = a``, ``t_2 = b`` of :func:`~holofit.scattering.lens_pupil.sphere_pupil` (the factor
``exp(-ikz)`` is the incident phase at the particle). Everything but ``t_m`` depends on the
heights and radii only: :class:`SphereLensLines` keeps, per group of heights that need about
the same quadrature (:func:`holofit.scattering.lens_transform.node_count` grows with ``|z|``;
a group takes the rule of its largest, within a factor 2), the Bessel values, the phases and
the angular functions of the Mie series, so that each sphere costs two real matrix products per
group.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import special

from holofit.aberration import Aberration
from holofit.optics import Optics
from holofit.scattering.lens import SQRT_SWITCH
from holofit.scattering.lens_pupil import aperture_angle, pupil_nodes, sphere_pupil
from holofit.scattering.lens_transform import NODES_ROUND, node_count
from holofit.scattering.mie import MieWave
from holofit.scattering.mie_kernels import angular_pi_tau

__all__ = ["SphereLensLines", "sphere_lens_lines"]


@dataclass(frozen=True)
class _Group:
    """Heights sharing one quadrature: their rows, the nodes and what depends on them only."""

    rows: NDArray[np.intp]
    cos_theta: NDArray[np.float64]
    j0: NDArray[np.float64]  # (n_rho, nodes)
    j2: NDArray[np.float64]
    phase: NDArray[np.complex128]  # (nodes, heights): weight, sin th, exp(ik z (cos th - 1))
    pi: NDArray[np.float64]  # (order, nodes): Mie angular functions at th
    tau: NDArray[np.float64]


class SphereLensLines:
    """The two lines of the lens image, on fixed heights and radii, for any sphere.

    Parameters
    ----------
    optics : Optics
        Illumination and medium.
    z_um : array_like, shape (n_z,)
        Heights of the sphere above the focal plane, um (any sign).
    rho_um : array_like, shape (n_rho,)
        Lateral distances from the sphere's axis, um.
    order : int
        Largest Mie series length of the spheres to come (sets the quadrature; a longer
        series is refused).
    numerical_aperture : float, optional
        The objective's NA (default: the optics').
    apodization : {"aplanatic", "none"}
        The lens model (:mod:`holofit.scattering.lens_pupil`).
    aberration : Aberration, optional
        The objective's pupil phase (:mod:`holofit.aberration`; default: the optics'), a
        factor ``exp(i Phi(th))`` in every node's phase.
    """

    def __init__(self, optics: Optics, z_um: ArrayLike, rho_um: ArrayLike, order: int,
                 numerical_aperture: float | None = None, apodization: str = "aplanatic",
                 aberration: Aberration | None = None) -> None:
        na = optics.numerical_aperture if numerical_aperture is None else numerical_aperture
        if na is None:
            raise ValueError("no numerical aperture for the lens model: give one, or set "
                             "numerical_aperture in the instrument")
        self.optics = optics
        self.order = int(order)
        self.apodization = apodization
        self.z = np.atleast_1d(np.asarray(z_um, dtype=float))
        self.rho = np.atleast_1d(np.asarray(rho_um, dtype=float))
        k = optics.k
        theta_max = aperture_angle(na, optics.n_medium)
        sqrt_end = bool(apodization == "aplanatic" and np.cos(theta_max) < SQRT_SWITCH)
        rho_max = float(np.abs(self.rho).max()) if self.rho.size else 0.0
        ab = optics.aberration if aberration is None else aberration
        self.aberration = ab
        variation = ab.variation(theta_max)
        counts = np.array([node_count(k, float(z), rho_max, theta_max, self.order, variation)
                           for z in self.z], dtype=float)
        rounded = NODES_ROUND * np.ceil(2.0 ** np.ceil(np.log2(counts)) / NODES_ROUND)
        self._groups: list[_Group] = []
        for n_nodes in np.unique(rounded).astype(int):
            rows = np.flatnonzero(rounded == n_nodes)
            theta, w = pupil_nodes(theta_max, int(n_nodes), sqrt_end)
            sin_t, cos_t = np.sin(theta), np.cos(theta)
            x = k * self.rho[:, None] * sin_t[None, :]
            j0 = special.j0(x)
            with np.errstate(divide="ignore", invalid="ignore"):
                j2 = np.where(x > 0, 2.0 * special.j1(x) / x - j0, 0.0)
            phase = np.exp(1j * k * np.outer(cos_t - 1.0, self.z[rows])) * (w * sin_t)[:, None]
            if not ab.is_zero:
                phase *= np.exp(1j * ab.phase(theta))[:, None]
            # the sphere's S1, S2 are forward-scattering amplitudes at th from the axis
            pi, tau = angular_pi_tau(np.ascontiguousarray(cos_t), self.order)
            self._groups.append(_Group(rows, cos_t, j0, j2, np.ascontiguousarray(phase), pi,
                                       tau))

    def __call__(self, wave: MieWave) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
        """``(p, b)``: ``E_par`` along the polarisation and across it, shape (n_z, n_rho).

        The incident phase is included: this is what
        :func:`holofit.scattering.lens.lens_field_on_pixels` gives on those pixels, projected
        on the polarisation.

        Raises
        ------
        ValueError
            If the sphere's series is longer than ``order``, or its optics differ.
        """
        n = int(wave.a.size)
        if n > self.order:
            raise ValueError(f"a sphere with {n} Mie terms: these lines were set up for "
                             f"{self.order} at most")
        if (wave.optics.wavelength_um, wave.optics.n_medium) != (self.optics.wavelength_um,
                                                                self.optics.n_medium):
            raise ValueError("the sphere was solved for other optics than these lines")
        weights = (2 * np.arange(1, n + 1) + 1) / (np.arange(1, n + 1) * (np.arange(1, n + 1)
                                                                          + 1.0))
        wa, wb = weights * wave.a, weights * wave.b
        p = np.empty((self.z.size, self.rho.size), dtype=complex)
        b = np.empty_like(p)
        for g in self._groups:
            s1 = _real_left(wa, g.pi[:n]) + _real_left(wb, g.tau[:n])
            s2 = _real_left(wa, g.tau[:n]) + _real_left(wb, g.pi[:n])
            t0, t2 = sphere_pupil(s1, s2, g.cos_theta, self.apodization)
            g0 = _real_product(g.j0, g.phase * t0[:, None])
            g2 = _real_product(g.j2, g.phase * t2[:, None])
            p[g.rows] = (g2 - g0).T
            b[g.rows] = (-g0 - g2).T
        return p, b


def _real_left(c: NDArray[np.complex128], real: NDArray[np.float64]) -> NDArray[np.complex128]:
    """``c @ real`` for a complex vector and a real matrix, as real products."""
    return (c.real @ real) + 1j * (c.imag @ real)


def _real_product(real: NDArray[np.float64], cplx: NDArray[np.complex128]
                  ) -> NDArray[np.complex128]:
    """``real @ cplx`` as one real matrix product (numpy's mixed product is not BLAS)."""
    flat = np.ascontiguousarray(cplx).view(np.float64)
    return np.ascontiguousarray(real @ flat).view(np.complex128)


def sphere_lens_lines(
    wave: MieWave, z_um: ArrayLike, rho_um: ArrayLike, numerical_aperture: float | None = None,
    apodization: str = "aplanatic",
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """:class:`SphereLensLines` of one sphere: ``E_par`` along the polarisation and across it.

    Parameters
    ----------
    wave : MieWave
        The solved sphere.
    z_um : array_like, shape (n_z,)
        Heights of the sphere above the focal plane, um (any sign).
    rho_um : array_like, shape (n_rho,)
        Lateral distances from the sphere's axis, um.
    numerical_aperture : float, optional
        The objective's NA (default: the wave's optics').
    apodization : {"aplanatic", "none"}
        The lens model.

    Returns
    -------
    p, b : ndarray of complex, shape (n_z, n_rho)
    """
    lines = SphereLensLines(wave.optics, z_um, rho_um, int(wave.a.size), numerical_aperture,
                            apodization)
    return lines(wave)
