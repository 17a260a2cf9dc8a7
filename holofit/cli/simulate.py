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
from holofit.cli.simulate_trajectory import simulate_trajectory_cmd
from holofit.models import Sphere
from holofit.progress import progress_bar
from holofit.simulate.holograms import simulate_movie


@click.group()
def simulate() -> None:
    """Synthetic holograms and trajectories with known ground truth."""


simulate.add_command(simulate_trajectory_cmd)


def _positions(position: tuple[str, ...], positions_file: Path | None) -> np.ndarray:
    if positions_file is not None:
        table = pd.read_csv(positions_file)
        missing = {"x_um", "y_um", "z_um"} - set(table.columns)
        if missing:
            raise click.BadParameter(
                f"{positions_file}: missing column(s) {', '.join(sorted(missing))}",
                param_hint="--positions",
            )
        return table[["x_um", "y_um", "z_um"]].to_numpy(float)
    if not position:
        raise click.BadParameter("give --position X,Y,Z (um) or --positions FILE")
    return np.array([parse_triple(p, "--position") for p in position])


@simulate.command("sphere")
@instrument_option(required=False)
@click.option(
    "--particle", "-p", default=None, help="Sphere model TOML (overrides --radius/--index)."
)
@click.option("--radius", type=float, default=0.5, show_default=True, help="Radius, um.")
@click.option(
    "--index",
    "index_re",
    type=float,
    default=1.59,
    show_default=True,
    help="Refractive index (real part).",
)
@click.option(
    "--index-imag",
    type=float,
    default=0.0,
    show_default=True,
    help="Imaginary part of the index (>= 0 absorbs).",
)
@click.option(
    "--position",
    multiple=True,
    metavar="X,Y,Z",
    help="Full-frame particle centre in um; repeat for a movie.",
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
@click.option("--seed", type=int, default=0, show_default=True)
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
            raise click.BadParameter(f"{particle}: not a sphere model", param_hint="--particle")
    else:
        try:
            model = Sphere(radius, complex(index_re, index_imag))
        except ValueError as exc:
            raise click.BadParameter(str(exc)) from None
    pos = _positions(position, positions_file)
    frame_shape = parse_pair(shape, "--shape")
    with progress_bar(len(pos), "simulate", unit="frame") as bar:
        result = simulate_movie(
            model,
            inst,
            pos,
            frame_shape,
            alpha=alpha,
            noise=noise,
            seed=seed,
            out_dir=out,
            progress=bar.update,
        )
    click.echo(
        f"wrote {result.movie} ({len(pos)} frame(s) of {frame_shape[0]}x{frame_shape[1]}),"
        f" {result.background}, {result.truth_table}"
    )
