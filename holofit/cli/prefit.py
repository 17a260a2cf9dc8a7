"""``holofit prefit``."""

from __future__ import annotations

import click

from holofit.cli.common import not_yet


@click.command(context_settings={"ignore_unknown_options": True})
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
def prefit(args: tuple[str, ...]) -> None:
    """Lorenz-Mie fit of every crop (x, y, z, n, a, alpha) with automatic initial guesses.

    Not implemented yet: this stage arrives with its own issue.
    """
    not_yet("prefit", "pending issue")
