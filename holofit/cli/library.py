"""``holofit library``."""

from __future__ import annotations

import click

from holofit.cli.common import not_yet


@click.command(context_settings={"ignore_unknown_options": True})
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
def library(args: tuple[str, ...]) -> None:
    """DDA holograms over a grid of orientations; best starting orientation per frame.

    Not implemented yet: this stage arrives with its own issue.
    """
    not_yet("library", "pending issue")
