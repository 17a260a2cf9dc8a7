"""Holograms on a detector: the field the camera records
(:func:`holofit.scattering.recorded_field.recorded_field`, the one rule that simulate, the fits
and the pictures share: with an objective NA in the optics the lens image of
:mod:`holofit.scattering.lens`; without, the field in the focal plane itself), interfered with
the incident plane wave (:func:`holofit.conventions.hologram_intensity`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.conventions import DetectorGrid, hologram_intensity
from holofit.engines.select import select_engine
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.recorded_field import recorded_field_on_detector
from holofit.scattering.theory import Orientation, ScatteredWave, ScatteringEngine

__all__ = ["calc_hologram", "hologram"]


def calc_hologram(
    wave: ScatteredWave,
    position_um: ArrayLike,
    grid: DetectorGrid,
    alpha: float = 1.0,
    far_field: bool = False,
) -> NDArray[np.float64]:
    """Normalised hologram of a solved particle at a position.

    Parameters
    ----------
    wave : ScatteredWave
        The solved particle (any engine).
    position_um : array_like, shape (3,)
        Full-frame particle centre ``(x, y, z)``, um.
    grid : DetectorGrid
        The pixels.
    alpha : float
        Scattered-field scaling.
    far_field : bool
        Use the asymptotic far-field form of the scattered field (as ADDA and the paper did).
        Engines that only know the far field use it whatever this says. Ignored when
        ``wave.optics.numerical_aperture`` is set: the lens image is built from the far-field
        amplitude exactly, at any distance.

    Returns
    -------
    ndarray, shape ``grid.shape``
        Intensity relative to the background.
    """
    ex, ey = recorded_field_on_detector(wave, position_um, grid, far_field)
    return hologram_intensity(ex, ey, wave.optics.polarization_rad, alpha)


def hologram(
    model: ParticleModel,
    position_um: ArrayLike,
    grid: DetectorGrid,
    optics: Optics,
    orientation: Orientation | None = None,
    alpha: float = 1.0,
    theory: ScatteringEngine | None = None,
    far_field: bool = False,
) -> NDArray[np.float64]:
    """Solve ``model`` and compute its hologram in one call (convenience for one-off use)."""
    theory = theory or select_engine(model)
    wave = theory.solve(model, optics, orientation)
    return calc_hologram(wave, position_um, grid, alpha, far_field)
