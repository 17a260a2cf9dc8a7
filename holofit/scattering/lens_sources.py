"""Where the lens gets each engine's far field: the imaged pupil field at quadrature angles.

* :class:`SpherePupil`: Lorenz-Mie ``S1, S2`` (azimuthal orders 0 and +-2 only);
* :class:`ExpansionPupil`: an outgoing multipole expansion of order L in the lab frame (orders
  ``|m| <= L + 1``): the built-in DDA's own :attr:`~holofit.dda.engine.DDAWave.expansion`, or
  the projection of any engine's ``far_field_amplitude`` (ADDA: one run on the quadrature grid
  of :func:`holofit.scattering.multipole.expansion_from_far_field`, exact for the band-limited far
  field of sources inside the circumscribing sphere).

A source keeps what it needs and no reference to the wave, so a cache keyed weakly by the wave
can hold it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from holofit.scattering.lens_pupil import expansion_pupil_modes, sphere_pupil
from holofit.scattering.mie import MieWave, far_field_amplitudes
from holofit.scattering.theory import ScatteredWave

if TYPE_CHECKING:
    from holofit.scattering.multipole import MultipoleExpansion

__all__ = ["ExpansionPupil", "SpherePupil", "pupil_source", "wave_radius"]


class SpherePupil:
    """A sphere's far field, from its relative index and size parameter."""

    def __init__(self, wave: MieWave) -> None:
        self.m = wave.m
        self.x = wave.x
        #: series length, the far field's highest multipole order
        self.order = int(wave.a.size)

    def modes(self, theta: NDArray, apodization: str) -> tuple[NDArray, NDArray]:
        """``(a, b)`` of :func:`~holofit.scattering.lens_pupil.sphere_pupil` at ``theta``."""
        s1, s2 = far_field_amplitudes(self.m, self.x, theta)
        return sphere_pupil(s1, s2, np.cos(theta), apodization)


class ExpansionPupil:
    """A far field given by an outgoing multipole expansion (lab frame)."""

    def __init__(self, expansion: MultipoleExpansion) -> None:
        self.expansion = expansion
        self.order = int(expansion.order)

    def modes(self, theta: NDArray, apodization: str) -> tuple[NDArray, NDArray]:
        """``(t_plus, t_minus)`` of
        :func:`~holofit.scattering.lens_pupil.expansion_pupil_modes` at ``theta``."""
        return expansion_pupil_modes(self.expansion, theta, apodization)


def wave_radius(wave: ScatteredWave) -> float:
    """Radius about the particle centre that contains the scatterer, um.

    The wave's own ``radius_um`` if it has one (built-in DDA), else its model's bounding radius
    plus half a dipole-cell diagonal when the wave has a dipole ``geometry`` (ADDA).
    """
    radius = getattr(wave, "radius_um", None)
    if radius is not None:
        return float(radius)
    model = getattr(wave, "model", None)
    if model is None:
        raise TypeError(f"{type(wave).__name__}: cannot tell the particle's size for the lens")
    d = getattr(getattr(wave, "geometry", None), "d", None)
    return float(model.bounding_radius_um) + (0.5 * np.sqrt(3.0) * float(d) if d else 0.0)


def pupil_source(wave: ScatteredWave) -> SpherePupil | ExpansionPupil:
    """The far-field source of any solved wave (see the module docstring).

    Raises
    ------
    TypeError
        If the wave gives no far-field amplitudes.
    """
    if isinstance(wave, MieWave):
        return SpherePupil(wave)
    expansion = getattr(wave, "expansion", None)
    if expansion is not None:
        return ExpansionPupil(expansion)
    far = getattr(wave, "far_field_amplitude", None)
    if far is None:
        raise TypeError(
            f"{type(wave).__name__} gives no far-field amplitudes: the lens model needs them"
        )
    from holofit.scattering.multipole import default_order, expansion_from_far_field

    k = wave.optics.k
    radius = wave_radius(wave)
    # A = lim kr exp(-ikr) E = i F
    expansion = expansion_from_far_field(lambda d: 1j * far(d), k, default_order(k, radius),
                                         radius)
    return ExpansionPupil(expansion)
