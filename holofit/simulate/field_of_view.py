"""Movies of a field of view that holds several particles, with known truth.

Each particle has its own model, engine and trajectory; a particle may be outside the frame
for part of the movie (its hologram then enters or leaves through an edge). The camera records
the sum of the particles' scattered *fields* with the incident wave (superposition at the
camera, :mod:`holofit.scattering.recorded_field`), so overlapping holograms interfere as they do
in a real microscope; multiple scattering between the particles is neglected (it is of the order of
the scattered amplitude at the neighbour's distance squared: docs: validation, "field of
view"). The truth table is keyed by (``particle``, ``frame``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from holofit.camera import Camera
from holofit.config import Instrument
from holofit.conventions import hologram_intensity, pixel_centres
from holofit.engines.select import select_engine
from holofit.particles import ParticleModel
from holofit.scattering.recorded_field import recorded_field
from holofit.scattering.theory import Orientation, ScatteredWave, ScatteringEngine
from holofit.simulate.holograms import (
    TRUTH_UNITS,
    Exposure,
    GroundTruth,
    SimulatedMovie,
    SimulationError,
    check_positions,
    default_camera,
    film,
)

__all__ = ["FIELD_TRUTH_UNITS", "ParticleInView", "simulate_field_of_view"]

FIELD_TRUTH_UNITS = {"particle": "id (order of the particles given)", **TRUTH_UNITS}


@dataclass
class ParticleInView:
    """One particle of a field of view.

    Attributes
    ----------
    model : ParticleModel
        The particle.
    positions_um : array_like, shape (N, 3)
        Full-frame ``(x, y, z)`` of its centre in every frame, um (it may lie outside the
        frame: its hologram is then cut by the edge, or absent).
    orientations : array_like, shape (N, 3), optional
        ``(psi, theta, phi)`` per frame, rad (ignored for isotropic models).
    alpha : float
        Scattered-field scaling.
    theory : ScatteringEngine, optional
        Engine; the model's default otherwise.
    """

    model: ParticleModel
    positions_um: ArrayLike
    orientations: ArrayLike | None = None
    alpha: float = 1.0
    theory: ScatteringEngine | None = None


class _Solved:
    """A particle's solved wave, re-solved only when its orientation changes."""

    def __init__(self, particle: ParticleInView, instrument: Instrument, n: int,
                 index: int) -> None:
        lens = instrument.optics.numerical_aperture is not None
        try:
            self.pos = check_positions(particle.model, particle.positions_um, lens)
        except SimulationError as exc:
            raise SimulationError(f"particle {index}: {exc}", exc.frame) from None
        if len(self.pos) != n:
            raise SimulationError(
                f"particle {index} has {len(self.pos)} positions, particle 0 has {n}: every "
                "particle needs one position per frame"
            )
        if particle.orientations is None:
            self.orient = np.zeros((n, 3))
        else:
            self.orient = np.atleast_2d(np.asarray(particle.orientations, dtype=float))
            if self.orient.shape != (n, 3):
                raise SimulationError(
                    f"particle {index}: orientations must have shape ({n}, 3), got "
                    f"{self.orient.shape}"
                )
        self.particle = particle
        self.theory = particle.theory or select_engine(particle.model)
        self.optics = instrument.optics
        self._wave: ScatteredWave | None = None
        self._orientation: tuple[float, ...] | None = None

    def wave(self, k: int) -> ScatteredWave:
        model = self.particle.model
        o = tuple(self.orient[k]) if model.anisotropic else (0.0, 0.0, 0.0)
        if self._wave is None or o != self._orientation:
            self._wave = self.theory.solve(model, self.optics, Orientation(*o))
            self._orientation = o
        return self._wave


