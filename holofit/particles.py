"""Particle models: the physical description of a scatterer, independent of any engine.

A model holds sizes (um) and absolute refractive indices; the engines (Lorenz-Mie, the built-in
DDA, ADDA) turn it into a scattered field. Orientation and position are not part of a model:
they change from frame to frame while the model stays fixed.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, fields
from typing import Any, ClassVar

import numpy as np

from holofit.io.shapefile import read_shape_file

__all__ = [
    "MODEL_TYPES",
    "Cluster",
    "CoatedSphere",
    "Cylinder",
    "Dimer",
    "Ellipsoid",
    "JanusSphere",
    "ParticleModel",
    "Sphere",
    "Spherocylinder",
    "Spheroid",
    "VoxelShape",
    "model_from_dict",
]


@dataclass(frozen=True)
class ParticleModel:
    """Base class of all particle models."""

    kind: ClassVar[str] = ""
    #: names of the fields that are sizes (um) and must be positive
    size_fields: ClassVar[tuple[str, ...]] = ()
    #: names of the fields that are lengths (um) allowed to be zero
    nonnegative_fields: ClassVar[tuple[str, ...]] = ()
    #: names of the fields that are refractive indices
    index_fields: ClassVar[tuple[str, ...]] = ()
    #: True if the scattering depends on orientation
    anisotropic: ClassVar[bool] = True
    #: True if the shape is symmetric about its particle z axis (a spin phi changes nothing)
    axisymmetric: ClassVar[bool] = True

    def parameters(self) -> dict[str, float | complex]:
        """Model parameters by name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def replace(self, **changes: Any) -> ParticleModel:
        """A copy with some parameters changed (numbers; a voxel shape's or a cluster's
        ``indices`` as a tuple)."""
        params = self.parameters()
        params.update(changes)
        return type(self)(**params)

    def __post_init__(self) -> None:
        for name in self.size_fields:
            value = getattr(self, name)
            if not value > 0:
                raise ValueError(
                    f"{self.kind}: {name} must be a positive length in um, got {value}"
                )
        for name in self.nonnegative_fields:
            value = getattr(self, name)
            if not value >= 0:
                raise ValueError(f"{self.kind}: {name} must be a length >= 0 in um, got {value}")
        for name in self.index_fields:
            value = complex(getattr(self, name))
            if value.real <= 0 or value.imag < 0:
                raise ValueError(
                    f"{self.kind}: {name} must be a refractive index with positive real part "
                    f"and Im >= 0 (absorbing), got {value}"
                )

    @property
    def bounding_radius_um(self) -> float:
        """Radius of the smallest sphere about the model centre that contains the particle."""
        raise NotImplementedError

    @property
    def head_tail_symmetric(self) -> bool:
        """True if the particle is its own mirror image through the x-y plane (u and -u are
        the same orientation: rods, spheroids; not a Janus particle)."""
        return True


@dataclass(frozen=True)
class Sphere(ParticleModel):
    """Homogeneous sphere.

    Parameters
    ----------
    radius_um : float
        Radius, um.
    index : complex
        Absolute refractive index.
    """

    radius_um: float
    index: complex

    kind: ClassVar[str] = "sphere"
    size_fields: ClassVar[tuple[str, ...]] = ("radius_um",)
    index_fields: ClassVar[tuple[str, ...]] = ("index",)
    anisotropic: ClassVar[bool] = False

    @property
    def bounding_radius_um(self) -> float:
        return self.radius_um


@dataclass(frozen=True)
class Spherocylinder(ParticleModel):
    """Spherocylinder (capsule) along particle z, the paper's rod model.

    Parameters
    ----------
    a_um : float
        Cap radius (half the width), um.
    b_um : float
        Half tip-to-tip length, um (``b >= a``; the cylindrical part is ``2(b - a)`` long).
    index : complex
        Absolute refractive index.
    """

    a_um: float
    b_um: float
    index: complex

    kind: ClassVar[str] = "spherocylinder"
    size_fields: ClassVar[tuple[str, ...]] = ("a_um", "b_um")
    index_fields: ClassVar[tuple[str, ...]] = ("index",)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.b_um < self.a_um:
            raise ValueError(
                f"spherocylinder: half-length b_um ({self.b_um}) must be >= cap radius a_um "
                f"({self.a_um})"
            )

    @property
    def bounding_radius_um(self) -> float:
        return self.b_um


@dataclass(frozen=True)
class JanusSphere(ParticleModel):
    """Sphere with a hemispherical cap shell on its particle +z side (the paper's Janus model).

    The particle centre is the centre of the core sphere.

    Parameters
    ----------
    radius_um : float
        Core radius, um.
    cap_thickness_um : float
        Maximum thickness of the cap (at the pole), um.
    index_core, index_cap : complex
        Absolute refractive indices of core and cap.
    """

    radius_um: float
    cap_thickness_um: float
    index_core: complex
    index_cap: complex

    kind: ClassVar[str] = "janus"
    size_fields: ClassVar[tuple[str, ...]] = ("radius_um", "cap_thickness_um")
    index_fields: ClassVar[tuple[str, ...]] = ("index_core", "index_cap")

    @property
    def bounding_radius_um(self) -> float:
        return self.radius_um + self.cap_thickness_um

    @property
    def head_tail_symmetric(self) -> bool:
        return False


