"""``holofit fit``."""

from __future__ import annotations

import click

from holofit.cli.common import not_yet


@click.command(context_settings={"ignore_unknown_options": True})
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
def fit(args: tuple[str, ...]) -> None:
    """DDA fit of every frame: initial pass (all parameters) then final pass (static ones fixed).

    Not implemented yet: this stage arrives with its own issue.
    """
    not_yet("fit", "pending issue")
