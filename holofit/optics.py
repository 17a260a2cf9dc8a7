"""Illumination and medium: what every scattering calculation needs to know about the light."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from holofit.aberration import NO_ABERRATION, Aberration
from holofit.conventions import medium_wavenumber, polarization_vector

__all__ = ["Optics"]


@dataclass(frozen=True)
class Optics:
    """Plane-wave illumination in a homogeneous medium.

    Parameters
    ----------
    wavelength_um : float
        Vacuum wavelength, um.
    n_medium : float
        Refractive index of the medium (real).
    polarization_rad : float
        Angle of the linear polarisation from lab x, rad.
    numerical_aperture : float, optional
        NA of the objective that images the sample onto the camera. None (default): the ideal
        model, in which the camera records the field in the focal plane itself. A number: the
        hologram is the image through an ideal objective of that NA
        (:mod:`holofit.scattering.lens`).
    aberration : Aberration, optional
        The objective's pupil phase beyond the ideal lens (:mod:`holofit.aberration`: spherical
        aberration, coefficients in rad); default none, the ideal objective. It needs a
        numerical aperture: without an objective in the model there is no pupil to aberrate.
    """

    wavelength_um: float
    n_medium: float
    polarization_rad: float = 0.0
    numerical_aperture: float | None = None
    aberration: Aberration = NO_ABERRATION

    def __post_init__(self) -> None:
        na = self.numerical_aperture
        if na is not None and not (np.isfinite(na) and na > 0):
            raise ValueError(f"numerical_aperture must be a positive number or None, got {na}")
        if not isinstance(self.aberration, Aberration):
            raise TypeError(f"aberration must be an Aberration, got {self.aberration!r}")
        if na is None and not self.aberration.is_zero:
            raise ValueError("an aberrated pupil needs an objective: give the optics a "
                             "numerical_aperture")

    @property
    def k(self) -> float:
        """Wavenumber in the medium, rad/um."""
        return medium_wavenumber(self.wavelength_um, self.n_medium)

    @property
    def wavelength_medium_um(self) -> float:
        """Wavelength in the medium, um."""
        return self.wavelength_um / self.n_medium

    @property
    def polarization(self) -> NDArray[np.float64]:
        """Unit polarisation vector in the lab frame."""
        return polarization_vector(self.polarization_rad)
