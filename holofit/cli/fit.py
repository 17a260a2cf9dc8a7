"""``holofit fit``: DDA fit of every frame, initial and final pass."""

from __future__ import annotations

from pathlib import Path

import click
import pandas as pd

from holofit.cli.common import (
    instrument_option,
    load_instrument_arg,
    load_particle_arg,
    out_dir_option,
    particle_option,
    track_options,
)
from holofit.cli.stage_options import (
    aperture_choice,
    aperture_options,
    batch_options,
    frame_list,
    make_batch_options,
    parse_int_list,
    quality_options,
)
from holofit.config import ParticleConfig
from holofit.engines.select import ENGINE_CHOICES
from holofit.fit.config import PASSES, FitConfig, FitRun
from holofit.fit.continuity import ContinuitySettings
from holofit.fit.model_error import MODEL_ERROR_FRAMES, ModelErrorSettings
from holofit.fit.settings import FollowSettings, FrameFitSettings
from holofit.fit.stage import run_fit
from holofit.fit.static import STATIC_MODES
from holofit.fit.task import check_fixed, fixable_names
from holofit.fit.tmatrix_policy import TMATRIX_CHOICES
from holofit.quality import QualityLimits


@click.command()
@click.argument("crop_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--prefit", "prefit_dir", required=True,
              type=click.Path(exists=True, path_type=Path),
              help="Output of `holofit prefit` for these crops (start positions, alpha).")
@click.option("--library", "library_dir", default=None,
              type=click.Path(exists=True, path_type=Path),
              help="Output of `holofit library` for these crops and particle (start "
                   "orientations; not needed for spheres).")
@particle_option(multiple=True)
@track_options
@out_dir_option()
@instrument_option(required=False)
@click.option("--pass", "pass_name", type=click.Choice(PASSES), default="both",
              show_default=True,
              help="initial: everything free on some frames, writes static.json; final: "
                   "static parameters fixed, every frame; both: one then the other.")
@click.option("--initial-frames", type=click.IntRange(min=1), default=None,
              help="Frames of the initial pass (1 for a single hologram: everything free) "
                   "[default: 1 in 20 of the frames that can be fitted, at least 8, at most "
                   "500; the choice is printed].")
@click.option("--static-mode", type=click.Choice(STATIC_MODES), default="per-track",
              show_default=True,
              help="Crops of several tracks: static parameters per track, or pooled over "
                   "the tracks (one batch of identical particles).")
@click.option("--static", "static_file", default=None,
              type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="static.json with the static parameters of the final pass [default: "
                   "OUT/static.json from the initial pass].")
@click.option("--engine", type=click.Choice(ENGINE_CHOICES), default=None,
              help="Scattering engine [default: the particle config's: auto, the exact one where "
                   "the particle has one (docs/engines/index.md); builtin: the DDA].")
@click.option("--fix", "fixed", default="", metavar="NAME,NAME",
              help="Hold these parameters at the particle config's values: x_um, y_um, z_um, "
                   "orientation, alpha, or the model's own, "
                   + "; ".join(f"{kind}: {', '.join(names)}"
                               for kind, names in fixable_names().items())
                   + " (a voxel file: n1, n2, ... of its domains).")
@click.option("--tmatrix", type=click.Choice(TMATRIX_CHOICES), default="auto",
              show_default=True,
              help="Serve the final pass from the particle's T-matrix (built once, saved as "
                   "OUT/tmatrix.npz; auto: built-in engine and at least 8 frames, or the exact "
                   "engine whatever the frames).")
@click.option("--starts", "n_starts", type=click.IntRange(min=1), default=2, show_default=True,
              help="Library candidates used as starts (plus the mirrored best).")
@click.option("--no-mirror", is_flag=True,
              help="Do not also start from the best candidate mirrored through the x-y plane.")
@click.option("--no-model-test", is_flag=True,
              help="A non-spherical model's run does not test each track against a sphere of "
                   "the prefit's size (by default a sphere in a rod run is fitted as a sphere).")
@click.option("--no-continuity", is_flag=True,
              help="Skip the continuity sweeps (final-pass frames that look like a wrong "
                   "minimum refitted from their neighbours' orientations).")
