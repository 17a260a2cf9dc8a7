"""The scattering-theory interface that every engine implements.

A :class:`ScatteringEngine` (Lorenz-Mie, the built-in DDA, ADDA) turns a particle model, an
orientation and the optics into a :class:`ScatteredWave`: a solved problem that knows the
scattered field at any point outside the particle. Positions are applied afterwards, so one
solve serves every position change. The hologram code, ``simulate`` and the fits only talk to
these two classes.

Field convention (see :mod:`holofit.conventions`): fields are lab-frame Cartesian, relative to
the incident plane wave, whose phase is zero at the particle centre; the incident phase at the
particle, ``exp(-i k z_p)``, is applied by the detector-level functions.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from holofit.conventions import DetectorGrid, incident_phase_at
from holofit.optics import Optics
from holofit.particles import ParticleModel

__all__ = ["Orientation", "ScatteredWave", "ScatteringEngine"]


@dataclass(frozen=True)
class Orientation:
    """zyz Euler angles of the particle, rad (:func:`holofit.conventions.euler_zyz`)."""

    psi: float = 0.0
    theta: float = 0.0
    phi: float = 0.0

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.psi, self.theta, self.phi)


class ScatteredWave(ABC):
    """A solved scattering problem: particle, orientation and illumination fixed.

    Attributes
    ----------
    optics : Optics
        The illumination it was solved for.
    exact_near_field : bool
        True if :meth:`field_at` includes the near-field terms exactly; False for engines that
        only know the far-field amplitudes (ADDA), whose fields use the asymptotic form.
    """

    optics: Optics
    exact_near_field: bool = True

    @abstractmethod
    def field_at(self, points_um: ArrayLike, far_field: bool = False) -> NDArray[np.complex128]:
        """Scattered field at points relative to the particle centre.

        Parameters
        ----------
        points_um : array_like, shape (N, 3)
            Lab-frame positions relative to the particle centre, um.
        far_field : bool
            If True, use the asymptotic form ``exp(ikr)/(-ikr) F(r_hat)`` instead of the exact
            field (what ADDA and the paper used).

        Returns
        -------
        ndarray of complex, shape (N, 3)
            Lab Cartesian field, relative to the incident field with zero phase at the particle
            centre.
        """

    def field_on_pixels(
        self,
        position_um: ArrayLike,
        xs_um: ArrayLike,
        ys_um: ArrayLike,
        far_field: bool = False,
    ) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
        """Transverse scattered field at a list of pixel centres, incident phase included.

        Every hologram (a full detector, a masked crop, a random subset of pixels) is computed
        through this method; engines override it with a fast path.

        Parameters
        ----------
        position_um : array_like, shape (3,)
            Full-frame particle position ``(x, y, z)``, um.
        xs_um, ys_um : array_like, shape (N,)
            Full-frame sample-plane coordinates of the pixel centres, um (x along columns).
        far_field : bool
            Asymptotic far-field form instead of the exact field.

        Returns
        -------
        e_x, e_y : ndarray of complex, shape (N,)
        """
        xp, yp, zp = (float(v) for v in np.asarray(position_um, dtype=float).reshape(3))
        xs = np.asarray(xs_um, dtype=float).ravel()
        ys = np.asarray(ys_um, dtype=float).ravel()
        pts = np.stack([xs - xp, ys - yp, np.full(xs.size, -zp)], axis=1)
        e = self.field_at(pts, far_field=far_field) * incident_phase_at(zp, self.optics.k)
        return e[:, 0], e[:, 1]

    def field_on_detector(
        self,
        position_um: ArrayLike,
        grid: DetectorGrid,
        far_field: bool = False,
    ) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
        """Transverse scattered field at the pixels of ``grid``, incident phase included.

        Parameters
        ----------
        position_um : array_like, shape (3,)
            Full-frame particle position ``(x, y, z)``, um.
        grid : DetectorGrid
            The pixels.
        far_field : bool
            Asymptotic far-field form instead of the exact field.

        Returns
        -------
        e_x, e_y : ndarray of complex, shape ``grid.shape``
        """
        x, y = grid.coordinates()
        ex, ey = self.field_on_pixels(position_um, x.ravel(), y.ravel(), far_field)
        return ex.reshape(grid.shape), ey.reshape(grid.shape)


class ScatteringEngine(ABC):
    """An engine that solves a particle model for a given orientation and illumination.

    Its name is its entry in the engine registry (:mod:`holofit.engines.registry`);
    :meth:`can_handle` says which models it solves (the ``auto`` choice of
    :mod:`holofit.engines.select` asks the exact engines in turn).
    """

    name: str = ""
    #: the model classes it solves (empty: any particle model)
    models: ClassVar[tuple[type[ParticleModel], ...]] = ()
    #: the models it solves, in words (error messages)
    handles: str = "any particle"

    @classmethod
    def can_handle(cls, model: ParticleModel) -> bool:
        """True if this engine solves ``model`` (an instance of :attr:`models`, if any)."""
        return not cls.models or isinstance(model, cls.models)

    def check_model(self, model: ParticleModel) -> None:
        """TypeError naming the engine and what it handles if it cannot solve ``model``."""
        if not self.can_handle(model):
            raise TypeError(f"the {self.name} engine handles {self.handles} only, not "
                            f"{model.kind!r}")

    def forget_history(self) -> None:
        """Forget what earlier solves leave behind to speed up later ones (an iterative
        solver's warm starts), so that the next results depend on their own inputs only: a
        batch item's rows are then the same whichever items its worker ran before (a
        resumed run gives an uninterrupted run's rows). Engines without such state do
        nothing."""
        return None

    @abstractmethod
    def solve(
        self, model: ParticleModel, optics: Optics, orientation: Orientation | None = None
    ) -> ScatteredWave:
        """Solve the scattering problem; the result serves every particle position."""


#: the former name, kept for existing code (deprecated)
ScatteringTheory = ScatteringEngine
