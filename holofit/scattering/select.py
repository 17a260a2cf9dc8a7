"""Choosing the scattering engine for a particle (``--engine`` and the ``[dda]`` table)."""

from __future__ import annotations

from holofit.config import ParticleConfig
from holofit.models import Sphere
from holofit.scattering.registry import get_theory
from holofit.scattering.theory import ScatteringTheory

__all__ = ["ENGINE_CHOICES", "theory_for"]

ENGINE_CHOICES = ("auto", "mie", "builtin", "adda")


def theory_for(config: ParticleConfig, engine: str | None = None) -> ScatteringTheory:
    """The engine for a particle-model config.

    Parameters
    ----------
    config : ParticleConfig
        The particle, with its optional ``[dda]`` settings.
    engine : {"auto", "mie", "builtin", "adda"}, optional
        Overrides the config. ``auto`` (default): exact Lorenz-Mie for spheres, otherwise the
        ``[dda] engine`` of the config (the built-in DDA unless it says ``adda``).
    """
    engine = engine or "auto"
    if engine not in ENGINE_CHOICES:
        raise ValueError(f"engine must be one of {ENGINE_CHOICES}, got {engine!r}")
    settings = config.dda_settings()
    if engine == "auto":
        if isinstance(config.model, Sphere) and "dda" not in config.settings:
            engine = "mie"
        else:
            engine = settings.engine
    if engine == "mie":
        if not isinstance(config.model, Sphere):
            raise ValueError(
                f"{config.path}: Lorenz-Mie theory handles spheres only, not {config.model.kind!r}"
            )
        return get_theory("mie")
    return get_theory(engine, settings=settings)
