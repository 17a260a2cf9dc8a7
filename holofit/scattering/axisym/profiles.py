"""Bodies of revolution as permittivity profiles ``eps(r, theta)`` on spheres about the centre.

Every particle this package solves is a body of revolution about particle z made of a few
homogeneous materials. On the sphere of radius ``r`` about the particle centre, each material
occupies a union of polar-angle intervals; with ``x = cos(theta)`` a profile gives, for any
``r``, the intervals ``[x_lo, x_hi]`` not filled by the medium and their relative permittivity
``(n_material / n_medium)^2``. The exact angular integrals of
:mod:`holofit.scattering.axisym.angular` are split at these interval ends, so the profile's
discontinuities in ``theta`` cost no accuracy.

A profile also names

* ``r_start`` and ``index_start``: the largest sphere about the centre made of one material
  (the invariant imbedding starts from its Lorenz-Mie T-matrix);
* ``r_outer``: the circumscribing radius;
* ``breaks``: the radii between ``r_start`` and ``r_outer`` where an interval end changes its
  formula (a kink or a square-root end in ``r``); the radial integration runs segment by
  segment between them, each with a change of variable that makes square-root ends smooth.

Homogeneous star-shaped bodies also give their surface ``r(theta)`` and its derivative
(:meth:`Profile.surface`), what the extended-boundary-condition method integrates over.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from holofit.particles import (
    CoatedSphere,
    Cylinder,
    JanusSphere,
    ParticleModel,
    Sphere,
    Spherocylinder,
    Spheroid,
)

__all__ = [
    "CapProfile",
    "CylinderProfile",
    "LayeredProfile",
    "Profile",
    "SpherocylinderProfile",
    "SpheroidProfile",
    "TaperedJanusSphere",
    "profile_of",
    "supports_model",
]

#: an interval of ``x = cos(theta)`` and its relative permittivity
Interval = tuple[float, float, complex]


def _rel_eps(index: complex, n_medium: float) -> complex:
    return complex(index) ** 2 / float(n_medium) ** 2


@dataclass(frozen=True)
class TaperedJanusSphere(ParticleModel):
    """Sphere with a tapered ("crescent") cap on its particle +z side.

    The cap is what lies inside a sphere of the core's radius displaced by the cap thickness
    along +z and outside the core (HoloPy's ``JanusSphere_Tapered``, the shape directional
    sputtering leaves): thickness ``t`` at the pole, falling to zero on the circle
    ``z = t / 2`` (polar angle ``arccos(t / 2R)``). The particle centre is the core's centre.

    Parameters
    ----------
    radius_um : float
        Core radius ``R``, um.
    cap_thickness_um : float
        Cap thickness at the pole ``t``, um (``t < 2 R``).
    index_core, index_cap : complex
        Absolute refractive indices of core and cap.
    """

    radius_um: float
    cap_thickness_um: float
    index_core: complex
    index_cap: complex

    kind = "janus_tapered"  # type: ignore[assignment]
    size_fields = ("radius_um", "cap_thickness_um")  # type: ignore[assignment]
    index_fields = ("index_core", "index_cap")  # type: ignore[assignment]

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.cap_thickness_um < 2 * self.radius_um:
            raise ValueError("janus_tapered: cap_thickness_um must be below the core diameter")

    @property
    def bounding_radius_um(self) -> float:
        return self.radius_um + self.cap_thickness_um

    @property
    def head_tail_symmetric(self) -> bool:
        return False


class Profile:
    """A body of revolution about particle z as ``eps(r, theta)`` (module docstring)."""

    r_start: float
    index_start: complex
    r_outer: float
    #: True if ``eps(r, pi - theta) = eps(r, theta)`` (up-down symmetric bodies)
    mirror_symmetric: bool = False
    #: True if one material: :meth:`surface` is defined (EBCM)
    homogeneous: bool = False
    index: complex = 1.0

    def breaks(self) -> list[float]:
        """Segment ends from ``r_start`` to ``r_outer``, um (ascending, both included)."""
        return [self.r_start, self.r_outer]

    def intervals(self, r: float, n_medium: float) -> list[Interval]:
        """The non-medium intervals of ``x = cos(theta)`` on the sphere of radius ``r`` (um)
        and their permittivities relative to the medium."""
        raise NotImplementedError

    def surface(self, theta: NDArray) -> tuple[NDArray, NDArray]:
        """``r(theta)`` and ``dr/dtheta`` of the surface, um (homogeneous bodies only)."""
        raise NotImplementedError

    def surface_kinks(self) -> list[float]:
        """Polar angles (rad, in (0, pi)) where the surface's curvature jumps or it has an
        edge: the EBCM's quadrature is split there."""
        return []


