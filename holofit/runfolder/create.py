"""``holofit init``: write a run folder (Makefile, README, copies of the two configs).

Everything is checked before anything is written: the movie, backgrounds and dark frames
exist and are readable movies, make can use their paths, the configs resolve and validate,
the analysis model suits the particle, the extra stage options leave the Makefile's own
options alone and suit the movie and the particle (:mod:`holofit.runfolder.stagecheck`: the
crop size against the frames, follow mode and start point, ``--fix`` names), and the folder
has no Makefile yet (unless ``force``). The Makefile is written
last, so a folder with a Makefile is a complete run folder.
"""

from __future__ import annotations

import datetime as _dt
import os
import shlex
import sys
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import holofit
from holofit.analysis.settings import AnalysisConfig, SettingError
from holofit.config import ParticleConfig, load_instrument, load_particle, resolve_config
from holofit.engines.select import ENGINE_CHOICES
from holofit.io.atomic import atomic_write_text
from holofit.io.movie import MovieError, open_movie
from holofit.provenance import command_line
from holofit.runfolder.errors import RunFolderError
from holofit.runfolder.makefile import (
    BATCH_MAKEFILE_MARK,
    render_batch_makefile,
    render_run_makefile,
)
from holofit.runfolder.readme import render_readme
from holofit.runfolder.spec import (
    STAGES,
    RunFolderConfig,
    analysis_model_for,
    analysis_reads_model,
    check_make_path,
    check_stage_options,
)
from holofit.runfolder.stagecheck import check_crop_options, check_fit_options, initial_pass_note

__all__ = ["RunFolder", "RunInputs", "default_holofit_command", "init_run",
           "write_batch_makefile"]

INSTRUMENT_COPY = "instrument.toml"
PARTICLE_COPY = "particle.toml"


@dataclass
class RunFolder:
    """What :func:`init_run` wrote.

    Attributes
    ----------
    path : Path
        The run folder.
    makefile, readme, instrument, particle : Path
        Its Makefile, README.md and the two config copies.
    spec : RunFolderConfig
        What the Makefile says.
    batch_makefile : Path, optional
        The parent folder's Makefile that runs every run folder (``batch_makefile=True``).
    notes : list of str
        What the user should know (e.g. a parent Makefile left alone).
    """

    path: Path
    makefile: Path
    readme: Path
    instrument: Path
    particle: Path
    spec: RunFolderConfig
    batch_makefile: Path | None = None
    notes: list[str] = field(default_factory=list)


def default_holofit_command() -> str:
    """The shell command of the holofit that is running: the ``holofit`` script beside this
    interpreter, else ``python -m holofit.cli`` with this interpreter."""
    exe = Path(sys.executable)
    script = exe.with_name("holofit")
    if script.is_file() and os.access(script, os.X_OK):
        return shlex.quote(str(script))
    return f"{shlex.quote(str(exe))} -m holofit.cli"


def _input(path: str | Path, what: str) -> str:
    """Absolute path of an existing input movie / background / dark, usable by make."""
    return _read_input(path, what)[0]


def _read_input(path: str | Path, what: str) -> tuple[str, int, tuple[int, int]]:
    """:func:`_input`, with the movie's frame count and frame shape (rows, cols)."""
    p = Path(path).expanduser()
    if not p.exists():
        raise RunFolderError(f"{what} {path}: no such file or folder")
    absolute = os.path.abspath(p)
    check_make_path(absolute, what)
    try:
        with open_movie(absolute) as movie:
            n_frames = len(movie)
            shape = (int(movie.frame_shape[0]), int(movie.frame_shape[1]))
    except MovieError as exc:
        raise RunFolderError(f"{what}: {exc}") from None
    return absolute, n_frames, shape


def _check_light(backgrounds: Sequence[str], darks: Sequence[str], dark_count: float | None,
                 normalized: bool) -> None:
    """The combinations ``holofit crop`` accepts."""
    if darks and dark_count is not None:
        raise RunFolderError("give either dark frames (--dark) or a dark level (--dark-count), "
                             "not both")
    if normalized and (backgrounds or darks or dark_count is not None):
        raise RunFolderError("a normalised movie (--normalized) takes no background and no "
                             "dark level")
    if not normalized and not backgrounds:
        raise RunFolderError("give the background of the raw movie (--background, repeat for "
                             "several files), or --normalized for a movie that is normalised "
                             "already")
    if dark_count is not None and not dark_count >= 0:
        raise RunFolderError(f"dark level must be >= 0 counts, got {dark_count}")


