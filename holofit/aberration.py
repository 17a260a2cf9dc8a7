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
        phase = self.phase(np.linspace(0.0, float(theta_max), int(samples) + 1))
        return float(np.abs(np.diff(phase)).sum())

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