def _frame_field(
    solved: Sequence[_Solved], k: int, xs: NDArray, ys: NDArray
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    ex = np.zeros(xs.shape, dtype=complex)
    ey = np.zeros(xs.shape, dtype=complex)
    for s in solved:
        fx, fy = recorded_field(s.wave(k), s.pos[k], xs.ravel(), ys.ravel())
        ex += s.particle.alpha * np.reshape(fx, xs.shape)
        ey += s.particle.alpha * np.reshape(fy, xs.shape)
    return ex, ey


def simulate_field_of_view(
    particles: Sequence[ParticleInView],
    instrument: Instrument,
    frame_shape: tuple[int, int],
    *,
    camera: Camera | None = None,
    noise: bool = True,
    seed: int = 0,
    n_background: int = 5,
    out_dir: str | Path | None = None,
    keep_frames: bool = False,
    progress: Any = None,
) -> SimulatedMovie:
    """Simulate a movie of several particles in one field of view.

    Parameters
    ----------
    particles : sequence of ParticleInView
        The particles, each with one position per frame (all the same number of frames).
    instrument : Instrument
        Optics, pixel size, camera bit depth and frame rate.
    frame_shape : tuple of int
        ``(rows, columns)`` of the frames.
    camera : Camera, optional
        Camera model; by default the instrument's
        (:func:`~holofit.simulate.holograms.default_camera`).
    noise : bool
        Add shot and read noise (quantisation always applies).
    seed : int
        Random seed of the camera noise.
    n_background : int
        Frames in the background stack.
    out_dir : str or Path, optional
        If given, write ``movie.tif``, ``background.tif`` and ``truth.csv`` (+ sidecars); the
        truth has one row per (particle, frame), whether or not the particle is in the frame.
    keep_frames : bool
        Also return the raw frames in memory.
    progress : callable, optional
        Called with the number of frames done.

    Returns
    -------
    SimulatedMovie
        ``truth`` has the columns :data:`FIELD_TRUTH_UNITS`.

    Raises
    ------
    SimulationError
        No particles, particles with different numbers of frames, or positions that cannot be
        imaged (:func:`~holofit.simulate.holograms.check_positions`); the message names the
        particle. Nothing is written.
    """
    if not particles:
        raise SimulationError("no particles: nothing to simulate")
    n = len(np.atleast_2d(np.asarray(particles[0].positions_um, dtype=float)))
    solved = [_Solved(p, instrument, n, i) for i, p in enumerate(particles)]
    camera = camera or default_camera(instrument)
    rng = np.random.default_rng(seed)
    xs, ys = pixel_centres(frame_shape, instrument.pixel_size_um)
    dt = 1.0 / instrument.frame_rate_hz if instrument.frame_rate_hz else 1.0
    truth = _truth_table(solved, n, dt, instrument.pixel_size_um)
    meta = _metadata(solved, instrument, camera, noise, seed)
    pol = instrument.optics.polarization_rad
    holograms = (hologram_intensity(*_frame_field(solved, k, xs, ys), pol) for k in range(n))
    exposure = Exposure(camera, noise, n_background=n_background)
    return film(
        holograms, exposure, rng, frame_shape,
        GroundTruth(truth, FIELD_TRUTH_UNITS, meta, "simulated field of view"),
        out_dir=out_dir, keep_frames=keep_frames, progress=progress,
    )


def _truth_table(solved: Sequence[_Solved], n: int, dt: float, pixel_um: float) -> pd.DataFrame:
    """One row per (particle, frame): the true position (um and px), orientation and alpha."""
    return pd.concat(
        [
            pd.DataFrame({
                "particle": i,
                "frame": np.arange(n),
                "time_s": np.arange(n) * dt,
                "x_um": s.pos[:, 0], "y_um": s.pos[:, 1], "z_um": s.pos[:, 2],
                "x_px": s.pos[:, 0] / pixel_um,
                "y_px": s.pos[:, 1] / pixel_um,
                "psi_rad": s.orient[:, 0], "theta_rad": s.orient[:, 1],
                "phi_rad": s.orient[:, 2],
                "alpha": s.particle.alpha,
            })
            for i, s in enumerate(solved)
        ],
        ignore_index=True,
    )


def _metadata(solved: Sequence[_Solved], instrument: Instrument, camera: Camera, noise: bool,
              seed: int) -> dict[str, Any]:
    """The sidecar's description of the simulation."""
    return {
        "instrument": instrument.as_dict(),
        "particles": [
            {"model": s.particle.model.kind, **s.particle.model.parameters(),
             "engine": getattr(s.theory, "name", type(s.theory).__name__),
             "alpha": s.particle.alpha}
            for s in solved
        ],
        "superposition": "scattered fields summed at the camera; no multiple scattering",
        "camera": camera.__dict__,
        "noise": noise,
        "seed": seed,
    }