@dataclass(frozen=True)
class SpherocylinderProfile(Profile):
    """Capsule of cap radius ``a`` and half tip-to-tip length ``b`` (um) along z."""

    a: float
    b: float
    index: complex

    mirror_symmetric = True
    homogeneous = True

    @property
    def r_start(self) -> float:  # type: ignore[override]
        return self.a

    @property
    def index_start(self) -> complex:  # type: ignore[override]
        return self.index

    @property
    def r_outer(self) -> float:  # type: ignore[override]
        return self.b

    def breaks(self) -> list[float]:
        h = self.b - self.a
        if h <= 0:
            return [self.a]
        return [self.a, float(np.hypot(self.a, h)), self.b]

    def intervals(self, r: float, n_medium: float) -> list[Interval]:
        a, h = self.a, self.b - self.a
        if r <= a:
            return [(-1.0, 1.0, _rel_eps(self.index, n_medium))]
        if r >= self.b:
            return []
        if r * r <= a * a + h * h:
            xb = np.sqrt(max(0.0, 1.0 - (a / r) ** 2))
        else:
            xb = (r * r + h * h - a * a) / (2.0 * r * h)
        xb = float(min(max(xb, 0.0), 1.0))
        e = _rel_eps(self.index, n_medium)
        return [(-1.0, -xb, e), (xb, 1.0, e)]

    def surface(self, theta: NDArray) -> tuple[NDArray, NDArray]:
        a, h = self.a, self.b - self.a
        t = np.asarray(theta, dtype=float)
        c, s = np.cos(t), np.sin(t)
        ac = np.abs(c)
        # cap: r^2 - 2 r h |c| + h^2 - a^2 = 0;  side: r s = a
        disc = np.sqrt(np.maximum(a * a - h * h * s * s, 0.0))
        r_cap = h * ac + disc
        with np.errstate(divide="ignore", invalid="ignore"):
            r_side = a / s
        tj = np.arctan2(a, h) if h > 0 else np.pi / 2  # junction from the axis
        on_cap = np.minimum(t, np.pi - t) <= tj
        r = np.where(on_cap, r_cap, r_side)
        sgn = np.sign(c)
        with np.errstate(divide="ignore", invalid="ignore"):
            dcap = -h * sgn * s - h * h * s * c / np.where(disc > 0, disc, 1.0)
            dside = -a * c / (s * s)
        dr = np.where(on_cap, dcap, dside)
        return r, dr

    def surface_kinks(self) -> list[float]:
        h = self.b - self.a
        if h <= 0:
            return []
        tj = float(np.arctan2(self.a, h))
        return [tj, float(np.pi - tj)]


