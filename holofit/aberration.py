"""Spherical aberration of the objective: a phase over its pupil (the value object and the pure
functions of the pupil phase).

Parametrisation
---------------
A real objective imaging into water through a coverslip (an index mismatch, a coverslip of
another thickness than the design's, a depth into the sample) adds to each scattered plane wave
a phase that depends on its angle ``th`` from the optical axis only (Martin, Leahy & Manoharan,
"Improving holographic particle characterization by modeling spherical aberration", Opt.
Express 2022; HoloPy's ``AberratedMieLens``). The pupil coordinate is

    x = cos th - 1        (0 on the axis, cos th_max - 1 at the pupil's edge),

the defocus variable: a particle at height ``z_p`` gives each plane wave the phase
``k z_p x`` (:mod:`holofit.scattering.lens`), so ``x^2`` is the 4th order in the pupil radius
(``x ~ -sin^2 th / 2``), ``x^3`` the 6th. With coefficients ``c = (c_0, c_1, ...)`` in radians
the lens multiplies the wave at ``th`` by ``exp(i Phi(th))``,

    Phi(th) = -x^2 sum_k c_k P_k(x),

``P_k`` the Legendre polynomials (``P_0 = 1``, ``P_1 = x``): ``c_0`` is the 4th-order
(primary, "3rd-order Seidel") spherical aberration, ``c_1`` the 6th-order one, and term ``k``
reaches the wavefront order ``2k + 4``. The coordinate is not normalised by the aperture, so
the coefficients do not change when the NA is fitted with them.

Conventions
-----------
* The numbers are HoloPy's ``spherical_aberration`` coefficients, term for term, so published
  values carry over. HoloPy's lens integral is written in the conjugate time convention
  (its defocus phase is ``k z_p (1 - cos th)``); in holofit's ``exp(-i omega t)`` (the design's
  section 2) the same pupil is the conjugate phase, hence the leading minus sign.
* Sign, physically: ``Phi > 0`` lengthens the optical path of the wave at ``th`` by
  ``Phi / k_0`` against the axial wave. A positive ``c_0`` alone (``Phi = -c_0 x^2 < 0``)
  shortens the marginal rays' paths, as moving the particle farther from the lens (larger
  ``z_p``) does; a fitted ``z`` therefore partly absorbs it, which is why an unmodelled
  aberration shifts ``z`` as well as the index and radius.
* The axial wave (``th = 0``, the incident light, the reference of the hologram) is unchanged:
  ``Phi(0) = 0``.
* Zero coefficients (the default) are the ideal objective, bit for bit.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.polynomial import legendre
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "MAX_SPHERICAL_TERMS",
    "NO_ABERRATION",
    "SPHERICAL_NAMES",
    "Aberration",
    "layer_aberration",
    "pupil_coordinate",
    "spherical_basis",
    "spherical_phase",
]

#: most spherical-aberration coefficients (wavefront orders 4, 6, 8, 10)
MAX_SPHERICAL_TERMS = 4
#: fit-table names of the coefficients (rad), by the highest wavefront order each reaches
SPHERICAL_NAMES = tuple(f"sa{2 * k + 4}_rad" for k in range(MAX_SPHERICAL_TERMS))


def pupil_coordinate(theta: ArrayLike) -> NDArray[np.float64]:
    """``x = cos th - 1`` at angles ``th`` from the axis (rad), as ``-2 sin^2(th / 2)``, which
    keeps its digits near the axis where ``cos th - 1`` would cancel."""
    s = np.sin(0.5 * np.asarray(theta, dtype=float))
    return -2.0 * s * s


def spherical_basis(theta: ArrayLike, n_terms: int) -> NDArray[np.float64]:
    """``-x^2 P_k(x)`` for ``k = 0 .. n_terms - 1`` at angles ``th`` (rad), shape
    ``(n_terms, N)``: ``dPhi / dc_k``, the pupil phase per unit coefficient."""
    x = pupil_coordinate(np.atleast_1d(theta))
    out = np.empty((int(n_terms), x.size))
    lead = -(x * x)
    p_prev, p = np.ones_like(x), x
    for k in range(int(n_terms)):
        if k == 0:
            out[0] = lead
            continue
        if k > 1:  # Bonnet: (k) P_k = (2k - 1) x P_{k-1} - (k - 1) P_{k-2}
            p_prev, p = p, ((2 * k - 1) * x * p - (k - 1) * p_prev) / k
        out[k] = lead * p
    return out


def spherical_phase(theta: ArrayLike, coefficients: Sequence[float]) -> NDArray[np.float64]:
    """``Phi(th) = -x^2 sum_k c_k P_k(x)``, rad (the module docstring), at angles ``th``."""
    c = np.asarray(coefficients, dtype=float)
    x = pupil_coordinate(np.atleast_1d(theta))
    if c.size == 0:
        return np.zeros_like(x)
    return -(x * x) * legendre.legval(x, c)


@functools.lru_cache(maxsize=64)
def _variation(key: tuple[float, ...], theta_max: float, samples: int) -> float:
    """:meth:`Aberration.variation` (cached: a fit asks for it at every hologram)."""
    phase = spherical_phase(np.linspace(0.0, theta_max, samples + 1), key)
    return float(np.abs(np.diff(phase)).sum())


@dataclass(frozen=True)
class Aberration:
    """The objective's pupil phase beyond the ideal lens (default: none).

    Parameters
    ----------
    spherical : sequence of float
        Spherical-aberration coefficients ``c_0, c_1, ...`` (rad; at most
        :data:`MAX_SPHERICAL_TERMS`): ``c_0`` 4th order, ``c_1`` 6th order in the pupil radius,
        HoloPy's ``spherical_aberration`` numbers (module docstring for the phase, its sign and
        its pupil coordinate).

    Notes
    -----
    Kept by :class:`holofit.optics.Optics` and applied by the lens
    (:mod:`holofit.scattering.lens`) to every engine's image alike; it needs an objective (a
    numerical aperture).
    """

    spherical: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        values = tuple(float(v) for v in np.atleast_1d(np.asarray(self.spherical, dtype=float)))
        if len(values) > MAX_SPHERICAL_TERMS:
            raise ValueError(f"at most {MAX_SPHERICAL_TERMS} spherical-aberration coefficients "
                             f"(wavefront orders 4..{2 * MAX_SPHERICAL_TERMS + 2}), got "
                             f"{len(values)}")
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"spherical-aberration coefficients must be finite, got {values}")
        object.__setattr__(self, "spherical", values)

    @property
    def is_zero(self) -> bool:
        """True for the ideal objective (no coefficient or all zero)."""
        return not any(self.spherical)

    @property
    def key(self) -> tuple[float, ...]:
        """The coefficients without trailing zeros (``()`` for none): equal keys, equal pupils
        (a cache key)."""
        c = list(self.spherical)
        while c and c[-1] == 0.0:
            c.pop()
        return tuple(c)

    def phase(self, theta: ArrayLike) -> NDArray[np.float64]:
        """The pupil phase ``Phi`` at angles ``th`` from the axis, rad."""
        return spherical_phase(theta, self.key)

    def variation(self, theta_max: float, samples: int = 64) -> float:
        """Total variation of the pupil phase over ``[0, theta_max]``, rad: what the lens's
        quadrature rule adds nodes for (0 for the ideal objective)."""
        if self.is_zero:
            return 0.0
        return _variation(self.key, float(theta_max), int(samples))

    def padded(self, n_terms: int) -> Aberration:
        """The same pupil with at least ``n_terms`` coefficients (zeros appended)."""
        c = self.spherical
        return Aberration(c + (0.0,) * max(0, int(n_terms) - len(c)))

    @classmethod
    def from_values(cls, values: dict[str, float], start: Aberration | None = None
                    ) -> Aberration:
        """An aberration from fit-table values (``sa4_rad``, ``sa6_rad``, ...), the others
        from ``start``."""
        c = list((start or cls()).spherical)
        for k, name in enumerate(SPHERICAL_NAMES):
            if name in values:
                c += [0.0] * (k + 1 - len(c))
                c[k] = float(values[name])
        return cls(tuple(c))

    def values(self) -> dict[str, float]:
        """The coefficients by fit-table name (``sa4_rad``, ...)."""
        return dict(zip(SPHERICAL_NAMES, self.spherical, strict=False))


#: the ideal objective (the optics' default)
NO_ABERRATION = Aberration()


def layer_aberration(wavelength_um: float, n_medium: float, numerical_aperture: float,
                     n_layer: float, thickness_um: float, n_terms: int = 2,
                     samples: int = 400) -> tuple[Aberration, float]:
    """The spherical aberration of a plane layer the objective's design does not expect, in
    this module's coefficients: a start value, or a realistic size, for a calibration.

    A plane wave leaving the particle at ``th`` in the medium crosses a layer of index
    ``n_layer`` and signed thickness ``t`` (``t > 0``: a layer the design lacks, e.g. a
    coverslip thicker than designed, replacing medium; ``t < 0``: design medium of index
    ``n_layer`` that the sample replaces, e.g. an oil objective focused ``|t|`` into water)
    and gains ``k_0 t (n_layer cos th_l - n_medium cos th)``, ``n_layer sin th_l =
    n_medium sin th`` (Gibson & Lanni, J. Opt. Soc. Am. A 8, 1601 (1991); Torok et al., J.
    Opt. Soc. Am. A 12, 325 (1995)). Its piston and its defocus (constant and linear in
    ``x = cos th - 1``: a shift of the fitted ``z``) are left out by a least-squares fit over
    the pupil, weighted by ``sin th`` (equal solid angles), together with the first
    ``n_terms`` basis functions ``-x^2 P_k(x)``.

    Parameters
    ----------
    wavelength_um : float
        Vacuum wavelength, um.
    n_medium : float
        Index of the medium around the particle.
    numerical_aperture : float
        The objective's NA (the pupil fitted over: ``sin th <= NA / n_medium``).
    n_layer : float
        Index of the layer.
    thickness_um : float
        Signed thickness of the layer, um (see above).
    n_terms : int
        Coefficients returned (at most :data:`MAX_SPHERICAL_TERMS`).
    samples : int
        Points of the fit over the pupil.

    Returns
    -------
    aberration : Aberration
        The fitted coefficients, rad.
    residual_rad : float
        Root-mean-square (``sin th``-weighted) of what they leave of the layer's phase, rad.

    Raises
    ------
    ValueError
        If the layer's index cannot carry every ray of the pupil (``n_layer`` below
        ``NA``: total internal reflection).
    """
    theta_max = float(np.arcsin(min(numerical_aperture / n_medium, 1.0)))
    if n_layer <= n_medium * np.sin(theta_max):
        raise ValueError(f"a layer of index {n_layer} reflects the rays beyond NA {n_layer}: "
                         f"it cannot carry the pupil of NA {numerical_aperture}")
    k0 = 2.0 * np.pi / wavelength_um
    theta = np.linspace(0.0, theta_max, int(samples))
    sin_t, cos_t = np.sin(theta), np.cos(theta)
    cos_l = np.sqrt(1.0 - (n_medium * sin_t / n_layer) ** 2)
    phase = k0 * thickness_um * (n_layer * cos_l - n_medium * cos_t)
    x = pupil_coordinate(theta)
    design = np.vstack([np.ones_like(x), x, spherical_basis(theta, n_terms)]).T
    w = np.sqrt(np.maximum(sin_t, 1e-300))
    coef, *_ = np.linalg.lstsq(design * w[:, None], phase * w, rcond=None)
    left = phase - design @ coef
    residual = float(np.sqrt(np.sum(sin_t * left**2) / np.sum(sin_t)))
    return Aberration(tuple(float(c) for c in coef[2:])), residual
