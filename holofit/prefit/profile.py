"""Radial profiles of sphere holograms: the measured one, and the exact azimuthal average of
the Lorenz-Mie model.

A sphere's hologram under linearly polarised light is not rotationally symmetric, but its
azimuthal average is a 1-D function of the distance rho from the particle's axis that still
carries z (fringe spacing), a and n (fringe amplitude and phase). The average of the model is
exact and cheap: in the sphere's frame the scattered field at azimuth phi (from the
polarisation) has components along and across the polarisation

    E_par(phi)  = cos^2(phi) P + sin^2(phi) B,      E_perp(phi) = sin(phi) cos(phi) (P - B),

with ``P = E_par(0)`` and ``B = E_par(pi/2)`` (Bohren & Huffman eqs. 4.45-4.50 projected on the
lab axes). Averaging ``|e_pol + alpha E|^2`` over phi gives

    <I>(rho) = 1 + 2 alpha L(rho) + alpha^2 Q(rho),
    L = Re(P + B) / 2,
    Q = 3/8 |P|^2 + 3/8 |B|^2 + 1/4 Re(P B*) + 1/8 |P - B|^2,

so two radial lines of field values give the exact average (checked in the tests against a
dense numerical average). The image through an objective lens (optics with a numerical aperture)
has the same two azimuthal orders, so the same formula holds for it; its two lines come from
:func:`holofit.scattering.lens_lines.sphere_lens_lines`, every height at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.scattering.lens_lines import SphereLensLines, sphere_lens_lines
from holofit.scattering.mie import MieWave

__all__ = [
    "RadialProfile",
    "annulus_mean_radius",
    "profile_terms",
    "radial_profile",
]


def annulus_mean_radius(n_bins: int) -> NDArray[np.float64]:
    """Mean distance from the centre of the points of the annuli ``[b, b + 1)``, b = 0..n-1
    (in the same unit as the bin width): ``2/3 ((b+1)^3 - b^3) / ((b+1)^2 - b^2)``."""
    b = np.arange(n_bins, dtype=float)
    return (2.0 / 3.0) * ((b + 1) ** 3 - b**3) / ((b + 1) ** 2 - b**2)


@dataclass(frozen=True)
class RadialProfile:
    """Azimuthally averaged crop.

    Attributes
    ----------
    mean : ndarray, shape (n_bins,)
        Mean normalised intensity in each 1-pixel-wide annulus (NaN where empty).
    counts : ndarray, shape (n_bins,)
        Number of valid pixels in each annulus (the weights of a profile fit).
    """

    mean: NDArray[np.float64]
    counts: NDArray[np.float64]


def radial_profile(
    data: NDArray,
    valid: NDArray[np.bool_],
    centre_rc: tuple[float, float],
    n_bins: int,
) -> RadialProfile:
    """Average a crop over annuli of one pixel width about a centre.

    Parameters
    ----------
    data : ndarray, shape (rows, cols)
        Normalised crop.
    valid : ndarray of bool, same shape
        Pixels to use (False for masked or saturated pixels).
    centre_rc : tuple of float
        Centre ``(row, column)`` in crop pixel indices (fractional).
    n_bins : int
        Number of annuli, ``[b, b + 1)`` pixels for b = 0..n_bins-1.

    Returns
    -------
    RadialProfile
    """
    rows, cols = np.indices(data.shape)
    r = np.hypot(rows - centre_rc[0], cols - centre_rc[1])
    b = r.astype(np.int64)
    keep = valid & (b < n_bins)
    idx = b[keep]
    counts = np.bincount(idx, minlength=n_bins).astype(float)
    sums = np.bincount(idx, weights=data[keep].astype(float), minlength=n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    return RadialProfile(mean, counts)


def profile_terms(
    wave: MieWave, z_um: ArrayLike, rho_um: ArrayLike, lines: SphereLensLines | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Terms ``L`` and ``Q`` of the exact azimuthally averaged hologram (module docstring).

    Parameters
    ----------
    wave : MieWave
        The solved sphere; with a numerical aperture in its optics, the lens image.
    z_um : array_like, shape (n_z,)
        Heights of the particle above the focal plane, um (``|z|`` > radius in the ideal
        model; any height through the lens).
    rho_um : array_like, shape (n_rho,)
        Distances from the particle's axis in the detector plane, um.
    lines : SphereLensLines, optional
        The lens lines already set up for these heights and radii (a table of many spheres
        shares them); made here if the optics have an NA and none is given.

    Returns
    -------
    L, Q : ndarray, shape (n_z, n_rho)
        ``<I> = 1 + 2 alpha L + alpha^2 Q``.
    """
    z = np.atleast_1d(np.asarray(z_um, dtype=float))
    rho = np.atleast_1d(np.asarray(rho_um, dtype=float))
    if lines is not None:
        p, b = lines(wave)
    elif wave.optics.numerical_aperture is not None:
        p, b = sphere_lens_lines(wave, z, rho)
    else:
        beta = wave.optics.polarization_rad
        cb, sb = np.cos(beta), np.sin(beta)
        # pixels along the polarisation, then across it, with the particle above the origin
        xs = np.concatenate([rho * cb, -rho * sb])
        ys = np.concatenate([rho * sb, rho * cb])
        n = rho.size
        p = np.empty((z.size, n), dtype=complex)
        b = np.empty((z.size, n), dtype=complex)
        for i, zi in enumerate(z):
            ex, ey = wave.field_on_pixels((0.0, 0.0, zi), xs, ys)
            e_par = ex * cb + ey * sb
            p[i] = e_par[:n]
            b[i] = e_par[n:]
    lin = 0.5 * (p + b).real
    quad = (
        0.375 * (p.real**2 + p.imag**2)
        + 0.375 * (b.real**2 + b.imag**2)
        + 0.25 * (p * b.conj()).real
        + 0.125 * np.abs(p - b) ** 2
    )
    return lin, quad
