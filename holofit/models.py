"""Particle models: the physical description of a scatterer, independent of any engine.

A model holds sizes (um) and absolute refractive indices; the engines (Lorenz-Mie, the built-in
DDA, ADDA) turn it into a scattered field. Orientation and position are not part of a model:
they change from frame to frame while the model stays fixed.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import ClassVar

__all__ = ["MODEL_TYPES", "ParticleModel", "Sphere", "model_from_dict"]


@dataclass(frozen=True)
class ParticleModel:
    """Base class of all particle models."""

    kind: ClassVar[str] = ""
    #: names of the fields that are sizes (um) and must be positive
    size_fields: ClassVar[tuple[str, ...]] = ()
    #: names of the fields that are refractive indices
    index_fields: ClassVar[tuple[str, ...]] = ()
    #: True if the scattering depends on orientation
    anisotropic: ClassVar[bool] = True

    def parameters(self) -> dict[str, float | complex]:
        """Model parameters by name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def replace(self, **changes: float | complex) -> ParticleModel:
        """A copy with some parameters changed."""
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


MODEL_TYPES: dict[str, type[ParticleModel]] = {"sphere": Sphere}


def model_from_dict(kind: str, params: dict[str, float | complex]) -> ParticleModel:
    """Build a model of type ``kind`` from keyword parameters."""
    try:
        cls = MODEL_TYPES[kind]
    except KeyError:
        raise ValueError(
            f"unknown particle model {kind!r}; known: {', '.join(sorted(MODEL_TYPES))}"
        ) from None
    return cls(**params)
