"""``holofit init``: a thin layer over :func:`holofit.runfolder.init_run`."""

from __future__ import annotations

import shlex
from pathlib import Path

import click

from holofit.analysis.recipes import MODELS
from holofit.cli.analyze import analyze
from holofit.cli.common import instrument_option, particle_option
from holofit.cli.crop import crop
from holofit.cli.fit import fit
from holofit.cli.library import library
from holofit.cli.prefit import prefit
from holofit.engines.select import ENGINE_CHOICES
from holofit.runfolder import RunInputs, init_run

#: stage -> its command (to check extra options against the command's own parser)
_COMMANDS = {"crop": crop, "prefit": prefit, "library": library, "fit": fit, "analyze": analyze}


def _check_parses(stage: str, text: str) -> None:
    """Extra options of ``stage`` that its command would refuse: a usage error now, not when
    make reaches the stage."""
    hint = f"--{stage}-opts"
    command = _COMMANDS[stage]
    try:
        words = shlex.split(text)
        values, rest, _ = command.make_parser(click.Context(command, info_name=stage)).parse_args(
            words)
    except ValueError as exc:
        raise click.BadParameter(f"{text!r}: {exc}", param_hint=hint) from None
    except click.UsageError as exc:
        raise click.BadParameter(f"{text!r}: {exc.format_message()} (holofit {stage} --help)",
                                 param_hint=hint) from None
    positional = [values.get(p.name) for p in command.params if isinstance(p, click.Argument)]
    if rest or any(isinstance(v, str) or (isinstance(v, tuple) and v) for v in positional):
        raise click.BadParameter(f"{text!r}: options only (the run folder gives the inputs)",
                                 param_hint=hint)
    # every value as the command converts it (choices, numbers, ranges); paths are left to
    # the stage: they are relative to the run folder, not to here
    ctx = click.Context(command, info_name=stage)
    for param in command.params:
        if (isinstance(param, click.Option) and values.get(param.name) is not None
                and not isinstance(param.type, click.Path)):
            try:
                param.process_value(ctx, values[param.name])
            except click.UsageError as exc:
                raise click.BadParameter(f"{text!r}: {exc.format_message()} (holofit {stage} "
                                         "--help)", param_hint=hint) from None


def _stage_option(stage: str):  # type: ignore[no-untyped-def]
    return click.option(f"--{stage}-opts", f"{stage}_opts", default="", metavar="'OPTIONS'",
                        help=f"Extra options of `holofit {stage}` (the Makefile's "
                             f"{stage.upper()}_OPTS).")


@click.command()
@click.argument("run_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--movie", required=True, type=click.Path(path_type=Path),
              help="The raw movie (TIFF stack or folder of TIFF frames); referred to by "
                   "absolute path, not copied.")
@click.option("--background", "-b", "backgrounds", multiple=True, type=click.Path(path_type=Path),
              help="Background frame, stack or folder; repeat for several files.")
@click.option("--dark", "darks", multiple=True, type=click.Path(path_type=Path),
              help="Dark frame or stack; repeat for several files.")
@click.option("--dark-count", type=click.FloatRange(min=0), default=None,
              help="Dark level in counts (instead of --dark).")
@click.option("--normalized", is_flag=True,
              help="The movie is background-divided already (no --background).")
@instrument_option()
@particle_option(multiple=True)
@click.option("--engine", type=click.Choice(ENGINE_CHOICES), default=None,
              help="Scattering engine of library and fit [default: the particle config's].")
@click.option("--temperature-c", type=float, default=21.0, show_default=True,
              help="Sample temperature for the analysis, C.")
@click.option("--model", "-m", type=click.Choice(MODELS), default=None,
              help="Diffusion analysis imposed on every track [default: each track's from "
                   "the particle the fit gave it, read from the fit table: sphere, janus, rod "
                   "for rods, cylinders, spheroids and dimers].")
@_stage_option("crop")
@_stage_option("prefit")
@_stage_option("library")
@_stage_option("fit")
@_stage_option("analyze")
@click.option("--holofit", "holofit_command", default=None, metavar="COMMAND",
              help="Shell command that runs holofit in the Makefile [default: this holofit]; "
                   "make HOLOFIT=... overrides it.")
@click.option("--force", is_flag=True,
              help="Write RUN's Makefile, README and configs again (outputs are kept; make "
                   "reruns what changed).")
@click.option("--batch-makefile", is_flag=True,
              help="Also write a Makefile in RUN's parent folder that runs every run folder "
                   "in it (make -C PARENT -j4 JOBS=2).")
def init(
    run_dir: Path,
    movie: Path,
    backgrounds: tuple[Path, ...],
    darks: tuple[Path, ...],
    dark_count: float | None,
    normalized: bool,
    instrument: str,
    particle: tuple[str, ...],
    engine: str | None,
    temperature_c: float,
    model: str | None,
    crop_opts: str,
    prefit_opts: str,
    library_opts: str,
    fit_opts: str,
    analyze_opts: str,
    holofit_command: str | None,
    force: bool,
    batch_makefile: bool,
) -> None:
    """Make RUN_DIR a run folder: a Makefile whose targets are the stages, and copies of the
    two configs.

    `make -C RUN_DIR` then runs crop -> prefit -> library -> fit (initial, final) -> analyze,
    each only when out of date: a second make does nothing, editing RUN_DIR/particle.toml
    reruns library, fit and analyze, and an interrupted make resumes the stage it stopped in.
    `make -C RUN_DIR JOBS=8` sets the workers per stage, SCHEDULER=... a Dask cluster. See
    RUN_DIR/README.md.
    """
    options = {"crop": crop_opts, "prefit": prefit_opts, "library": library_opts,
               "fit": fit_opts, "analyze": analyze_opts}
    for stage, text in options.items():
        if text.strip():
            _check_parses(stage, text)
    made = init_run(
        run_dir,
        RunInputs(
            movie,
            backgrounds=backgrounds,
            darks=darks,
            dark_count=dark_count,
            normalized=normalized,
        ),
        instrument=instrument,
        particle=particle,
        engine=engine,
        temperature_c=temperature_c,
        model=model,
        options=options,
        holofit_command=holofit_command,
        force=force,
        batch_makefile=batch_makefile,
    )
    spec = made.spec
    chain = " -> ".join(
        [
            "crop",
            "prefit",
            *(["library"] if spec.anisotropic else []),
            "fit",
            f"analyze ({spec.analysis_model})",
        ]
    )
    click.echo(
        f"wrote {made.makefile} ({chain}), {made.readme}, {made.instrument}, {made.particle}"
    )
    if made.batch_makefile is not None and not made.notes:
        click.echo(
            f"wrote {made.batch_makefile}: make -C {made.batch_makefile.parent} runs "
            "every run folder in it"
        )
    for note in made.notes:
        click.echo(f"holofit init: note: {note}", err=True)
    click.echo(f"run it: make -C {shlex.quote(str(run_dir))}")