def _config_copy(source: Path) -> str:
    """The text of a config copy: a header naming the source, then the file as it is."""
    return (f"# Copy of {source} made by `holofit init`: the stages of this run folder read\n"
            f"# this file. Edit it here; make reruns the stages it affects.\n"
            + source.read_text(encoding="utf-8"))


def _shape_file(source: Path) -> PurePosixPath | None:
    """The relative shape file of a ``voxels`` particle config, to be copied beside it."""
    doc = tomllib.loads(source.read_text(encoding="utf-8"))
    rel = doc.get("particle", {}).get("path")
    if not isinstance(rel, str) or Path(rel).is_absolute():
        return None
    rel_path = PurePosixPath(rel)
    if ".." in rel_path.parts:
        raise RunFolderError(f"{source}: the shape file {rel} lies outside the config's folder; "
                             "give its absolute path in the config")
    return rel_path


def _check_particle(cfg: ParticleConfig, source: Path) -> None:
    adda = cfg.settings.get("dda", {}).get("adda_path") if isinstance(
        cfg.settings.get("dda"), dict) else None
    if isinstance(adda, str) and adda and not Path(adda).is_absolute() and "/" in adda:
        raise RunFolderError(f"{source}: [dda] adda_path {adda!r} is relative; the stages run "
                             "in the run folder: give an absolute path")


def _command() -> str:
    """The command that is running, quoted as a shell would need it, on one line."""
    words = command_line().split(" ", 1)[:1] + sys.argv[1:]
    return " ".join(shlex.quote(w) for w in words).replace("\n", " ")


def _write_if_changed(path: Path, text: str) -> None:
    """Write ``text`` unless the file holds it already (its time stamp then stays: make does
    not rerun the stages that depend on it)."""
    if path.is_file() and path.read_text(encoding="utf-8") == text:
        return
    atomic_write_text(path, text)


def write_batch_makefile(folder: str | Path) -> tuple[Path, str | None]:
    """Write ``folder/Makefile`` that runs every run folder in ``folder``.

    Returns
    -------
    path : Path
        The Makefile.
    note : str or None
        Why an existing Makefile that holofit did not write was left alone (None: written or
        already holofit's).
    """
    path = Path(folder) / "Makefile"
    if path.exists():
        first = path.read_text(encoding="utf-8", errors="replace").split("\n", 1)[0]
        if not first.startswith(BATCH_MAKEFILE_MARK):
            return path, (f"{path} exists and was not written by holofit: left as it is (see "
                          "holofit's docs, 'Run folders and make', for the lines that run "
                          "every run folder)")
    _write_if_changed(path, render_batch_makefile())
    return path, None


@dataclass(frozen=True)
class RunInputs:
    """The light a run folder's movie was recorded with, as ``holofit crop`` takes it.

    Attributes
    ----------
    movie : str or Path
        The raw movie (TIFF stack or folder of frames); referred to by absolute path.
    backgrounds, darks : sequence of paths
        Background and dark files (as ``holofit crop --background / --dark``).
    dark_count : float, optional
        Dark level in counts, instead of dark frames.
    normalized : bool
        The movie is background-divided already (no background).
    """

    movie: str | Path
    backgrounds: Sequence[str | Path] = ()
    darks: Sequence[str | Path] = ()
    dark_count: float | None = None
    normalized: bool = False


