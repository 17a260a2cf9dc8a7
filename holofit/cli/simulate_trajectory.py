"""``holofit simulate trajectory``: Brownian rigid-body trajectories as fit tables."""

from __future__ import annotations

from pathlib import Path

import click

from holofit.cli.common import out_dir_option, parse_triple

POSITIVE = click.FloatRange(min=0, min_open=True)
NONNEGATIVE = click.FloatRange(min=0)
FRACTION = click.FloatRange(min=0, max=1, max_open=True)


@click.command("trajectory")
@click.option("--n-frames", "--frames", "n_frames", type=click.IntRange(min=2), default=2000,
              show_default=True,
              help="Number of frames (--frames: the old name, deprecated; elsewhere --frames "
                   "is a START:STOP range).")
@click.option("--frame-rate", type=POSITIVE, default=100.0, show_default=True,
              help="Frames per second.")
@click.option("--d-par", type=NONNEGATIVE, default=None,
              help="Translational diffusion along the axis, um^2/s.")
@click.option("--d-perp", type=NONNEGATIVE, default=None,
              help="Translational diffusion across the axis, um^2/s.")
@click.option("--d-t", type=NONNEGATIVE, default=None,
              help="Isotropic translational diffusion, um^2/s (sets both --d-par and --d-perp).")
@click.option("--d-r", type=NONNEGATIVE, required=True,
              help="Rotational diffusion about axes perpendicular to the symmetry axis, 1/s.")
@click.option("--d-spin", type=NONNEGATIVE, default=None,
              help="Rotational diffusion about the symmetry axis, 1/s [default: --d-r].")
@click.option("--drift", default="0,0,0", show_default=True, metavar="VX,VY,VZ",
              help="Constant drift velocity (e.g. sedimentation: 0,0,-0.9), um/s.")
@click.option("--start", default="0,0,10", show_default=True, metavar="X,Y,Z",
              help="Position at frame 0, um.")
@click.option("--substeps", type=click.IntRange(min=1), default=None,
              help="Integration steps per frame [default: D_r h <= 1e-3, at least 4].")
@click.option("--eps-um", type=NONNEGATIVE, default=0.0, show_default=True,
              help="Localisation noise (s.d. per coordinate), um.")
@click.option("--eps-z-um", type=NONNEGATIVE, default=None,
              help="Localisation noise along z, um [default: --eps-um].")
@click.option("--eps-r", type=NONNEGATIVE, default=0.0, show_default=True,
              help="Angular noise: rms angle between measured and true axis, rad.")
@click.option("--flip-fraction", type=FRACTION, default=0.0, show_default=True,
              help="Fraction of frames with u -> -u (head-tail flips).")
@click.option("--mirror-fraction", type=FRACTION, default=0.0, show_default=True,
              help="Fraction of frames with u_z -> -u_z (mirrored-orientation outliers).")
@click.option("--fail-fraction", type=FRACTION, default=0.0, show_default=True,
              help="Fraction of frames written with status 'failed'.")
@click.option("--missing-fraction", type=FRACTION, default=0.0, show_default=True,
              help="Fraction of frames left out of the table.")
@click.option("--a-um", type=float, default=None, help="Static column a_um to write, um.")
@click.option("--b-um", type=float, default=None, help="Static column b_um to write, um.")
@click.option("--n", "index", type=float, default=None, help="Static column n to write.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Random seed: the same seed gives the same trajectory.")
@out_dir_option()
def simulate_trajectory_cmd(
    n_frames: int, frame_rate: float, d_par: float | None, d_perp: float | None,
    d_t: float | None, d_r: float, d_spin: float | None, drift: str, start: str,
    substeps: int | None,
    eps_um: float, eps_z_um: float | None, eps_r: float, flip_fraction: float,
    mirror_fraction: float, fail_fraction: float, missing_fraction: float, a_um: float | None,
    b_um: float | None, index: float | None, seed: int, out: Path,
) -> None:
    """Rigid-body Brownian motion (Beard & Schlick rotation, anisotropic body-frame
    translation) with localisation and angular noise and optional artefacts.

    Writes OUT/trajectory.csv (the "measured" trajectory, fit-table schema; its sidecar JSON
    holds the truth: parameters and the frames of every injected artefact) and OUT/truth.csv
    (the noise-free trajectory, same schema).
    """
    from holofit.simulate.brownian import (
        BrownianParameters,
        MeasurementNoise,
        simulate_trajectory,
    )

    if d_t is not None:
        if d_par is not None or d_perp is not None:
            raise click.UsageError("give --d-t or --d-par/--d-perp, not both")
        d_par = d_perp = d_t
    if d_par is None or d_perp is None:
        raise click.UsageError("give --d-par and --d-perp (um^2/s), or --d-t")
    fractions = {"--flip-fraction": flip_fraction, "--mirror-fraction": mirror_fraction,
                 "--fail-fraction": fail_fraction, "--missing-fraction": missing_fraction}
    if sum(fractions.values()) >= 1:
        raise click.UsageError(f"{' + '.join(fractions)} must add up to less than 1, got "
                               f"{sum(fractions.values()):g}")
    static = {k: v for k, v in (("a_um", a_um), ("b_um", b_um), ("n", index)) if v is not None}
    try:
        params = BrownianParameters(
            n_frames, 1.0 / frame_rate, d_par, d_perp, d_r, d_spin,
            parse_triple(drift, "--drift"), parse_triple(start, "--start"), None, substeps,
        )
        noise = MeasurementNoise(eps_um, eps_z_um, eps_r, flip_fraction, mirror_fraction,
                                 fail_fraction, missing_fraction)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None
    sim = simulate_trajectory(params, noise, seed=seed, static=static, out_dir=out)
    click.echo(
        f"wrote {sim.path} ({n_frames} frames at {frame_rate:g}/s: {len(sim.flipped_frames)} "
        f"flipped, {len(sim.mirrored_frames)} mirrored, {len(sim.failed_frames)} failed, "
        f"{len(sim.missing_frames)} missing) and {sim.truth_path}"
    )