@dataclass(frozen=True)
class SpheroidProfile(Profile):
    """Spheroid of equatorial semi-axis ``a`` and polar semi-axis ``c`` (um)."""

    a: float
    c: float
    index: complex

    mirror_symmetric = True
    homogeneous = True

    @property
    def r_start(self) -> float:  # type: ignore[override]
        return min(self.a, self.c)

    @property
    def index_start(self) -> complex:  # type: ignore[override]
        return self.index

    @property
    def r_outer(self) -> float:  # type: ignore[override]
        return max(self.a, self.c)

    def breaks(self) -> list[float]:
        if self.a == self.c:
            return [self.a]
        return [self.r_start, self.r_outer]

    def intervals(self, r: float, n_medium: float) -> list[Interval]:
        a, c = self.a, self.c
        e = _rel_eps(self.index, n_medium)
        if r <= min(a, c):
            return [(-1.0, 1.0, e)]
        if r >= max(a, c):
            return []
        xb2 = (1.0 / a**2 - 1.0 / r**2) / (1.0 / a**2 - 1.0 / c**2)
        xb = float(np.sqrt(min(max(xb2, 0.0), 1.0)))
        if c > a:  # prolate: the body near the poles
            return [(-1.0, -xb, e), (xb, 1.0, e)]
        return [(-xb, xb, e)]

    def surface(self, theta: NDArray) -> tuple[NDArray, NDArray]:
        t = np.asarray(theta, dtype=float)
        s, c = np.sin(t), np.cos(t)
        q = (s / self.a) ** 2 + (c / self.c) ** 2
        r = 1.0 / np.sqrt(q)
        dq = 2.0 * s * c * (1.0 / self.a**2 - 1.0 / self.c**2)
        return r, -0.5 * r**3 * dq


@dataclass(frozen=True)
class CylinderProfile(Profile):
    """Flat-ended cylinder of radius ``rho`` and half-length ``h`` (um) along z."""

    rho: float
    h: float
    index: complex

    mirror_symmetric = True
    homogeneous = True

    @property
    def r_start(self) -> float:  # type: ignore[override]
        return min(self.rho, self.h)

    @property
    def index_start(self) -> complex:  # type: ignore[override]
        return self.index

    @property
    def r_outer(self) -> float:  # type: ignore[override]
        return float(np.hypot(self.rho, self.h))

    def breaks(self) -> list[float]:
        lo, hi = sorted((self.rho, self.h))
        out = [lo]
        if hi > lo:
            out.append(hi)
        out.append(self.r_outer)
        return out

    def intervals(self, r: float, n_medium: float) -> list[Interval]:
        e = _rel_eps(self.index, n_medium)
        if r <= self.r_start:
            return [(-1.0, 1.0, e)]
        if r >= self.r_outer:
            return []
        x_lo = float(np.sqrt(max(0.0, 1.0 - (self.rho / r) ** 2)))
        x_hi = float(min(1.0, self.h / r))
        if x_hi <= x_lo:
            return []
        if x_lo == 0.0:
            return [(-x_hi, x_hi, e)]
        return [(-x_hi, -x_lo, e), (x_lo, x_hi, e)]

    def surface(self, theta: NDArray) -> tuple[NDArray, NDArray]:
        t = np.asarray(theta, dtype=float)
        s, c = np.sin(t), np.cos(t)
        tc = np.arctan2(self.rho, self.h)
        on_end = np.minimum(t, np.pi - t) <= tc
        with np.errstate(divide="ignore", invalid="ignore"):
            r_end = self.h / np.abs(c)
            r_side = self.rho / s
            d_end = self.h * s * np.sign(c) / (c * c)
            d_side = -self.rho * c / (s * s)
        return np.where(on_end, r_end, r_side), np.where(on_end, d_end, d_side)

    def surface_kinks(self) -> list[float]:
        tc = float(np.arctan2(self.rho, self.h))
        return [tc, float(np.pi - tc)]


