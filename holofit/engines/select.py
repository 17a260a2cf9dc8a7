"""Choosing the scattering engine for a particle: the one rule, used by every stage.

``auto`` means the exact solution where one exists (the first exact engine of
:data:`holofit.engines.registry.EXACT_ENGINES` whose class can handle the model), and otherwise
the engine the DDA settings name (the built-in DDA unless they say ``adda``):

* a sphere without DDA settings: Lorenz-Mie (``mie``); a sphere with a ``[dda]`` table in its
  config is computed by the DDA (that is how the paper's DDA-vs-Mie validation is run);
* a dimer or a sphere cluster: the superposition T-matrix (``cluster``,
  :mod:`holofit.scattering.cluster`), unless the DDA settings say ``adda``;
* a coated sphere: coated-sphere Lorenz-Mie (``coated_sphere``), unless they say ``adda``;
* a body of revolution - spherocylinder (the paper's rod), spheroid, flat-ended cylinder,
  Janus sphere: its exact T-matrix (``exact``, :mod:`holofit.scattering.axisym`), unless
  they say ``adda``; a ``[dda]`` table without ``engine`` is the DDA's settings for when the
  DDA is asked for, not a choice of it;
* anything else (an ellipsoid, a voxel file): the built-in DDA (or ``adda``).

``--engine builtin`` (or ``adda``) computes any of them by the DDA, for comparison; so does a
particle config whose ``[dda]`` table names ``engine`` (:meth:`holofit.config.ParticleConfig.
theory`). ``docs/engines/index.md`` ("What auto picks") lists the choice by particle, and why.
"""

from __future__ import annotations

from holofit.dda.settings import DDASettings
from holofit.engines.registry import ENGINE_NAMES, EXACT_ENGINES, engine_class, get_engine
from holofit.particles import ParticleModel
from holofit.scattering.theory import ScatteringEngine

__all__ = ["ENGINE_CHOICES", "exact_engine", "select_engine"]

#: what ``--engine`` and a config's ``engine`` accept
ENGINE_CHOICES: tuple[str, ...] = ("auto", *ENGINE_NAMES)


def exact_engine(model: ParticleModel) -> str | None:
    """The exact engine ``auto`` picks for ``model`` without DDA settings, or None."""
    for name in EXACT_ENGINES:
        if engine_class(name).can_handle(model):
            return name
    return None


def select_engine(
    model: ParticleModel, settings: DDASettings | None = None, engine: str | None = None
) -> ScatteringEngine:
    """The engine for ``model``.

    Parameters
    ----------
    model : ParticleModel
        The particle.
    settings : DDASettings, optional
        The particle's DDA settings (its config's ``[dda]`` table); None if it has none.
    engine : {"auto", "mie", "builtin", "adda", "cluster", "coated_sphere", "exact"}, optional
        Overrides the choice; ``auto`` (default) as in the module docstring.

    Raises
    ------
    ValueError
        An unknown engine, or an engine asked for a particle it does not handle.
    """
    engine = engine or "auto"
    if engine not in ENGINE_CHOICES:
        raise ValueError(f"engine must be one of {', '.join(ENGINE_CHOICES)}, got {engine!r}")
    if engine == "auto":
        exact = exact_engine(model)
        dda_engine = (settings or DDASettings()).engine
        if exact is None or (exact == "mie" and settings is not None) or dda_engine == "adda":
            engine = dda_engine
        else:
            engine = exact
    cls = engine_class(engine)
    if not cls.can_handle(model):
        raise ValueError(f"the {engine} engine handles {cls.handles} only, not {model.kind!r}")
    if engine in EXACT_ENGINES:
        return get_engine(engine)
    return get_engine(engine, settings=settings or DDASettings())


#: the former name, kept for existing code (deprecated)
select_theory = select_engine
