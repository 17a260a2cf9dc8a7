"""``holofit demo``: the main job on an embedded default input."""

from __future__ import annotations

from pathlib import Path

import click

from holofit.demo import run_demo


@click.command()
@click.option(
    "--out",
    "-o",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("demo-out"),
    show_default=True,
    help="Output folder.",
)
def demo(out: Path) -> None:
    """Run the pipeline on a built-in synthetic movie and print what it measured."""
    run_demo(out, echo=click.echo)
