"""Options and helpers shared by the subcommands."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click

from holofit.config import (
    Instrument,
    ParticleConfig,
    load_instrument,
    load_particle,
    resolve_config,
)

F = TypeVar("F", bound=Callable[..., Any])


def instrument_option(required: bool = True) -> Callable[[F], F]:
    return click.option(
        "--instrument",
        "-i",
        required=required,
        help="Instrument TOML file, or the name of a shipped one (e.g. paper_100x_oil; "
        "configs/instruments).",
    )


def particle_option(required: bool = True, multiple: bool = False) -> Callable[[F], F]:
    """``-p/--particle-model``: a particle-model file or the name of a shipped one; with
    ``multiple``, a run's population (the first non-spherical one the primary model)."""
    more = (" Give it again for the other models of the population (spheres, coated spheres):"
            " each track is given the one that fits it best." if multiple else "")
    return click.option(
        "--particle-model",
        "-p",
        "particle",
        required=required,
        multiple=multiple,
        help="Particle-model TOML file, or the name of a shipped one (e.g. rod_paper; "
        "configs/particles)." + more,
    )


def track_options(f: F) -> F:
    """``--particle N`` and ``--exclude-particle N`` (each repeatable): the tracks a stage
    runs on (a track is a crop table's ``particle``)."""
    def ids(ctx: click.Context, param: click.Parameter, values: tuple[str, ...]
            ) -> tuple[int, ...]:
        out = []
        for v in values:
            try:
                out.append(int(v))
            except ValueError:
                raise click.BadParameter(
                    f"{v!r}: a track id (an integer); the particle model is -p/"
                    "--particle-model", param=param) from None
        return tuple(out)

    f = click.option("--exclude-particle", "exclude_particles", multiple=True,
                     callback=ids, metavar="N",
                     help="Leave out track N (repeatable).")(f)
    return click.option("--particle", "particles", multiple=True, callback=ids, metavar="N",
                        help="Only track N (repeatable) [default: every track].")(f)


def load_instrument_arg(value: str) -> Instrument:
    """The instrument of ``--instrument``.

    A bad config (missing, misspelt, a key typo, a value out of range) is a
    :class:`ConfigError`, reported like every input failure (``holofit STAGE: error: ...``,
    exit status 1; :mod:`holofit.cli.errors`): the message names the file and the key.
    """
    return load_instrument(resolve_config(value, "instruments"))


def load_particle_arg(value: str) -> ParticleConfig:
    """The particle model of ``--particle`` (errors as for :func:`load_instrument_arg`)."""
    return load_particle(resolve_config(value, "particles"))


def parse_triple(value: str, name: str) -> tuple[float, float, float]:
    try:
        parts = [float(v) for v in value.split(",")]
    except ValueError:
        raise click.BadParameter(
            f"expected three comma-separated numbers, got {value!r}", param_hint=name
        ) from None
    if len(parts) != 3:
        raise click.BadParameter(
            f"expected three comma-separated numbers, got {value!r}", param_hint=name
        )
    return parts[0], parts[1], parts[2]


def parse_pair(value: str, name: str) -> tuple[int, int]:
    try:
        parts = [int(v) for v in value.replace("x", ",").split(",")]
    except ValueError:
        raise click.BadParameter(f"expected ROWS,COLS, got {value!r}", param_hint=name) from None
    if len(parts) != 2 or min(parts) <= 0:
        raise click.BadParameter(
            f"expected two positive integers ROWS,COLS, got {value!r}", param_hint=name
        )
    return parts[0], parts[1]


def out_dir_option(default: str | None = None) -> Callable[[F], F]:
    return click.option(
        "--out",
        "-o",
        type=click.Path(file_okay=False, path_type=Path),
        default=default,
        required=default is None,
        show_default=default is not None,
        help="Output folder (created if needed).",
    )