@dataclass(frozen=True)
class Spheroid(ParticleModel):
    """Spheroid with its symmetry axis along particle z.

    Parameters
    ----------
    a_um : float
        Equatorial semi-axis, um.
    c_um : float
        Polar semi-axis (along z), um.
    index : complex
        Absolute refractive index.
    """

    a_um: float
    c_um: float
    index: complex

    kind: ClassVar[str] = "spheroid"
    size_fields: ClassVar[tuple[str, ...]] = ("a_um", "c_um")
    index_fields: ClassVar[tuple[str, ...]] = ("index",)

    @property
    def bounding_radius_um(self) -> float:
        return max(self.a_um, self.c_um)


@dataclass(frozen=True)
class Ellipsoid(ParticleModel):
    """Triaxial ellipsoid with semi-axes along the particle x, y, z axes, um."""

    ax_um: float
    ay_um: float
    az_um: float
    index: complex

    kind: ClassVar[str] = "ellipsoid"
    axisymmetric: ClassVar[bool] = False
    size_fields: ClassVar[tuple[str, ...]] = ("ax_um", "ay_um", "az_um")
    index_fields: ClassVar[tuple[str, ...]] = ("index",)

    @property
    def bounding_radius_um(self) -> float:
        return max(self.ax_um, self.ay_um, self.az_um)


@dataclass(frozen=True)
class Cylinder(ParticleModel):
    """Flat-ended circular cylinder along particle z.

    Parameters
    ----------
    radius_um : float
        Radius, um.
    half_length_um : float
        Half the length, um.
    index : complex
        Absolute refractive index.
    """

    radius_um: float
    half_length_um: float
    index: complex

    kind: ClassVar[str] = "cylinder"
    size_fields: ClassVar[tuple[str, ...]] = ("radius_um", "half_length_um")
    index_fields: ClassVar[tuple[str, ...]] = ("index",)

    @property
    def bounding_radius_um(self) -> float:
        return float(np.hypot(self.radius_um, self.half_length_um))


@dataclass(frozen=True)
class Dimer(ParticleModel):
    """Two spheres on the particle z axis, sphere 1 below (-z), sphere 2 above (+z).

    The particle centre is the centre of volume of the pair; the symmetry axis points from
    sphere 1 to sphere 2.

    Parameters
    ----------
    radius1_um, radius2_um : float
        Radii, um.
    gap_um : float
        Surface-to-surface distance, um (0: touching).
    index1, index2 : complex
        Absolute refractive indices.
    """

    radius1_um: float
    radius2_um: float
    gap_um: float
    index1: complex
    index2: complex

    kind: ClassVar[str] = "dimer"
    size_fields: ClassVar[tuple[str, ...]] = ("radius1_um", "radius2_um")
    nonnegative_fields: ClassVar[tuple[str, ...]] = ("gap_um",)
    index_fields: ClassVar[tuple[str, ...]] = ("index1", "index2")

    def sphere_centres_z(self) -> tuple[float, float]:
        """z of the two sphere centres relative to the centre of volume, um."""
        a1, a2 = self.radius1_um, self.radius2_um
        sep = a1 + a2 + self.gap_um
        v1, v2 = a1**3, a2**3
        z1 = -sep * v2 / (v1 + v2)
        return z1, z1 + sep

    @property
    def bounding_radius_um(self) -> float:
        z1, z2 = self.sphere_centres_z()
        return max(-z1 + self.radius1_um, z2 + self.radius2_um)

    @property
    def head_tail_symmetric(self) -> bool:
        return self.radius1_um == self.radius2_um and complex(self.index1) == complex(
            self.index2)


@dataclass(frozen=True)
class CoatedSphere(ParticleModel):
    """A sphere with a concentric shell of uniform thickness (exact: coated-sphere Lorenz-Mie,
    :mod:`holofit.scattering.coated_mie`).

    Parameters
    ----------
    radius_um : float
        Core radius, um.
    shell_thickness_um : float
        Shell thickness, um (the outer radius is ``radius_um + shell_thickness_um``).
    index_core, index_shell : complex
        Absolute refractive indices of core and shell.
    """

    radius_um: float
    shell_thickness_um: float
    index_core: complex
    index_shell: complex

    kind: ClassVar[str] = "coated_sphere"
    size_fields: ClassVar[tuple[str, ...]] = ("radius_um", "shell_thickness_um")
    index_fields: ClassVar[tuple[str, ...]] = ("index_core", "index_shell")
    anisotropic: ClassVar[bool] = False

    @property
    def bounding_radius_um(self) -> float:
        return self.radius_um + self.shell_thickness_um


#: relative tolerance on the centre distance below which two cluster spheres overlap
OVERLAP_TOLERANCE = 1e-9


