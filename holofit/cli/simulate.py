"""``holofit simulate``: synthetic data with known truth."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np
import pandas as pd

from holofit.cli.common import (
    instrument_option,
    load_instrument_arg,
    load_particle_arg,
    out_dir_option,
    parse_pair,
    parse_triple,
)
from holofit.cli.errors import HolofitGroup
from holofit.cli.simulate_field import simulate_field_cmd
from holofit.cli.simulate_trajectory import simulate_trajectory_cmd
from holofit.engines.select import ENGINE_CHOICES
from holofit.particles import ParticleModel, Sphere
from holofit.progress import progress_bar
from holofit.simulate.holograms import Exposure, SimulationError, check_positions, simulate_movie

POSITIVE = click.FloatRange(min=0, min_open=True)
NONNEGATIVE = click.FloatRange(min=0)
SEED = click.IntRange(min=0)


@click.group(cls=HolofitGroup)
def simulate() -> None:
    """Synthetic holograms and trajectories with known ground truth."""


simulate.add_command(simulate_trajectory_cmd)
simulate.add_command(simulate_field_cmd)


def _read_csv(path: Path, option: str) -> pd.DataFrame:
    try:
        return pd.read_csv(path)
    except (ValueError, OSError) as exc:
        raise click.BadParameter(f"{path}: not a readable CSV table ({exc})",
                                 param_hint=option) from None


def _positions(
    model: ParticleModel,
    position: tuple[str, ...],
    positions_file: Path | None,
    file_option: str,
    table: pd.DataFrame | None = None,
    lens: bool = False,
) -> np.ndarray:
    """Positions from ``--position`` or a table file, checked against ``model`` (any height
    through an objective lens, ``lens``)."""
    if positions_file is not None:
        if position:
            raise click.UsageError(f"give --position or {file_option}, not both")
        if table is None:
            table = _read_csv(positions_file, file_option)
        missing = {"x_um", "y_um", "z_um"} - set(table.columns)
        if missing:
            raise click.BadParameter(
                f"{positions_file}: missing column(s) {', '.join(sorted(missing))}",
                param_hint=file_option,
            )
        pos = table[["x_um", "y_um", "z_um"]].to_numpy(float)
    elif not position:
        raise click.UsageError(f"give --position X,Y,Z (um) or {file_option} FILE")
    else:
        pos = np.array([parse_triple(p, "--position") for p in position])
    try:
        return check_positions(model, pos, lens)
    except SimulationError as exc:
        if positions_file is not None:
            where = f"{positions_file}" + (
                f", row {exc.frame + 1} of the table" if exc.frame is not None else ""
            )
            raise click.BadParameter(f"{where}: {exc}", param_hint=file_option) from None
        given = f" (--position {position[exc.frame]})" if exc.frame is not None else ""
        raise click.BadParameter(f"{exc}{given}", param_hint="--position") from None


@simulate.command("sphere")
@instrument_option(required=False)
@click.option(
    "--particle-model", "-p", "particle", default=None,
    help="Sphere model TOML (overrides --radius/--index)."
)
@click.option("--radius", type=POSITIVE, default=0.5, show_default=True, help="Radius, um.")
@click.option(
    "--index",
    "index_re",
    type=POSITIVE,
    default=1.59,
    show_default=True,
    help="Refractive index (real part).",
)
@click.option(
    "--index-imag",
    type=NONNEGATIVE,
    default=0.0,
    show_default=True,
    help="Imaginary part of the index (>= 0 absorbs).",
)
@click.option(
    "--position",
    multiple=True,
    metavar="X,Y,Z",
    help="Full-frame particle centre in um (z: height above the focal plane, larger than the "
    "radius; any height for an instrument with a numerical_aperture); repeat for a movie.",
)
@click.option(
    "--positions",
    "positions_file",
    type=click.Path(exists=True, path_type=Path),
    help="CSV with columns x_um, y_um, z_um: one frame per row.",
)
@click.option(
    "--shape",
    default="256,256",
    show_default=True,
    metavar="ROWS,COLS",
    help="Frame size in pixels.",
)
@click.option(
    "--alpha", type=float, default=1.0, show_default=True, help="Scattered-field scaling."
)
@click.option(
    "--noise/--no-noise",
    default=True,
    show_default=True,
    help="Poisson shot noise and read noise (quantisation always applies).",
)
@click.option("--seed", type=SEED, default=0, show_default=True,
              help="Random seed of the camera noise: the same seed gives the same movie.")
@out_dir_option()
def simulate_sphere(
    instrument: str | None,
    particle: str | None,
    radius: float,
    index_re: float,
    index_imag: float,
    position: tuple[str, ...],
    positions_file: Path | None,
    shape: str,
    alpha: float,
    noise: bool,
    seed: int,
    out: Path,
) -> None:
    """Holograms of a sphere (exact Lorenz-Mie) with camera noise.

    Writes OUT/movie.tif (raw counts), OUT/background.tif and OUT/truth.csv with its sidecar
    JSON (instrument, particle, camera, seed).
    """
    inst = load_instrument_arg(instrument or "paper_100x_oil")
    if particle is not None:
        model = load_particle_arg(particle).model
        if not isinstance(model, Sphere):
            raise click.BadParameter(f"{particle}: not a sphere model",
                                     param_hint="--particle-model")
    else:
        try:
            model = Sphere(radius, complex(index_re, index_imag))
        except ValueError as exc:
            raise click.BadParameter(str(exc)) from None
    pos = _positions(model, position, positions_file, "--positions",
                     lens=inst.optics.numerical_aperture is not None)
    frame_shape = parse_pair(shape, "--shape")
    with progress_bar(len(pos), "simulate", unit="frame") as bar:
        result = simulate_movie(model, inst, pos, frame_shape, alpha=alpha, seed=seed,
                                out_dir=out, progress=bar.update,
                                exposure=Exposure(noise=noise))
    click.echo(
        f"wrote {result.movie} ({len(pos)} frame(s) of {frame_shape[0]}x{frame_shape[1]}),"
        f" {result.background}, {result.truth_table}"
    )


def _orientations(orientation: tuple[str, ...], table: pd.DataFrame | None, n: int) -> np.ndarray:
    if table is not None and {"psi_rad", "theta_rad"} <= set(table.columns):
        phi = table["phi_rad"] if "phi_rad" in table.columns else 0.0
        return np.column_stack([table["psi_rad"], table["theta_rad"], np.broadcast_to(phi, n)])
    if not orientation:
        return np.zeros((n, 3))
    values = np.radians([parse_triple(o, "--orientation") for o in orientation])
    if len(values) == 1:
        return np.repeat(values, n, axis=0)
    if len(values) != n:
        raise click.BadParameter(
            f"give one --orientation or one per position ({n}), got {len(values)}",
            param_hint="--orientation",
        )
    return values


@simulate.command("hologram")
@click.option(
    "--particle-model",
    "-p",
    "particle",
    required=True,
    help="Particle-model TOML (any model: sphere, spherocylinder, janus, dimer, ...).",
)
@instrument_option(required=False)
@click.option(
    "--engine",
    type=click.Choice(ENGINE_CHOICES),
    default="auto",
    show_default=True,
    help="Scattering engine (auto: the exact one where the particle has one - Lorenz-Mie, "
    "coated sphere, cluster, the T-matrix of a body of revolution - else the config's "
    "[dda]; docs/engines/index.md).",
)
@click.option(
    "--position",
    multiple=True,
    metavar="X,Y,Z",
    help="Full-frame particle centre in um (z: height above the focal plane, larger "
    "than the particle's bounding radius; any height for an instrument with a "
    "numerical_aperture); repeat for a movie.",
)
@click.option(
    "--orientation",
    multiple=True,
    metavar="PSI,THETA,PHI",
    help="zyz Euler angles in degrees: one for all frames or one per --position.",
)
@click.option(
    "--trajectory",
    "trajectory_file",
    type=click.Path(exists=True, path_type=Path),
    help="CSV with x_um, y_um, z_um (and psi_rad, theta_rad[, phi_rad]) per frame, "
    "e.g. from `holofit simulate trajectory`.",
)
@click.option(
    "--shape",
    default="256,256",
    show_default=True,
    metavar="ROWS,COLS",
    help="Frame size in pixels.",
)
@click.option(
    "--alpha",
    type=float,
    default=1.0,
    show_default=True,
    help="Scattered-field scaling (the fits' alpha; 1: the exact field).",
)
@click.option(
    "--noise/--no-noise",
    default=True,
    show_default=True,
    help="Poisson shot noise and read noise (quantisation always applies).",
)
@click.option(
    "--seed",
    type=SEED,
    default=0,
    show_default=True,
    help="Random seed of the camera noise: the same seed gives the same movie.",
)
@out_dir_option()
def simulate_hologram(
    particle: str,
    instrument: str | None,
    engine: str,
    position: tuple[str, ...],
    orientation: tuple[str, ...],
    trajectory_file: Path | None,
    shape: str,
    alpha: float,
    noise: bool,
    seed: int,
    out: Path,
) -> None:
    """Holograms of any particle model (DDA for non-spheres) with camera noise.

    Writes OUT/movie.tif, OUT/background.tif and OUT/truth.csv (+ sidecar JSON).
    """
    inst = load_instrument_arg(instrument or "paper_100x_oil")
    cfg = load_particle_arg(particle)
    try:
        theory = cfg.theory(engine)
    except (ValueError, RuntimeError) as exc:
        raise click.BadParameter(str(exc), param_hint="--engine") from None
    table = _read_csv(trajectory_file, "--trajectory") if trajectory_file is not None else None
    pos = _positions(
        cfg.model,
        position,
        trajectory_file,
        "--trajectory",
        table,
        lens=inst.optics.numerical_aperture is not None,
    )
    orient = _orientations(orientation, table, len(pos))
    frame_shape = parse_pair(shape, "--shape")
    with progress_bar(len(pos), "simulate", unit="frame") as bar:
        result = simulate_movie(
            cfg.model,
            inst,
            pos,
            frame_shape,
            orientations=orient,
            alpha=alpha,
            theory=theory,
            seed=seed,
            out_dir=out,
            progress=bar.update,
            exposure=Exposure(noise=noise),
        )
    click.echo(
        f"wrote {result.movie} ({len(pos)} frame(s) of {cfg.model.kind}, engine "
        f"{theory.name}), {result.background}, {result.truth_table}"
    )
