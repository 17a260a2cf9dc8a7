"""The ``exact`` engine: bodies of revolution served from their exact T-matrix.

:class:`AxisymmetricTMatrix` builds the T-matrix of a ``(model, optics)`` once
(:func:`holofit.scattering.axisym.build.build_exact_tmatrix`, kept in a small cache) and
returns every orientation as a :class:`~holofit.scattering.tmatrix_wave.TMatrixWave` (a Wigner
rotation and a product; exact orientation derivatives; the camera plane and the lens through
its expansion), like the built-in DDA serves its lattice's T-matrix. Points closer than
``NEAR_ZONE`` circumscribing radii are summed from the expansion itself, which is exact (to
truncation) outside the circumscribing sphere; points inside it raise ``ValueError``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from holofit.cache import LRUCache
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.axisym.build import DEFAULT_TOLERANCE, build_exact_tmatrix
from holofit.scattering.axisym.profiles import SUPPORTED
from holofit.scattering.expansion_wave import NearField
from holofit.scattering.theory import Orientation, ScatteringTheory
from holofit.scattering.tmatrix import TMatrix
from holofit.scattering.tmatrix_wave import TMatrixWave

__all__ = ["AxisymmetricTMatrix"]

#: T-matrices kept per engine (a fit's initial pass changes sizes and indices often)
CACHE_SIZE = 8


class AxisymmetricTMatrix(ScatteringTheory):
    """Exact T-matrix engine for bodies of revolution (engine name ``exact``).

    Parameters
    ----------
    tolerance : float
        Target truncation estimate of each build (:func:`build_exact_tmatrix`).
    **_ignored
        Other engines' options (``settings``), accepted so that the engine choice can pass
        them to any engine.
    """

    name = "exact"
    models: ClassVar[tuple[type[ParticleModel], ...]] = SUPPORTED
    handles = ("bodies of revolution (spherocylinders, spheroids, cylinders, Janus spheres, "
               "layered spheres)")
    own_tmatrix = True

    def __init__(self, tolerance: float = DEFAULT_TOLERANCE, **_ignored: Any) -> None:
        self.tolerance = float(tolerance)
        self._tmatrices: LRUCache[tuple, TMatrix] = LRUCache(CACHE_SIZE)
        self.builds = 0

    @staticmethod
    def _key(model: ParticleModel, optics: Optics) -> tuple:
        return (model, float(optics.wavelength_um), float(optics.n_medium))

    def tmatrix(self, model: ParticleModel, optics: Optics, **build_options: Any) -> TMatrix:
        """The T-matrix of ``(model, optics)``: cached, else built (options passed to
        :func:`build_exact_tmatrix`). :func:`holofit.dda.tmatrix_io.save_tmatrix` writes it
        to a file that :func:`~holofit.dda.tmatrix_io.load_tmatrix` reads back."""
        self.check_model(model)
        key = self._key(model, optics)
        tm = self._tmatrices.get(key)
        if tm is None:
            options = {"tolerance": self.tolerance, **build_options}
            options.pop("workers", None)
            tm = build_exact_tmatrix(model, optics, **options)
            self.builds += 1
            self._tmatrices.put(key, tm)
        return tm

    def solve(self, model: ParticleModel, optics: Optics,
              orientation: Orientation | None = None) -> TMatrixWave:
        """The scattered wave of one orientation (the T-matrix built on first use)."""
        tm = self.tmatrix(model, optics)
        wave = TMatrixWave(model, optics, orientation or Orientation(), tm)
        wave._near = _expansion_near_field(wave)
        return wave


def _expansion_near_field(wave: TMatrixWave) -> NearField:
    """Near points from the expansion itself (valid outside the circumscribing sphere)."""
    radius = wave.tmatrix.radius_um

    def field(points: NDArray) -> NDArray[np.complex128]:
        r = np.linalg.norm(points, axis=1)
        if np.any(r <= radius):
            raise ValueError(f"points within the circumscribing sphere ({radius:.4g} um) of "
                             "the particle centre: the exact engine's expansion does not hold")
        return wave.expansion.field_at(points)

    return field