@click.option("--model-error/--no-model-error", "model_error", default=None,
              help="Estimate the final table's model error (sidecar and notes): a "
                   "discrete-dipole engine refits a few frames on a 1.25x finer lattice (a size, "
                   "not a signed correction); an exact "
                   "engine records its T-matrix's stated accuracy [default: on].")
@click.option("--model-error-frames", type=click.IntRange(min=1), default=MODEL_ERROR_FRAMES,
              show_default=True, help="Frames the DDA's model-error estimate refits.")
@click.option("--independent-frames", "independent", is_flag=True,
              help="Fit every frame independently from the library's starts (default for a "
                   "non-spherical particle: follow each track, each frame from its "
                   "predecessor's fit, re-acquired from the library where that fails).")
@click.option("--no-tracking", "no_tracking", is_flag=True, hidden=True,
              help="Deprecated spelling of --independent-frames.")
@click.option("--flag-probability", type=click.FloatRange(min=0, max=0.5, min_open=True,
                                                          max_open=True),
              default=1e-4, show_default=True,
              help="After the continuity sweeps, an ok frame becomes poor_fit when its chi^2 "
                   "is improbable: a frame in the right minimum is flagged with this "
                   "probability (chi^2 of its pixels and the movie's measured excess scatter).")
@click.option("--ambiguity-chi2", type=click.FloatRange(min=0), default=9.0,
              show_default=True,
              help="A runner-up within this chi^2 (in pixel-noise units) flags the frame "
                   "ambiguous.")
@click.option("--pixel-fraction", type=click.FloatRange(min=0, max=1, min_open=True),
              default=1.0, show_default=True,
              help="Fit a random subset with this fraction of the pixels (seeded by frame).")
@click.option("--saturation", type=float, default=None, metavar="LEVEL",
              help="Leave out pixels whose normalised value is >= LEVEL [default: none; "
                   "pixels masked by crop (NaN) are always left out].")
