"""Scattering engines by name (``--engine`` on the command line, ``engine`` in configs).

The table below is the whole registry: adding an engine means adding a line here. Engines are
imported when first asked for, so that choosing Lorenz-Mie never compiles the DDA kernels.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from holofit.scattering.theory import ScatteringTheory

__all__ = ["ENGINES", "get_theory"]


def _mie(**options: Any) -> ScatteringTheory:
    from holofit.scattering.mie import LorenzMie

    return LorenzMie(**options)


def _builtin(**options: Any) -> ScatteringTheory:
    from holofit.dda.engine import BuiltinDDA

    return BuiltinDDA(**options)


def _adda(**options: Any) -> ScatteringTheory:
    from holofit.dda.adda.engine import AddaEngine

    return AddaEngine(**options)


def _cluster(**options: Any) -> ScatteringTheory:
    from holofit.scattering.cluster import ClusterTheory

    return ClusterTheory(**options)


def _coated_sphere(**options: Any) -> ScatteringTheory:
    from holofit.scattering.coated_mie import CoatedMie

    return CoatedMie(**options)


#: engine name -> factory taking the engine's keyword options
ENGINES: dict[str, Callable[..., ScatteringTheory]] = {
    "mie": _mie,
    "builtin": _builtin,
    "adda": _adda,
    "cluster": _cluster,
    "coated_sphere": _coated_sphere,
}


def get_theory(name: str, **options: Any) -> ScatteringTheory:
    """The scattering engine called ``name`` (``mie``, ``builtin``, ``adda``, ``cluster``,
    ``coated_sphere``).

    Parameters
    ----------
    name : str
        Engine name.
    **options
        Passed to the engine (e.g. ``settings=DDASettings(...)``, ``dipole_size_um=...``).

    Raises
    ------
    ValueError
        For an unknown name (the message lists the known ones).
    """
    try:
        factory = ENGINES[name]
    except KeyError:
        raise ValueError(
            f"unknown scattering engine {name!r}; available: {', '.join(sorted(ENGINES))}"
        ) from None
    return factory(**options)
