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


def particle_option(required: bool = True) -> Callable[[F], F]:
    return click.option(
        "--particle",
        "-p",
        required=required,
        help="Particle-model TOML file, or the name of a shipped one (e.g. rod_paper; "
        "configs/particles).",
    )


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

