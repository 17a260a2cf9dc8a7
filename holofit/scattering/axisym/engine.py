"""The ``exact`` engine: bodies of revolution served from their exact T-matrix.

:class:`AxisymmetricTMatrix` builds the T-matrix of a ``(model, optics)`` once
(:func:`holofit.scattering.axisym.build.build_exact_tmatrix`, kept in a small cache) and
returns every orientation as a :class:`~holofit.scattering.tmatrix_wave.TMatrixWave` (a Wigner
rotation and a product; exact orientation derivatives; the camera plane and the lens through
its expansion), like the built-in DDA serves its lattice's T-matrix. A fit fixes the
engine's discretisation at a reference build of its start model
(:meth:`AxisymmetricTMatrix.fix_discretisation`,
:mod:`holofit.scattering.axisym.discretisation`), so that its T-matrices move smoothly with
the sizes and indices, as a DDA fit fixes its lattice. Points closer than
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
from holofit.scattering.axisym.build import (
    DEFAULT_TOLERANCE,
    build_exact_tmatrix,
    model_description,
)
from holofit.scattering.axisym.discretisation import (
    Discretisation,
    reference_build,
    remember_reference,
)
from holofit.scattering.axisym.profiles import SUPPORTED
from holofit.scattering.expansion_wave import NearField
from holofit.scattering.theory import Orientation, ScatteringEngine
from holofit.scattering.tmatrix import TMatrix
from holofit.scattering.tmatrix_wave import TMatrixWave

__all__ = ["AxisymmetricTMatrix"]

#: T-matrices kept per engine (a fit's initial pass changes sizes and indices often)
CACHE_SIZE = 8


class AxisymmetricTMatrix(ScatteringEngine):
    """Exact T-matrix engine for bodies of revolution (engine name ``exact``).

    Parameters
    ----------
    tolerance : float
        Target truncation estimate of each build (:func:`build_exact_tmatrix`).
    discretisation : Discretisation, optional
        Build every model at this order and with these radial steps (a fit's:
        :meth:`fix_discretisation`); None: each build searches its own order.
    **_ignored
        Other engines' options (``settings``), accepted so that the engine choice can pass
        them to any engine.
    """

    name = "exact"
    models: ClassVar[tuple[type[ParticleModel], ...]] = SUPPORTED
    handles = ("bodies of revolution (spherocylinders, spheroids, cylinders, Janus spheres, "
               "layered spheres)")
    own_tmatrix = True

    def __init__(self, tolerance: float = DEFAULT_TOLERANCE,
                 discretisation: Discretisation | None = None, **_ignored: Any) -> None:
        self.tolerance = float(tolerance)
        self._discretisation = discretisation
        self._reference: tuple[ParticleModel, Optics] | None = None
        self._tmatrices: LRUCache[tuple, TMatrix] = LRUCache(CACHE_SIZE)
        self.builds = 0

    def fix_discretisation(self, model: ParticleModel, optics: Optics,
                           lazy: bool = False) -> Discretisation | None:
        """Fix this engine's discretisation at ``model``'s reference build
        (:func:`~holofit.scattering.axisym.discretisation.reference_build`, searched once
        per process) and keep that build; returns the discretisation. ``lazy``: search only
        when the first T-matrix is needed (returns None), so that a worker given the driver's
        build (:meth:`adopt`) never searches. T-matrices cached so far are forgotten (they
        were built at their own orders)."""
        self.check_model(model)
        self._reference = (model, optics)
        self._discretisation = None
        self._tmatrices = LRUCache(CACHE_SIZE)
        return None if lazy else self.discretisation

    @property
    def discretisation(self) -> Discretisation | None:
        """The discretisation every build uses (None: each build searches its own order)."""
        if self._discretisation is None and self._reference is not None:
            model, optics = self._reference
            ref = reference_build(model, optics, self.tolerance)
            self._discretisation = Discretisation.of(ref)
            self._tmatrices.put(self._key(model, optics), ref)
        return self._discretisation

    def adopt(self, model: ParticleModel, optics: Optics, tm: TMatrix) -> bool:
        """Serve ``(model, optics)`` from ``tm`` (a T-matrix this engine built, e.g. read back
        from its file by the driver's build) if its provenance says it is that model's at
        this wavelength and medium, and at this engine's discretisation (True); else leave it
        (False). The driver's reference build of the model the engine is fixed at is taken
        as this process's (no search of its own)."""
        p = tm.provenance
        same = (p.get("engine") == self.name
                and p.get("model") == model_description(model)
                and _close(p.get("wavelength_um"), optics.wavelength_um)
                and _close(p.get("n_medium"), optics.n_medium))
        if not same:
            return False
        if (self._discretisation is None and self._reference is not None
                and self._key(*self._reference) == self._key(model, optics)
                and remember_reference(model, optics, self.tolerance, tm)):
            self._discretisation = Discretisation.of(tm)
        if self.discretisation is not None and tm.order != self.discretisation.order:
            return False
        self._tmatrices.put(self._key(model, optics), tm)
        return True

    @staticmethod
    def _key(model: ParticleModel, optics: Optics) -> tuple:
        return (model, float(optics.wavelength_um), float(optics.n_medium))

    def tmatrix(self, model: ParticleModel, optics: Optics, **build_options: Any) -> TMatrix:
        """The T-matrix of ``(model, optics)``: cached, else built (options passed to
        :func:`build_exact_tmatrix`). :func:`holofit.dda.tmatrix_io.save_tmatrix` writes it
        to a file that :func:`~holofit.dda.tmatrix_io.load_tmatrix` reads back."""
        self.check_model(model)
        fixed = self.discretisation  # the reference build first (it is cached)
        key = self._key(model, optics)
        tm = self._tmatrices.get(key)
        build_options = {k: v for k, v in build_options.items() if k != "workers"}
        if tm is None:
            if fixed is not None and not build_options:
                tm = fixed.build(model, optics)
            else:
                options = {"tolerance": self.tolerance, **build_options}
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


def _close(a: Any, b: float) -> bool:
    try:
        return abs(float(a) - float(b)) <= 1e-12 * max(abs(float(b)), 1.0)
    except (TypeError, ValueError):
        return False


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
