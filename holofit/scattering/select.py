"""Choosing the scattering engine for a particle: the one rule, used by every stage.

``auto`` means exact Lorenz-Mie for a sphere without DDA settings, and otherwise the engine the
DDA settings name (the built-in DDA unless they say ``adda``). A sphere with a ``[dda]`` table
in its config is computed by the DDA (that is how the paper's DDA-vs-Mie validation is run).
"""

from __future__ import annotations

from holofit.dda.settings import DDASettings
from holofit.models import ParticleModel, Sphere
from holofit.scattering.registry import get_theory
from holofit.scattering.theory import ScatteringTheory

__all__ = ["ENGINE_CHOICES", "select_theory"]

ENGINE_CHOICES = ("auto", "mie", "builtin", "adda")


def select_theory(
    model: ParticleModel, settings: DDASettings | None = None, engine: str | None = None
) -> ScatteringTheory:
    """The engine for ``model``.

    Parameters
    ----------
    model : ParticleModel
        The particle.
    settings : DDASettings, optional
        The particle's DDA settings (its config's ``[dda]`` table); None if it has none.
    engine : {"auto", "mie", "builtin", "adda"}, optional
        Overrides the choice; ``auto`` (default) as in the module docstring.

    Raises
    ------
    ValueError
        An unknown engine, or Lorenz-Mie asked for a particle that is not a sphere.
    """
    engine = engine or "auto"
    if engine not in ENGINE_CHOICES:
        raise ValueError(f"engine must be one of {', '.join(ENGINE_CHOICES)}, got {engine!r}")
    if engine == "auto":
        if isinstance(model, Sphere) and settings is None:
            engine = "mie"
        else:
            engine = (settings or DDASettings()).engine
    if engine == "mie":
        if not isinstance(model, Sphere):
            raise ValueError(f"Lorenz-Mie theory handles spheres only, not {model.kind!r}")
        return get_theory("mie")
    return get_theory(engine, settings=settings or DDASettings())
