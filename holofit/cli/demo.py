"""``holofit demo``: the main job on an embedded default input."""

from __future__ import annotations

from pathlib import Path

import click

from holofit.demo.rod import DEMO_PARTICLES, run_demo


@click.command()
@click.option(
    "--out",
    "-o",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("demo-out"),
    show_default=True,
    help="Output folder.",
)
@click.option("--particle", type=click.Choice(DEMO_PARTICLES), default="rod", show_default=True,
              help="rod: the paper's rod through all five stages; sphere: a sphere through "
                   "crop, prefit and analyze.")
@click.option("--n-frames", "--frames", "frames", type=click.IntRange(min=20), default=None,
              help="Frames of the movie [default: rod 500, sphere 300] (--frames: the old "
                   "name, deprecated; elsewhere --frames is a START:STOP range).")
@click.option("--workers", "-j", type=click.IntRange(min=0), default=2, show_default=True,
              help="Worker processes per stage (0: in this process).")
def demo(out: Path, particle: str, frames: int | None, workers: int) -> None:
    """Run the pipeline on a built-in synthetic movie and print what it measured."""
    run_demo(out, particle=particle, echo=click.echo, workers=workers, n_frames=frames)
