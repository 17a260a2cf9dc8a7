"""The ``holofit`` command line: a thin layer over the library, one subcommand per stage."""

from __future__ import annotations

import click

from holofit import __version__
from holofit.cli.analyze import analyze
from holofit.cli.crop import crop
from holofit.cli.demo import demo
from holofit.cli.errors import DEBUG_ENV, HolofitGroup
from holofit.cli.fit import fit
from holofit.cli.init import init
from holofit.cli.library import library
from holofit.cli.prefit import prefit
from holofit.cli.simulate import simulate

__all__ = ["main"]


@click.group(cls=HolofitGroup, context_settings={"help_option_names": ["-h", "--help"]})
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
    rerun and chained from a Makefile. `simulate` makes synthetic data with known truth.

    A failure caused by the input (a file, an option, ADDA) is one line,
    `holofit STAGE: error: MESSAGE`, with exit status 1.
    """


for command in (init, crop, prefit, library, fit, analyze, simulate, demo):
    main.add_command(command)
