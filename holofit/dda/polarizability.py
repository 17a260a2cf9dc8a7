"""Dipole polarisabilities (Gaussian units, um^3), exactly as ADDA defines them.

Clausius-Mossotti: ``alpha_CM = (3 d^3 / 4 pi) (m^2 - 1) / (m^2 + 2)``.

Lattice dispersion relation (Draine & Goodman 1993; ADDA ``-pol ldr``, its default):
``alpha = alpha_CM / (1 - (alpha_CM / d^3) M)`` with
``M = (b1 + (b2 + b3 S) m^2) (kd)^2 + (2/3) i (kd)^3`` and ``S = sum_mu (a_mu e_mu)^2`` for
propagation direction ``a`` and polarisation ``e`` in the lattice (particle) frame. ``m`` is
the relative index and ``k`` the wavenumber in the medium.

LDR with the averaged S term (``"ldr_avg"``): ``S`` replaced by its mean over propagation
directions and polarisations, ``<S> = 3 <a_x^2 e_x^2> = 1/5`` (from the isotropic fourth-rank
average of an orthonormal pair). Its polarisability, like Clausius-Mossotti's and the filtered
coupled dipoles', does not depend on the incident wave, so the lattice has a T-matrix
(:mod:`holofit.scattering.tmatrix`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "INCIDENCE_INDEPENDENT",
    "KINDS",
    "LDR_B1",
    "LDR_B2",
    "LDR_B3",
    "LDR_S_AVERAGE",
    "ldr_s_term",
    "polarizability",
]

LDR_B1 = 1.8915316529870797
LDR_B2 = -0.1648469150877195
LDR_B3 = 1.7700004019321372
#: mean of LDR's S over propagation directions and polarisations
LDR_S_AVERAGE = 0.2
#: every prescription, and those whose polarisability does not depend on the incident wave
KINDS = ("fcd", "ldr", "ldr_avg", "cm")
INCIDENCE_INDEPENDENT = ("fcd", "ldr_avg", "cm")


def ldr_s_term(propagation: ArrayLike, polarization: ArrayLike) -> float:
    """``S = sum_mu (a_mu e_mu)^2`` for real unit vectors in the lattice frame."""
    a = np.asarray(propagation, dtype=float)
    e = np.asarray(polarization, dtype=float)
    return float(np.sum((a * e) ** 2))


def polarizability(
    eps_rel: ArrayLike, d: float, k: float, kind: str = "ldr", s_term: float = 0.0
) -> NDArray[np.complex128]:
    """Polarisability of each dipole.

    Parameters
    ----------
    eps_rel : array_like of complex
        Relative permittivity ``m^2`` of each voxel (voxel / medium).
    d : float
        Dipole size, um.
    k : float
        Wavenumber in the medium, rad/um.
    kind : {"ldr", "ldr_avg", "cm", "fcd"}
        Prescription ("fcd" goes with the filtered interaction,
        :mod:`holofit.dda.interaction`).
    s_term : float
        LDR's ``S`` for the incident direction and polarisation (ignored by ``"ldr_avg"``,
        which uses :data:`LDR_S_AVERAGE`, and by ``"cm"`` and ``"fcd"``).

    Returns
    -------
    ndarray of complex
        ``alpha`` in um^3 (Gaussian units).
    """
    m2 = np.asarray(eps_rel, dtype=np.complex128)
    alpha_cm = 3.0 * d**3 / (4.0 * np.pi) * (m2 - 1.0) / (m2 + 2.0)
    if kind == "cm":
        return alpha_cm
    if kind == "fcd":
        # filtered coupled dipoles (ADDA -pol fcd): M = (4/3)(kd)^2 + (2/(3 pi)) ln((pi - kd) /
        # (pi + kd)) (kd)^3, plus the radiative reaction (2/3) i (kd)^3
        kd = k * d
        big_m = (4.0 / 3.0 * kd**2 + 2.0 / (3.0 * np.pi) * np.log((np.pi - kd) / (np.pi + kd))
                 * kd**3 + 2.0 / 3.0 * 1j * kd**3)
        return alpha_cm / (1.0 - (alpha_cm / d**3) * big_m)
    if kind == "ldr_avg":
        s_term = LDR_S_AVERAGE
    elif kind != "ldr":
        raise ValueError(f"polarizability kind must be one of {KINDS}, got {kind!r}")
    kd = k * d
    big_m = (LDR_B1 + (LDR_B2 + LDR_B3 * s_term) * m2) * kd**2 + (2.0 / 3.0) * 1j * kd**3
    return alpha_cm / (1.0 - (alpha_cm / d**3) * big_m)