def init_run(
    run_dir: str | Path,
    inputs: RunInputs,
    *,
    instrument: str | Path,
    particle: str | Path | Sequence[str | Path],
    engine: str | None = None,
    temperature_c: float = 21.0,
    model: str | None = None,
    options: Mapping[str, str] | None = None,
    holofit_command: str | None = None,
    force: bool = False,
    batch_makefile: bool = False,
) -> RunFolder:
    """Write a run folder: ``Makefile``, ``README.md``, ``instrument.toml``, ``particle.toml``.

    ``make -C run_dir`` then runs crop -> prefit -> library (anisotropic particles) -> fit
    (initial, final) -> analyze, each only when out of date (see
    :mod:`holofit.runfolder.makefile`).

    Parameters
    ----------
    run_dir : str or Path
        The run folder (created).
    inputs : RunInputs
        The movie, its background and dark files.
    instrument : str or Path
        Config file or name (``paper_60x_water``); copied into the folder.
    particle : str or Path, or a sequence of them
        Particle config file(s) or name(s) (``rod_paper``); copied into the folder (the first
        non-spherical one, or the first, as ``particle.toml``; the others as
        ``particle_<kind>.toml``): a run's population, each track fitted with the model that
        fits it best.
    engine : str, optional
        Scattering engine of library and fit (default: the particle config's).
    temperature_c : float
        Sample temperature for the analysis, C.
    model : {"rod", "janus", "sphere"}, optional
        Diffusion analysis imposed on every track (the Makefile passes ``--model``); default:
        each track's from the particle model the fit gave it, which the analysis reads from
        the fit table, in a run of one model as in a population.
    options : mapping, optional
        Stage (``crop``, ``prefit``, ``library``, ``fit``, ``analyze``) -> extra options.
    holofit_command : str, optional
        Shell command that runs holofit (default: :func:`default_holofit_command`).
    force : bool
        Replace an existing run folder's Makefile, README and configs (outputs are kept; make
        reruns what the new settings invalidate).
    batch_makefile : bool
        Also write the parent folder's Makefile that runs every run folder in it
        (:func:`write_batch_makefile`), unless the parent has a Makefile of its own.

    Returns
    -------
    RunFolder

    Raises
    ------
    RunFolderError, ConfigError
        Naming the input, option or file at fault; nothing is written then.
    """
    run = _check_run_dir(Path(run_dir), force, batch_makefile)
    movie_abs, n_frames, frame_shape, bg_abs, dark_abs = _light_inputs(inputs)
    dark_count, normalized = inputs.dark_count, inputs.normalized
    sources = [particle] if isinstance(particle, str | Path) else list(particle)
    if not sources:
        raise RunFolderError("no particle model: give one (-p)")
    # the primary model: the first non-spherical one (the library ranks its orientations)
    primary = next((p for p in sources
                    if load_particle(resolve_config(p, "particles")).model.anisotropic),
                   sources[0])
    inst_source, part_source, cfg, shape = _configs(instrument, primary)
    alternatives = _population(sources, part_source, cfg)
    analysis = _check_engine_and_analysis(cfg, engine, model, temperature_c)
    # --model only where given, or where a run of one model could not do without it
    forced = bool(model) or (not alternatives and not analysis_reads_model(
        cfg.model.kind, cfg.as_dict(), analysis))
    opts, notes = _check_options(options, cfg, frame_shape, n_frames)
    spec = RunFolderConfig(
        movie=movie_abs, backgrounds=bg_abs, darks=dark_abs, dark_count=dark_count,
        normalized=normalized, particle_kind=cfg.model.kind, anisotropic=cfg.model.anisotropic,
        analysis_model=analysis, temperature_c=float(temperature_c), engine=engine,
        options=opts, holofit=holofit_command or default_holofit_command(),
        instrument_source=str(inst_source.resolve()), particle_source=str(part_source.resolve()),
        alternatives=tuple(sorted(alternatives)),
        header=_header(), analysis_forced=forced,
    )
    folder = _write_folder(run, spec, inst_source, part_source, shape, notes, batch_makefile)
    for name, source in alternatives.items():
        _write_if_changed(run / name, _config_copy(source))
        load_particle(run / name)
    return folder


def _header() -> tuple[str, str]:
    """The Makefile's first lines: who wrote it, when, and the command."""
    now = _dt.datetime.now().astimezone().replace(microsecond=0).isoformat()
    return (f"holofit run folder: written by `holofit init` (holofit {holofit.__version__}), "
            f"{now}", _command())


def _light_inputs(inputs: RunInputs
                  ) -> tuple[str, int, tuple[int, int], tuple[str, ...], tuple[str, ...]]:
    """The movie (absolute path, frames, frame shape) and its background and dark files,
    checked."""
    bgs = [str(b) for b in inputs.backgrounds]
    dks = [str(d) for d in inputs.darks]
    _check_light(bgs, dks, inputs.dark_count, inputs.normalized)
    movie_abs, n_frames, frame_shape = _read_input(inputs.movie, "movie")
    return (movie_abs, n_frames, frame_shape, tuple(_input(b, "background") for b in bgs),
            tuple(_input(d, "dark frame") for d in dks))


def _configs(instrument: str | Path, particle: str | Path
             ) -> tuple[Path, Path, ParticleConfig, PurePosixPath | None]:
    """The two config files (by name or path), loaded and checked; a voxel model's shape file."""
    inst_source = resolve_config(instrument, "instruments")
    load_instrument(inst_source)
    part_source = resolve_config(particle, "particles")
    cfg = load_particle(part_source)
    _check_particle(cfg, part_source)
    return (inst_source, part_source, cfg,
            _shape_file(part_source) if cfg.model.kind == "voxels" else None)