@click.option("--noise-sd", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Pixel noise for chi^2 (default: estimated per crop).")
@click.option("--far-field", is_flag=True,
              help="Asymptotic far-field scattered field (as ADDA and the paper), not the exact.")
@aperture_options
@quality_options
@batch_options
def fit(
    crop_dir: Path,
    prefit_dir: Path,
    library_dir: Path | None,
    particle: tuple[str, ...],
    particles: tuple[int, ...],
    exclude_particles: tuple[int, ...],
    out: Path,
    instrument: str | None,
    pass_name: str,
    initial_frames: int | None,
    static_mode: str,
    static_file: Path | None,
    engine: str | None,
    fixed: str,
    tmatrix: str,
    n_starts: int,
    no_mirror: bool,
    no_model_test: bool,
    no_continuity: bool,
    model_error: bool | None,
    model_error_frames: int,
    independent: bool,
    no_tracking: bool,
    flag_probability: float,
    ambiguity_chi2: float,
    pixel_fraction: float,
    saturation: float | None,
    noise_sd: float | None,
    far_field: bool,
    numerical_aperture: str | None,
    fit_na: bool,
    max_chi2_red: float,
    min_r2: float | None,
    outlier_factor: float,
    plot: bool,
    plot_frames: str | None,
    override_instrument: bool,
    workers: int | None,
    scheduler: str | None,
    dask_local: bool,
    frame_range: str | None,
    retry_failed: bool,
    overwrite: bool,
    progress: bool | None,
) -> None:
    """DDA fit of every frame: an initial pass (all parameters free on some frames: spread over
    the movie, each seeded from the start statics' T-matrix, where the particle has one), the
    static parameters' robust average (OUT/static.json), then a final pass (static ones fixed).

    Writes OUT/initial.csv and OUT/fit.csv (the fit-table schema: `holofit analyze` reads
    fit.csv as it is; each row with values, 1-sigma errors d_*, chi2, chi2_red, R^2, the
    runner-up's delta_chi2 and an `ambiguous` flag, evaluations, time, status), their sidecars,
    plots, and data/model/residual pictures of a few frames. Parallel and resumable.
    """
    cfg, alternatives = _population([load_particle_arg(p) for p in particle])
    inst = load_instrument_arg(instrument) if instrument else None
    if min_r2 is not None:
        click.echo("note: --min-r2 is deprecated and has no effect: a fit is judged by its "
                   "chi^2 against the pixel noise, not by its R^2", err=True)
    opts = FrameFitSettings(n_starts=n_starts, mirror=not no_mirror,
                           ambiguity_chi2=ambiguity_chi2, pixel_fraction=pixel_fraction,
                           saturation=saturation, noise_sd=noise_sd, far_field=far_field,
                           quality=QualityLimits(max_chi2_red))
    batch = make_batch_options(workers, scheduler, dask_local, retry_failed, overwrite, progress)
    names = tuple(n.strip() for n in fixed.split(",") if n.strip())
    try:
        check_fixed(cfg.model, names)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--fix") from None
    if no_tracking:
        click.echo("note: --no-tracking is deprecated; use --independent-frames", err=True)
    config = FitConfig(
        cfg, alternatives=alternatives, model_test=not no_model_test,
        particles=particles or None, exclude_particles=exclude_particles, passes=pass_name,
        initial_frames=initial_frames, static=static_file,
        static_mode=static_mode, frame=opts, engine=engine, fixed=names, tmatrix=tmatrix,
        follow=FollowSettings(warm=not (independent or no_tracking)),
        continuity=ContinuitySettings(enabled=not no_continuity,
                                      flag_probability=flag_probability),
        model_error=ModelErrorSettings(enabled=model_error, frames=model_error_frames),
        frames=_tuple(frame_list(crop_dir, frame_range)), instrument=inst,
        override_instrument=override_instrument,
        numerical_aperture=aperture_choice(numerical_aperture), fit_na=fit_na,
        outlier_factor=outlier_factor, plot=plot,
        plot_frames=_tuple(parse_int_list(plot_frames, "--plot-frames")))
    run = run_fit(crop_dir, prefit_dir, library_dir, out, config, batch=batch)
    _report(run)


def _population(configs: list[ParticleConfig]) -> tuple[ParticleConfig, tuple[ParticleConfig,
                                                                            ...]]:
    """The primary model (the first non-spherical one, else the first) and the others."""
    if not configs:
        raise click.UsageError("give the particle model with -p/--particle-model")
    anisotropic = [c for c in configs if c.model.anisotropic]
    if len(anisotropic) > 1:
        raise click.BadParameter(
            f"{', '.join(c.model.kind for c in anisotropic)}: a run's population holds one "
            "non-spherical model (the library ranks its orientations); fit the others in a run "
            "of their own", param_hint="-p/--particle-model")
    primary = anisotropic[0] if anisotropic else configs[0]
    return primary, tuple(c for c in configs if c is not primary)


def _report(run: FitRun) -> None:
    """What the fit wrote: each pass's frames by status (its table's), the batches' items run
    now and before, the notes, the sweeps, the tracks left out, the tables."""
    tables = {"initial": run.initial, "final": run.final}
    for name, s in run.summaries.items():
        for note in s.notes:
            click.echo(f"note: {note}", err=True)
        table = tables.get(name)
        if table is not None and Path(table).exists():
            frame_counts = pd.read_csv(table)["status"].value_counts().to_dict()
            n_frames = sum(frame_counts.values())
        else:
            frame_counts, n_frames = s.statuses, s.n_frames
        counts = ", ".join(f"{k} {v}" for k, v in sorted(frame_counts.items()))
        items = "" if n_frames == s.n_frames else f" in {s.n_frames} chunk(s)"
        click.echo(f"fit ({name}): {n_frames} frame(s) [{counts}]{items}; {s.n_run} fitted "
                   f"now, {s.n_done_before} done before; {s.elapsed_s:.1f} s")
    for note in run.notes:
        click.echo(f"note: {note}", err=True)
    if run.static is not None:
        click.echo(f"static parameters -> {run.static}")
    if run.continuity is not None and run.continuity.sweeps:
        c = run.continuity
        click.echo(f"continuity: {c.sweeps} sweep(s), {c.refitted} refit(s), {c.replaced} "
                   f"row(s) improved, {c.flagged} flagged poor_fit")
    for p, why in sorted(run.left_out.items()):
        click.echo(f"particle {p} left out: {why}")
    if run.tracks is not None:
        click.echo(f"tracks (model, statics, status) -> {run.tracks}")
    if run.final is not None:
        click.echo(f"final fit table -> {run.final}")


def _tuple(values: list[int] | None) -> tuple[int, ...] | None:
    return None if values is None else tuple(values)
