"""Holograms on a detector: the scattered field of a solved particle, interfered with the
incident plane wave (DESIGN.md section 2; formula in :mod:`holofit.conventions`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.conventions import DetectorGrid, hologram_intensity
from holofit.models import ParticleModel
from holofit.optics import Optics
from holofit.scattering.theory import Orientation, ScatteredWave, ScatteringTheory

__all__ = ["calc_hologram", "default_theory", "hologram"]


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
        Engines that only know the far field use it whatever this says.

    Returns
    -------
    ndarray, shape ``grid.shape``
        Intensity relative to the background.
    """
    ex, ey = wave.field_on_detector(position_um, grid, far_field=far_field)
    return hologram_intensity(ex, ey, wave.optics.polarization_rad, alpha)


def default_theory(model: ParticleModel) -> ScatteringTheory:
    """Lorenz-Mie for spheres; the built-in DDA for every other model."""
    from holofit.models import Sphere
    from holofit.scattering.mie import LorenzMie

    if isinstance(model, Sphere):
        return LorenzMie()
    from holofit.scattering.registry import get_theory

    return get_theory("builtin")


def hologram(
    model: ParticleModel,
    position_um: ArrayLike,
    grid: DetectorGrid,
    optics: Optics,
    orientation: Orientation | None = None,
    alpha: float = 1.0,
    theory: ScatteringTheory | None = None,
    far_field: bool = False,
) -> NDArray[np.float64]:
    """Solve ``model`` and compute its hologram in one call (convenience for one-off use)."""
    theory = theory or default_theory(model)
    wave = theory.solve(model, optics, orientation)
    return calc_hologram(wave, position_um, grid, alpha, far_field)