@dataclass(frozen=True)
class LayeredProfile(Profile):
    """Concentric spheres: outer radii (ascending, um) and the index of each layer."""

    radii: tuple[float, ...]
    indices: tuple[complex, ...]

    mirror_symmetric = True

    @property
    def r_start(self) -> float:  # type: ignore[override]
        return self.radii[0]

    @property
    def index_start(self) -> complex:  # type: ignore[override]
        return self.indices[0]

    @property
    def r_outer(self) -> float:  # type: ignore[override]
        return self.radii[-1]

    def breaks(self) -> list[float]:
        return list(self.radii)

    def intervals(self, r: float, n_medium: float) -> list[Interval]:
        for radius, index in zip(self.radii, self.indices, strict=True):
            if r < radius:
                return [(-1.0, 1.0, _rel_eps(index, n_medium))]
        return []


@dataclass(frozen=True)
class CapProfile(Profile):
    """A core sphere with a cap shell on its +z side (Janus particles).

    ``x_edge`` is ``cos`` of the cap's rim angle for the uniform cap (0: the hemispherical
    shell of :class:`holofit.particles.JanusSphere`; -1: a full shell, the coated sphere);
    ``tapered`` selects the crescent cap of :class:`TaperedJanusSphere` instead.
    """

    radius: float
    thickness: float
    index_core: complex
    index_cap: complex
    x_edge: float = 0.0
    tapered: bool = False

    @property
    def r_start(self) -> float:  # type: ignore[override]
        return self.radius

    @property
    def index_start(self) -> complex:  # type: ignore[override]
        return self.index_core

    @property
    def r_outer(self) -> float:  # type: ignore[override]
        return self.radius + self.thickness

    @property
    def mirror_symmetric(self) -> bool:  # type: ignore[override]
        return (not self.tapered) and self.x_edge <= -1.0

    def intervals(self, r: float, n_medium: float) -> list[Interval]:
        if r <= self.radius:
            return [(-1.0, 1.0, _rel_eps(self.index_core, n_medium))]
        if r >= self.r_outer:
            return []
        e = _rel_eps(self.index_cap, n_medium)
        if self.tapered:
            t, big_r = self.thickness, self.radius
            xb = (r * r + t * t - big_r * big_r) / (2.0 * r * t)
            xb = float(min(max(xb, -1.0), 1.0))
            return [(xb, 1.0, e)] if xb < 1.0 else []
        return [(float(self.x_edge), 1.0, e)]


def profile_of(model: ParticleModel) -> Profile:
    """The profile of a supported model (:func:`supports_model`).

    Raises
    ------
    TypeError
        For a model that is not a supported body of revolution.
    """
    if isinstance(model, Spherocylinder):
        return SpherocylinderProfile(float(model.a_um), float(model.b_um), complex(model.index))
    if isinstance(model, Spheroid):
        return SpheroidProfile(float(model.a_um), float(model.c_um), complex(model.index))
    if isinstance(model, Cylinder):
        return CylinderProfile(float(model.radius_um), float(model.half_length_um),
                               complex(model.index))
    if isinstance(model, Sphere):
        return LayeredProfile((float(model.radius_um),), (complex(model.index),))
    if isinstance(model, CoatedSphere):
        return LayeredProfile(
            (float(model.radius_um), float(model.radius_um + model.shell_thickness_um)),
            (complex(model.index_core), complex(model.index_shell)))
    if isinstance(model, JanusSphere):
        return CapProfile(float(model.radius_um), float(model.cap_thickness_um),
                          complex(model.index_core), complex(model.index_cap))
    if isinstance(model, TaperedJanusSphere):
        return CapProfile(float(model.radius_um), float(model.cap_thickness_um),
                          complex(model.index_core), complex(model.index_cap), tapered=True)
    raise TypeError(f"no body-of-revolution profile for particle model {model.kind!r}")


#: the models :func:`profile_of` describes
SUPPORTED = (Spherocylinder, Spheroid, Cylinder, Sphere, CoatedSphere, JanusSphere,
             TaperedJanusSphere)


def supports_model(model: ParticleModel) -> bool:
    """True if ``model`` is a body of revolution this package builds a T-matrix for."""
    return isinstance(model, SUPPORTED)
