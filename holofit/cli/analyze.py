"""``holofit analyze``: diffusion coefficients from a fit table."""

from __future__ import annotations

from pathlib import Path

import click

from holofit.analysis.population import default_model
from holofit.analysis.recipes import MODELS
from holofit.cli.common import out_dir_option, track_options

__all__ = ["OPTION_OF_SETTING", "analyze"]

#: the option that sets each field of AnalysisConfig (to name it in messages)
OPTION_OF_SETTING = {
    "model": "--model",
    "temperature_c": "--temperature-c",
    "temperature_err_c": "--temperature-err-c",
    "a_um": "--a-um",
    "b_um": "--b-um",
    "a_err_um": "--da-um",
    "b_err_um": "--db-um",
    "d_est": "--d-est",
    "eps_r_est": "--eps-r-est",
    "reject_probability": "--reject-p",
    "fit_lags_translation": "--fit-lags-t",
    "fit_lags_rotation": "--fit-lags-r",
    "max_lag": "--max-lag",
}


def _lag_range(value: str | None, name: str) -> tuple[int, int] | None:
    if value is None:
        return None
    try:
        lo, hi = (int(v) for v in value.split(":"))
    except ValueError:
        raise click.BadParameter(
            f"expected FIRST:LAST lags in frames (e.g. 1:10), got {value!r}", param_hint=name
        ) from None
    if lo < 1 or hi < lo:
        raise click.BadParameter(f"need 1 <= FIRST <= LAST, got {value!r}", param_hint=name)
    return lo, hi


@click.command()
@click.argument("fit_table", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--model", "-m", type=click.Choice(MODELS), default=None,
              help="rod: any head-tail symmetric particle (rods, dimers); janus: capped "
              "sphere (x, y and psi only); sphere: translation only. Given, every track's "
              "[default: each track's from the particle model the fit gave it (the fit "
              "table's model column), else from the particle its sidecar records].")
@click.option("--temperature-c", type=float, default=21.0, show_default=True,
              help="Sample temperature, C.")
@click.option("--temperature-err-c", type=float, default=2.0, show_default=True,
              help="Its uncertainty, C.")
@click.option("--a-um", type=float, default=None,
              help="Radius (sphere, Janus) or cap radius (rod), um [default: table median].")
@click.option("--b-um", type=float, default=None,
              help="Rod half tip-to-tip length, um [default: table median].")
@click.option("--da-um", type=float, default=None, help="Uncertainty of a, um.")
@click.option("--db-um", type=float, default=None, help="Uncertainty of b, um.")
@click.option("--d-est", type=float, default=None,
              help="D_est for the rejection of improbable jumps, 1/s [default: estimated].")
@click.option("--eps-r-est", type=float, default=None,
              help="Angular noise per frame for the rejection, rad [default: estimated; "
              "0 = the paper's rule].")
@click.option("--reject-p", type=float, default=1e-4, show_default=True,
              help="Reject angular jumps less probable than this.")
@click.option("--reject/--no-reject", default=None,
              help="Reject improbable angular jumps [default: on for rods, off otherwise].")
@click.option("--flip/--no-flip", "head_tail", default=None,
              help="Correct head-tail flips [default: on for rods].")
@click.option("--drift/--no-drift", default=True, show_default=True,
              help="Subtract a constant drift velocity (sedimentation).")
@click.option("--fit-lags-t", default=None, metavar="FIRST:LAST",
              help="Translational fit range in frames [default: 1:p, p = 2 + 2.5 sqrt(x) "
              "from the reduced localisation error x = eps^2/(D dt), 3-20 lags].")
@click.option("--fit-lags-r", default=None, metavar="FIRST:LAST",
              help="Rotational fit range in frames [default: rod as for translation, below "
              "<|du|^2> = 0.5; janus: down to <p.p'> = 0.5].")
@click.option("--max-lag", type=int, default=None,
              help="Longest lag computed for the plots, frames [default: a quarter of the run].")
@click.option("--frame-interval-s", type=float, default=None,
              help="Override the time between frames, s.")
@click.option("--plot/--no-plot", "--plots/--no-plots", "plots", default=True, show_default=True,
              help="Write PNG plots (--plots/--no-plots: the old spelling, deprecated).")
@click.option("--min-track-frames", type=click.IntRange(min=3), default=20, show_default=True,
              help="Multi-particle tables: tracks with fewer ok frames are reported and left "
                   "out.")
@track_options
@out_dir_option()
def analyze(
    fit_table: Path,
    model: str | None,
    temperature_c: float,
    temperature_err_c: float,
    a_um: float | None,
    b_um: float | None,
    da_um: float | None,
    db_um: float | None,
    d_est: float | None,
    eps_r_est: float | None,
    reject_p: float,
    reject: bool | None,
    head_tail: bool | None,
    drift: bool,
    fit_lags_t: str | None,
    fit_lags_r: str | None,
    max_lag: int | None,
    frame_interval_s: float | None,
    plots: bool,
    min_track_frames: int,
    particles: tuple[int, ...],
    exclude_particles: tuple[int, ...],
    out: Path,
) -> None:
    """Diffusion analysis of FIT_TABLE: MSDs, orientation correlations, theory.

    Writes OUT/summary.csv (+ .json sidecar), OUT/summary.json, OUT/msd.csv and PNG plots
    (msd.png, orientation.png, trajectory.png), and prints a short report. A table of several
    tracks is analysed track by track (OUT/particle_N_summary.csv, ...) and pooled
    (OUT/tracks.csv, OUT/pooled.csv, tracks.png, track_msds.png; OUT/summary.csv with every
    track's rows, and a row for each track left out, with its reason). Each track is analysed
    with the model of the particle the fit gave it, unless --model imposes one; only tracks of
    one model are pooled.
    """
    from holofit.analysis import (
        AnalysisConfig,
        SettingError,
        TrackPooling,
        TrackSelection,
        run_analysis,
    )

    selection = TrackSelection(particles or None, exclude_particles, model)
    base = model
    if base is None:
        base, why = default_model(fit_table)
        if base is None:
            raise click.UsageError(f"give --model ({', '.join(MODELS)}): {fit_table}: {why}")
        click.echo(f"model: {base} ({why}); a track the fit gave another particle model is "
                   "analysed with that one's", err=True)

    try:
        settings = AnalysisConfig(
            model=base, temperature_c=temperature_c, temperature_err_c=temperature_err_c,
            a_um=a_um, b_um=b_um, a_err_um=da_um, b_err_um=db_um, head_tail=head_tail,
            reject=reject, reject_probability=reject_p, d_est=d_est, eps_r_est=eps_r_est,
            subtract_drift=drift, fit_lags_translation=_lag_range(fit_lags_t, "--fit-lags-t"),
            fit_lags_rotation=_lag_range(fit_lags_r, "--fit-lags-r"), max_lag=max_lag,
        )
    except SettingError as exc:
        raise click.BadParameter(exc.problem, param_hint=OPTION_OF_SETTING[exc.setting]) from None
    # FitTableError / AnalysisError name the file; the top-level handler shows them as
    # "holofit analyze: error: ..." like every stage's
    run = run_analysis(fit_table, settings, out, plots=plots, frame_interval_s=frame_interval_s,
                       pooling=TrackPooling(min_frames=min_track_frames), selection=selection)
    click.echo(run.report())
    click.echo("")
    click.echo("wrote " + ", ".join(str(p) for p in run.files.values()))

