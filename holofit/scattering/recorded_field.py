"""The field the camera records: the one rule every hologram goes through.

Without an objective in the model (``optics.numerical_aperture`` is None) that is the scattered
field at the pixels (:meth:`~holofit.scattering.theory.ScatteredWave.field_on_pixels`); with
one, it is the image of the scattered field through a lens of that numerical aperture
(:func:`holofit.scattering.lens.lens_field_on_pixels`), which also holds at and below the
focal plane.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.aberration import Aberration
from holofit.conventions import DetectorGrid
from holofit.scattering.lens import lens_field_on_pixels
from holofit.scattering.theory import ScatteredWave

__all__ = ["has_lens", "recorded_field", "recorded_field_on_detector"]


def has_lens(wave: ScatteredWave) -> bool:
    """True if the wave's optics include an objective lens."""
    return wave.optics.numerical_aperture is not None


def recorded_field(
    wave: ScatteredWave, position_um: ArrayLike, xs_um: ArrayLike, ys_um: ArrayLike,
    far_field: bool = False, numerical_aperture: float | None = None,
    aberration: Aberration | None = None,
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Transverse field at pixel centres as the camera records it, incident phase included.

    Parameters
    ----------
    wave : ScatteredWave
        The solved particle.
    position_um : array_like, shape (3,)
        Full-frame particle position, um.
    xs_um, ys_um : array_like, shape (N,)
        Full-frame pixel coordinates, um.
    far_field : bool
        Asymptotic far-field form of the scattered field (no lens only; the lens image is
        built from the far field exactly).
    numerical_aperture : float, optional
        Image through an objective of this NA, whatever the wave's optics say (a fit that
        varies the NA); default: the optics' own (a lens if they have an NA).
    aberration : Aberration, optional
        The objective's pupil phase (:mod:`holofit.aberration`), whatever the wave's optics
        say (a fit that varies it); default: the optics' own. It needs a lens.

    Raises
    ------
    ValueError
        If an aberration is given for the ideal model (no objective).
    """
    if numerical_aperture is not None or has_lens(wave):
        return lens_field_on_pixels(wave, position_um, xs_um, ys_um, numerical_aperture,
                                    aberration=aberration)
    if aberration is not None and not aberration.is_zero:
        raise ValueError("an aberrated pupil needs an objective: give a numerical aperture")
    return wave.field_on_pixels(position_um, xs_um, ys_um, far_field)


def recorded_field_on_detector(
    wave: ScatteredWave, position_um: ArrayLike, grid: DetectorGrid, far_field: bool = False,
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """:func:`recorded_field` at every pixel of ``grid`` (arrays of ``grid.shape``)."""
    x, y = grid.coordinates()
    ex, ey = recorded_field(wave, position_um, x.ravel(), y.ravel(), far_field)
    return ex.reshape(grid.shape), ey.reshape(grid.shape)