@dataclass(frozen=True)
class Cluster(ParticleModel):
    """Homogeneous spheres at fixed positions in the particle frame (touching or apart, not
    overlapping); exact by the superposition T-matrix (:mod:`holofit.scattering.cluster`).

    Parameters
    ----------
    radii_um : tuple of float
        Sphere radii, um.
    indices : tuple of complex
        Absolute refractive index of each sphere.
    positions_um : tuple of (x, y, z)
        Sphere centres in the particle frame, relative to the particle centre (the origin of
        the particle frame, about which the particle is positioned and rotated), um.
    """

    radii_um: tuple[float, ...]
    indices: tuple[complex, ...]
    positions_um: tuple[tuple[float, float, float], ...]

    kind: ClassVar[str] = "cluster"
    axisymmetric: ClassVar[bool] = False

    def __post_init__(self) -> None:
        radii = tuple(float(r) for r in self.radii_um)
        indices = tuple(complex(n) for n in self.indices)
        try:
            pos = tuple(tuple(float(v) for v in p) for p in self.positions_um)
        except TypeError:
            raise ValueError("cluster: positions_um must be a list of [x, y, z]") from None
        object.__setattr__(self, "radii_um", radii)
        object.__setattr__(self, "indices", indices)
        object.__setattr__(self, "positions_um", pos)
        if not radii:
            raise ValueError("cluster: at least one sphere is needed")
        if not len(radii) == len(indices) == len(pos):
            raise ValueError(f"cluster: {len(radii)} radii, {len(indices)} indices and "
                             f"{len(pos)} positions: one of each per sphere")
        for i, (r, n, p) in enumerate(zip(radii, indices, pos, strict=True)):
            if not r > 0:
                raise ValueError(f"cluster: radii_um[{i}] must be a positive length in um, "
                                 f"got {r}")
            if n.real <= 0 or n.imag < 0:
                raise ValueError(f"cluster: indices[{i}] must have Re > 0 and Im >= 0, got {n}")
            if len(p) != 3 or not all(np.isfinite(p)):
                raise ValueError(f"cluster: positions_um[{i}] must be [x, y, z] in um, got {p}")
        c = np.asarray(pos)
        for i in range(len(radii)):
            for j in range(i):
                dist = float(np.linalg.norm(c[i] - c[j]))
                if dist < (radii[i] + radii[j]) * (1.0 - OVERLAP_TOLERANCE):
                    raise ValueError(
                        f"cluster: spheres {j} and {i} overlap (centres {dist:.4g} um apart, "
                        f"radii {radii[j]:.4g} + {radii[i]:.4g} um)")

    @property
    def bounding_radius_um(self) -> float:
        c = np.asarray(self.positions_um)
        return float(np.max(np.linalg.norm(c, axis=1) + np.asarray(self.radii_um)))

    @property
    def head_tail_symmetric(self) -> bool:
        return False


@dataclass(frozen=True)
class VoxelShape(ParticleModel):
    """A user's dipole set from an ADDA shape file (one or several domains).

    Parameters
    ----------
    path : str
        ADDA text shape file: ``ix iy iz`` or ``ix iy iz domain`` per line.
    dipole_size_um : float
        Lattice spacing, um.
    indices : tuple of complex
        Absolute refractive index of each domain (domain 1 first).
    centre_um : tuple of float
        Position of the particle centre relative to the centre of the dipoles' bounding
        box, in the file's frame, um.
    """

    path: str
    dipole_size_um: float
    indices: tuple[complex, ...]
    centre_um: tuple[float, float, float] = (0.0, 0.0, 0.0)

    kind: ClassVar[str] = "voxels"
    size_fields: ClassVar[tuple[str, ...]] = ("dipole_size_um",)
    axisymmetric: ClassVar[bool] = False

    @property
    def head_tail_symmetric(self) -> bool:
        return False

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "indices", tuple(complex(v) for v in self.indices))
        object.__setattr__(self, "centre_um", tuple(float(v) for v in self.centre_um))
        for i, value in enumerate(self.indices):
            if value.real <= 0 or value.imag < 0:
                raise ValueError(f"voxels: indices[{i}] must have Re > 0 and Im >= 0, got {value}")

    @functools.cached_property
    def bounding_radius_um(self) -> float:  # type: ignore[override]
        """Radius about the particle centre of the sphere holding every voxel (read once)."""
        ijk, _ = read_shape_file(self.path)
        centre = (ijk.max(axis=0) + ijk.min(axis=0)) / 2
        pos = (ijk - centre) * self.dipole_size_um - np.asarray(self.centre_um)
        return float(np.sqrt((pos**2).sum(axis=1)).max() + self.dipole_size_um * np.sqrt(3) / 2)


MODEL_TYPES: dict[str, type[ParticleModel]] = {
    cls.kind: cls
    for cls in (Sphere, Spherocylinder, JanusSphere, Spheroid, Ellipsoid, Cylinder, Dimer,
                CoatedSphere, Cluster, VoxelShape)
}


def model_from_dict(kind: str, params: dict[str, float | complex]) -> ParticleModel:
    """Build a model of type ``kind`` from keyword parameters."""
    try:
        cls = MODEL_TYPES[kind]
    except KeyError:
        raise ValueError(
            f"unknown particle model {kind!r}; known: {', '.join(sorted(MODEL_TYPES))}"
        ) from None
    return cls(**params)
