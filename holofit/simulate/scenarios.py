"""A diffusing particle filmed through a microscope: the trajectory and its movie, with known
truth, in one call (what the demo, the validation studies and ``make replicate`` start from).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from holofit.config import Instrument, ParticleConfig
from holofit.simulate.brownian import BrownianParameters, SimulatedTrajectory, simulate_trajectory
from holofit.simulate.holograms import SimulatedMovie, simulate_movie

__all__ = ["DiffusingMovie", "diffusing_movie"]

#: movies at least this long are rendered from the particle's T-matrix (built-in DDA engine)
TMATRIX_MIN_FRAMES = 20


@dataclass
class DiffusingMovie:
    """The trajectory (truth) and the movie simulated along it."""

    trajectory: SimulatedTrajectory
    movie: SimulatedMovie


def diffusing_movie(
    particle: ParticleConfig,
    instrument: Instrument,
    dynamics: BrownianParameters,
    out_dir: str | Path,
    *,
    frame_shape: tuple[int, int] = (256, 256),
    alpha: float = 0.9,
    seed: int = 0,
) -> DiffusingMovie:
    """Simulate ``particle`` diffusing with ``dynamics`` and film it with ``instrument``.

    Writes ``OUT/traj/`` (``trajectory.csv``, ``truth.csv``) and ``OUT/sim/`` (``movie.tif``,
    ``background.tif``, ``truth.csv``). Holograms of an anisotropic particle come from its
    T-matrix when the movie has at least :data:`TMATRIX_MIN_FRAMES` frames and the engine has
    one (exact to the solver's precision at every orientation; a direct solve per frame
    otherwise).
    """
    out = Path(out_dir)
    traj = simulate_trajectory(dynamics, seed=seed, out_dir=out / "traj")
    truth = traj.truth
    theory = particle.theory(fixed_lattice_for=instrument.optics)
    if (particle.model.anisotropic and len(truth) >= TMATRIX_MIN_FRAMES
            and hasattr(theory, "tmatrix")):
        theory.tmatrix(particle.model, instrument.optics)
    movie = simulate_movie(
        particle.model, instrument, truth[["x_um", "y_um", "z_um"]].to_numpy(), frame_shape,
        orientations=truth[["psi_rad", "theta_rad", "phi_rad"]].to_numpy(), alpha=alpha,
        theory=theory, seed=seed + 1, out_dir=out / "sim",
    )
    return DiffusingMovie(traj, movie)
