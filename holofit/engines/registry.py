"""Scattering engines by name (``--engine`` on the command line, ``engine`` in configs).

This is the one list of engine names: the exact engines are listed here; the discrete-dipole
engines are those a particle's ``[dda]`` table may name (:data:`holofit.dda.settings.DDA_ENGINES`,
where their settings are validated); :data:`holofit.engines.select.ENGINE_CHOICES` is ``auto``
plus :data:`ENGINE_NAMES`. Each engine's class says what it handles
(:meth:`~holofit.scattering.theory.ScatteringEngine.can_handle`). Engines are imported when
first asked for, so that choosing Lorenz-Mie never compiles the DDA kernels.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from holofit.dda.settings import DDA_ENGINES
from holofit.scattering.theory import ScatteringEngine

__all__ = ["ENGINES", "ENGINE_NAMES", "EXACT_ENGINES", "engine_class", "get_engine"]


def _mie() -> type[ScatteringEngine]:
    from holofit.scattering.mie import LorenzMie

    return LorenzMie


def _cluster() -> type[ScatteringEngine]:
    from holofit.scattering.cluster import ClusterEngine

    return ClusterEngine


def _coated_sphere() -> type[ScatteringEngine]:
    from holofit.scattering.coated_mie import CoatedMie

    return CoatedMie


def _exact() -> type[ScatteringEngine]:
    from holofit.scattering.axisym.engine import AxisymmetricTMatrix

    return AxisymmetricTMatrix


def _dda(name: str) -> Callable[[], type[ScatteringEngine]]:
    def load() -> type[ScatteringEngine]:
        from holofit.dda.adda.engine import AddaEngine
        from holofit.dda.engine import BuiltinDDA

        return {cls.name: cls for cls in (BuiltinDDA, AddaEngine)}[name]

    return load


#: the exact engines, in ``auto``'s order of preference (the first that can handle a model):
#: a sphere's and a coated sphere's series before the T-matrix of a body of revolution, which
#: also handles them (through the same series, or the imbedding)
_EXACT: dict[str, Callable[[], type[ScatteringEngine]]] = {
    "mie": _mie,
    "cluster": _cluster,
    "coated_sphere": _coated_sphere,
    "exact": _exact,
}
#: engine name -> loader of its class (Lorenz-Mie, the discrete-dipole engines, the other
#: exact ones: the order ``--engine`` lists them in)
_CLASSES: dict[str, Callable[[], type[ScatteringEngine]]] = {
    "mie": _mie, **{name: _dda(name) for name in DDA_ENGINES},
    **{name: load for name, load in _EXACT.items() if name != "mie"}}
EXACT_ENGINES: tuple[str, ...] = tuple(_EXACT)
ENGINE_NAMES: tuple[str, ...] = tuple(_CLASSES)


def engine_class(name: str) -> type[ScatteringEngine]:
    """The class of the engine called ``name`` (imported on first use).

    Raises
    ------
    ValueError
        For an unknown name (the message lists the known ones).
    """
    try:
        load = _CLASSES[name]
    except KeyError:
        raise ValueError(
            f"unknown scattering engine {name!r}; available: {', '.join(sorted(_CLASSES))}"
        ) from None
    return load()


def _factory(name: str) -> Callable[..., ScatteringEngine]:
    return lambda **options: engine_class(name)(**options)


#: engine name -> factory taking the engine's keyword options
ENGINES: dict[str, Callable[..., ScatteringEngine]] = {name: _factory(name)
                                                       for name in ENGINE_NAMES}


def get_engine(name: str, **options: Any) -> ScatteringEngine:
    """The scattering engine called ``name`` (one of :data:`ENGINE_NAMES`: ``mie``,
    ``builtin``, ``adda``, ``cluster``, ``coated_sphere``, ``exact``).

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
    return engine_class(name)(**options)


#: the former name, kept for existing code (deprecated)
get_theory = get_engine
