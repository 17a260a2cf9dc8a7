"""``holofit crop``."""

from __future__ import annotations

import click

from holofit.cli.common import not_yet


@click.command(context_settings={"ignore_unknown_options": True})
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
def crop(args: tuple[str, ...]) -> None:
    """Normalise a raw movie by its background, find hologram centres, crop N x N around them.

    Not implemented yet: this stage arrives with its own issue.
    """
    not_yet("crop", "pending issue")
