"""``holofit analyze``."""

from __future__ import annotations

import click

from holofit.cli.common import not_yet


@click.command(context_settings={"ignore_unknown_options": True})
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
def analyze(args: tuple[str, ...]) -> None:
    """Diffusion analysis of a fit table: MSDs, orientation correlations, theory.

    Not implemented yet: this stage arrives with its own issue.
    """
    not_yet("analyze", "pending issue")
