"""Scattering engines by name (``--engine`` on the command line, ``engine`` in configs)."""

from __future__ import annotations

from collections.abc import Callable

from holofit.scattering.theory import ScatteringTheory

__all__ = ["ENGINES", "get_theory"]


def _mie() -> ScatteringTheory:
    from holofit.scattering.mie import LorenzMie

    return LorenzMie()


#: name -> factory; the DDA engines register themselves in their own modules' import
ENGINES: dict[str, Callable[..., ScatteringTheory]] = {"mie": _mie}


def get_theory(name: str, **options: object) -> ScatteringTheory:
    """The scattering engine called ``name`` (``mie``, ``builtin``, ``adda``)."""
    _load_optional_engines()
    try:
        factory = ENGINES[name]
    except KeyError:
        raise ValueError(
            f"unknown scattering engine {name!r}; available: {', '.join(sorted(ENGINES))}"
        ) from None
    return factory(**options)


def _load_optional_engines() -> None:
    """Import the engine modules so that they register (kept lazy: numba compiles)."""
    import importlib

    for module in ("holofit.dda.engine", "holofit.adda_engine"):
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