def _population(sources: Sequence[str | Path], primary: Path, cfg: ParticleConfig
                ) -> dict[str, Path]:
    """The population's other models beside ``primary``: copy name -> source. Every model is
    checked; a population holds at most one non-spherical model (the library ranks its
    orientations)."""
    out: dict[str, Path] = {}
    kinds = {cfg.model.kind}
    for source in sources:
        path = resolve_config(source, "particles")
        if path.resolve() == primary.resolve():
            continue
        other = load_particle(path)
        _check_particle(other, path)
        if other.model.anisotropic and cfg.model.anisotropic:
            raise RunFolderError(f"{path}: a second non-spherical model; a run's population "
                                 "holds one (the library ranks its orientations): make a run "
                                 "folder of its own for it")
        if other.model.kind in kinds:
            raise RunFolderError(f"{path}: a second {other.model.kind}; a population holds one "
                                 "model of each kind")
        kinds.add(other.model.kind)
        out[f"particle_{other.model.kind}.toml"] = path
    return out


def _check_run_dir(run: Path, force: bool, batch_makefile: bool) -> Path:
    """Refuse to overwrite a run folder without ``force``, or a file where the folder goes."""
    if (run / "Makefile").exists() and not force:
        raise RunFolderError(f"{run / 'Makefile'} exists: {run} is a run folder already (force "
                             "to write it again: its outputs are kept, and make reruns what the "
                             "new settings change)")
    if run.exists() and not run.is_dir():
        raise RunFolderError(f"{run}: exists and is not a folder")
    if batch_makefile:
        check_make_path(run.resolve().name, "run folder name")
    return run


def _check_engine_and_analysis(cfg: ParticleConfig, engine: str | None, model: str | None,
                               temperature_c: float) -> str:
    """Check the engine against the particle and the analysis settings; the analysis model."""
    if engine is not None:
        if engine not in ENGINE_CHOICES:
            raise RunFolderError(f"engine {engine!r}: expected one of "
                                 f"{', '.join(ENGINE_CHOICES)}")
        cfg.theory(engine)  # an engine that cannot handle the particle: ConfigError now
    analysis = analysis_model_for(cfg.model.kind, model, cfg.as_dict())
    try:
        AnalysisConfig(model=analysis, temperature_c=temperature_c)
    except SettingError as exc:
        raise RunFolderError(f"analysis {exc.setting}: {exc.problem}") from None
    return analysis


def _check_options(options: Mapping[str, str] | None, cfg: ParticleConfig,
                   frame_shape: tuple[int, int], n_frames: int
                   ) -> tuple[dict[str, str], list[str]]:
    """Check each stage's extra options now, as its command line would; the options and notes."""
    opts = dict(options or {})
    unknown = sorted(set(opts) - set(STAGES))
    if unknown:
        raise RunFolderError(f"options for unknown stage(s) {', '.join(unknown)}; stages: "
                             f"{', '.join(STAGES)}")
    if cfg.model.anisotropic and "--seed-only" not in opts.get("prefit", "").split():
        # the prefit only seeds a non-spherical particle's position (holofit.prefit.sphere)
        opts["prefit"] = f"--seed-only {opts.get('prefit', '')}".strip()
    opts = {stage: check_stage_options(stage, text) for stage, text in opts.items() if text}
    check_crop_options(opts.get("crop", ""), frame_shape)
    check_fit_options(opts.get("fit", ""), cfg.model)
    note = initial_pass_note(opts.get("fit", ""), n_frames)
    return opts, [note] if note else []


def _write_folder(run: Path, spec: RunFolderConfig, inst_source: Path, part_source: Path,
                  shape: PurePosixPath | None, notes: list[str], batch_makefile: bool) -> RunFolder:
    """Write the configs' copies, the README and the Makefile (last: it marks the folder)."""
    run.mkdir(parents=True, exist_ok=True)
    out = RunFolder(run, run / "Makefile", run / "README.md", run / INSTRUMENT_COPY,
                    run / PARTICLE_COPY, spec, notes=notes)
    _write_if_changed(out.instrument, _config_copy(inst_source))
    if shape is not None:
        target = run / shape
        target.parent.mkdir(parents=True, exist_ok=True)
        data = (part_source.parent / shape).read_bytes()
        if not target.is_file() or target.read_bytes() != data:
            target.write_bytes(data)
    _write_if_changed(out.particle, _config_copy(part_source))
    load_particle(out.particle)  # the copy reads as the original does
    _write_if_changed(out.readme, render_readme(spec))
    atomic_write_text(out.makefile, render_run_makefile(spec))
    if batch_makefile:
        out.batch_makefile, note = write_batch_makefile(run.resolve().parent)
        if note:
            out.notes.append(note)
    return out
