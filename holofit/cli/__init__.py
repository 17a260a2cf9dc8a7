"""The ``holofit`` command line: a thin layer over the library, one subcommand per stage.

Subcommands are imported when they are run (``holofit crop`` never loads the DDA engine or the
analysis), so every command starts in well under a second on top of Python's own start.
"""

from __future__ import annotations

import importlib

import click

from holofit import __version__
from holofit.cli.errors import DEBUG_ENV, HolofitGroup

__all__ = ["main"]

#: subcommand -> "module:attribute", in the order ``holofit --help`` lists them
COMMANDS: dict[str, str] = {
    "init": "holofit.cli.init:init",
    "crop": "holofit.cli.crop:crop",
    "prefit": "holofit.cli.prefit:prefit",
    "calibrate": "holofit.cli.calibrate:calibrate",
    "library": "holofit.cli.library:library",
    "fit": "holofit.cli.fit:fit",
    "analyze": "holofit.cli.analyze:analyze",
    "simulate": "holofit.cli.simulate:simulate",
    "demo": "holofit.cli.demo:demo",
}


class _Holofit(HolofitGroup):
    """The top-level group: subcommands from :data:`COMMANDS`, imported on first use."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        target = COMMANDS.get(cmd_name)
        if target is None:
            return None
        module, attribute = target.split(":")
        return getattr(importlib.import_module(module), attribute)


@click.group(cls=_Holofit, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="holofit")
@click.option(
    "--debug",
    is_flag=True,
    envvar=DEBUG_ENV,
    help=f"Show the Python traceback of a failure (also {DEBUG_ENV}=1).",
)
def main(debug: bool) -> None:
    """Holographic tracking of non-spherical colloids.

    Stages, in order: crop -> prefit -> library -> fit -> analyze. Each reads files and writes
    files (with a sidecar JSON of units, config, versions and the command), so stages can be
    rerun and chained from a Makefile (`holofit init`). `simulate` makes synthetic data with
    known truth. `calibrate` (between prefit and library, when the instrument's NA and
    spherical aberration are not known well enough) fits them on spheres at several heights
    and writes an instrument file for `holofit init -i` and every stage.

    A failure caused by the input (a file, an option, ADDA) is one line,
    `holofit STAGE: error: MESSAGE`, with exit status 1.
    """
