"""Exact Lorenz-Mie hologram on an arbitrary list of pixels (masked crops, random subsets).

:func:`holofit.hologram.calc_hologram` fills a whole rectangular grid. A fit only needs the
unmasked pixels (saturated or NaN pixels are dropped, an optional random subset keeps a
fraction), so these functions use :meth:`~holofit.scattering.mie.MieWave.field_on_pixels`,
the compiled series on a flat list of pixel centres.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.conventions import hologram_intensity
from holofit.scattering.mie import MieWave

__all__ = ["mie_field_on_pixels", "mie_hologram_on_pixels"]


def mie_field_on_pixels(
    wave: MieWave, position_um: ArrayLike, xs_um: NDArray, ys_um: NDArray
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """Exact scattered field (lab x and y components) at a list of pixel centres.

    Parameters
    ----------
    wave : MieWave
        The solved sphere.
    position_um : array_like, shape (3,)
        Full-frame particle centre ``(x, y, z)``, um.
    xs_um, ys_um : ndarray, shape (N,)
        Full-frame sample-plane coordinates of the pixel centres, um (x along columns).

    Returns
    -------
    e_x, e_y : ndarray of complex, shape (N,)
        Relative to the incident field, incident phase at the particle included.

    Raises
    ------
    ValueError
        If the particle is so close to the focal plane that a pixel lies inside the sphere.
    """
    return wave.field_on_pixels(position_um, xs_um, ys_um)


def mie_hologram_on_pixels(
    wave: MieWave, position_um: ArrayLike, xs_um: NDArray, ys_um: NDArray, alpha: float = 1.0
) -> NDArray[np.float64]:
    """Normalised hologram ``|e_pol + alpha E_s|^2`` at a list of pixel centres (see
    :func:`mie_field_on_pixels` for the arguments)."""
    ex, ey = mie_field_on_pixels(wave, position_um, xs_um, ys_um)
    return hologram_intensity(ex, ey, wave.optics.polarization_rad, alpha)
