"""Synthetic hologram movies with known truth.

A particle model is solved once per orientation (once for a sphere) and placed at each
frame's position; the camera model turns the normalised holograms into raw counts with shot
noise, read noise and quantisation. A background stack is written beside the movie, so the
output goes straight into ``holofit crop``.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from holofit.camera import Camera
from holofit.config import Instrument
from holofit.conventions import DetectorGrid
from holofit.engines.select import select_engine
from holofit.hologram import calc_hologram
from holofit.io.tables import write_table
from holofit.io.tiffstack import TiffStackWriter
from holofit.particles import ParticleModel
from holofit.provenance import sidecar
from holofit.scattering.theory import Orientation, ScatteringEngine

__all__ = [
    "Exposure",
    "GroundTruth",
    "SimulatedMovie",
    "SimulationError",
    "check_positions",
    "default_camera",
    "film",
    "movie_holograms",
    "simulate_movie",
    "smooth_illumination",
    "truth_table",
]

TRUTH_UNITS = {
    "frame": "index",
    "time_s": "s",
    "x_um": "um",
    "y_um": "um",
    "z_um": "um",
    "x_px": "pixel (column)",
    "y_px": "pixel (row)",
    "psi_rad": "rad",
    "theta_rad": "rad",
    "phi_rad": "rad",
    "alpha": "1",
}


class SimulationError(ValueError):
    """A simulation that cannot be made as asked; ``frame`` is the frame at fault, if any."""

    def __init__(self, message: str, frame: int | None = None) -> None:
        super().__init__(message)
        self.frame = frame


def check_positions(model: ParticleModel, positions_um: ArrayLike,
                    lens: bool = False) -> NDArray[np.float64]:
    """Check that every frame's position can be imaged.

    The ideal model (no objective lens) records the field in the focal plane (``z = 0``) of a
    particle above it (``z`` is the height of the centre, toward the light source): a plane that
    cuts the particle has no exterior field to record, and a particle below the plane would
    need the field of a virtual image, so the particle must lie wholly above the plane. The
    test uses the model's bounding radius (the smallest sphere about its centre that holds
    it), so it holds for every orientation. Through an objective lens
    (:mod:`holofit.scattering.lens`) the hologram is the image of the scattered wave, defined
    at every height: in, near and below the focal plane.

    Parameters
    ----------
    model : ParticleModel
        The particle.
    positions_um : array_like, shape (N, 3)
        ``(x, y, z)`` of the centre per frame, um.
    lens : bool
        The holograms are lens images (the instrument has a numerical aperture): any finite
        height is allowed.

    Returns
    -------
    ndarray, shape (N, 3)
        The positions as floats.

    Raises
    ------
    SimulationError
        Wrong shape, a non-finite coordinate, or ``z`` not above the bounding radius; the
        message and ``frame`` name the first frame at fault.
    """
    pos = np.atleast_2d(np.asarray(positions_um, dtype=float))
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise SimulationError(f"positions must have shape (N, 3), got {pos.shape}")
    if len(pos) == 0:
        raise SimulationError("no positions: nothing to simulate")
    bad = ~np.isfinite(pos).all(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise SimulationError(f"frame {k}: position {tuple(pos[k])} is not finite", k)
    if lens:
        return pos
    radius = float(model.bounding_radius_um)
    low = pos[:, 2] <= radius
    if low.any():
        k = int(np.argmax(low))
        x, y, z = (float(v) for v in pos[k])
        where = "lies below the focal plane" if z < -radius else "is cut by the focal plane"
        raise SimulationError(
            f"frame {k}: the particle centred at ({x:g}, {y:g}, {z:g}) um {where}: z, the "
            "height of the centre above the focal plane (toward the light source), must "
            f"exceed the particle's bounding radius, {radius:.4g} um (or image through an "
            "objective lens: give the instrument a numerical_aperture)",
            k,
        )
    return pos


@dataclass
class SimulatedMovie:
    """What :func:`simulate_movie` produced."""

    movie: Path | None
    background: Path | None
    truth_table: Path | None
    truth: pd.DataFrame
    frames: list[NDArray] | None = None


@dataclass(frozen=True)
class Exposure:
    """How simulated holograms are recorded.

    Attributes
    ----------
    camera : Camera, optional
        Camera model; by default the instrument's (:func:`default_camera`).
    noise : bool
        Add shot and read noise (quantisation always applies).
    uneven_illumination : float
        Amplitude of a smooth illumination pattern that both movie and background carry.
    n_background : int
        Frames in the background stack.
    """

    camera: Camera | None = None
    noise: bool = True
    uneven_illumination: float = 0.0
    n_background: int = 5

    def for_instrument(self, instrument: Instrument) -> Exposure:
        """This exposure with its camera made from ``instrument`` where it has none."""
        if self.camera is not None:
            return self
        return replace(self, camera=default_camera(instrument))


@dataclass(frozen=True)
class GroundTruth:
    """What a simulated movie's ``truth.csv`` holds: the table, its units, the sidecar's
    ``truth`` entry, and what the movie is (its TIFF description)."""

    table: pd.DataFrame
    units: dict[str, str]
    meta: dict[str, Any]
    label: str


def smooth_illumination(
    shape: tuple[int, int], rng: np.random.Generator, amplitude: float = 0.05
) -> NDArray[np.float64]:
    """A smooth, slightly uneven illumination pattern (relative, mean 1) for realism."""
    i, j = np.mgrid[0 : shape[0], 0 : shape[1]]
    u, v = i / max(shape[0] - 1, 1), j / max(shape[1] - 1, 1)
    c = rng.normal(0.0, amplitude, 5)
    pattern = 1 + c[0] * (u - 0.5) + c[1] * (v - 0.5) + c[2] * (u - 0.5) * (v - 0.5)
    pattern += c[3] * np.cos(2 * np.pi * u) + c[4] * np.sin(2 * np.pi * v) * 0.5
    return pattern / pattern.mean()


def simulate_movie(
    model: ParticleModel, instrument: Instrument, positions_um: ArrayLike,
    frame_shape: tuple[int, int], *, orientations: ArrayLike | None = None, alpha: float = 1.0,
    theory: ScatteringEngine | None = None, exposure: Exposure | None = None, seed: int = 0,
    out_dir: str | Path | None = None, keep_frames: bool = False, progress: Any = None,
) -> SimulatedMovie:
    """Simulate a movie of holograms of one particle.

    Parameters
    ----------
    model : ParticleModel
        The particle.
    instrument : Instrument
        Optics and pixel size.
    positions_um : array_like, shape (N, 3)
        Full-frame ``(x, y, z)`` of the particle centre in each frame, um.
    frame_shape : tuple of int
        ``(rows, columns)`` of the frames.
    orientations : array_like, shape (N, 3), optional
        ``(psi, theta, phi)`` per frame, rad (ignored for isotropic models).
    alpha : float
        Scattered-field scaling.
    theory : ScatteringEngine, optional
        Engine; Lorenz-Mie for spheres and the built-in DDA otherwise.
    exposure : Exposure, optional
        Camera, noise, illumination and background frames (default: the instrument's camera,
        with noise).
    seed : int
        Random seed.
    out_dir : str or Path, optional
        If given, write ``movie.tif``, ``background.tif`` and ``truth.csv`` (+ sidecars).
    keep_frames : bool
        Also return the raw frames in memory.
    progress : callable, optional
        Called with the number of frames done.

    Returns
    -------
    SimulatedMovie

    Raises
    ------
    SimulationError
        Positions that are not wholly above the focal plane without a lens
        (:func:`check_positions`), or orientations of the wrong shape; nothing is written.
    """
    pos = check_positions(model, positions_um, instrument.optics.numerical_aperture is not None)
    orient = _check_orientations(orientations, pos.shape[0])
    theory = theory or select_engine(model)
    exposure = (exposure or Exposure()).for_instrument(instrument)
    assert exposure.camera is not None
    rng = np.random.default_rng(seed)
    illum = (smooth_illumination(frame_shape, rng, exposure.uneven_illumination)
             if exposure.uneven_illumination > 0 else None)
    grid = DetectorGrid(frame_shape, instrument.pixel_size_um)
    truth = truth_table(instrument, pos, orient, alpha)
    meta_common = {
        "instrument": instrument.as_dict(),
        "particle": {"model": model.kind, **{k: v for k, v in model.parameters().items()}},
        "engine": getattr(theory, "name", type(theory).__name__),
        "camera": exposure.camera.__dict__, "noise": exposure.noise, "seed": seed,
        "alpha": alpha, "uneven_illumination": exposure.uneven_illumination,
    }
    holograms = movie_holograms(model, theory, instrument, pos, orient, grid, alpha)
    return film(
        holograms, exposure, rng, frame_shape,
        GroundTruth(truth, TRUTH_UNITS, meta_common, "simulated movie"),
        illumination=illum, out_dir=out_dir, keep_frames=keep_frames, progress=progress,
    )


def _check_orientations(orientations: ArrayLike | None, n: int) -> NDArray[np.float64]:
    """The ``(n, 3)`` orientations (zeros if None); SimulationError for another shape."""
    if orientations is None:
        return np.zeros((n, 3))
    orient = np.atleast_2d(np.asarray(orientations, dtype=float))
    if orient.shape != (n, 3):
        raise SimulationError(f"orientations must have shape ({n}, 3), got {orient.shape}")
    return orient


def truth_table(instrument: Instrument, pos: NDArray, orient: NDArray,
                alpha: float) -> pd.DataFrame:
    """The ground truth of a one-particle movie (columns and units of :data:`TRUTH_UNITS`)."""
    n = pos.shape[0]
    dt = 1.0 / instrument.frame_rate_hz if instrument.frame_rate_hz else 1.0
    return pd.DataFrame(
        {
            "frame": np.arange(n),
            "time_s": np.arange(n) * dt,
            "x_um": pos[:, 0],
            "y_um": pos[:, 1],
            "z_um": pos[:, 2],
            "x_px": pos[:, 0] / instrument.pixel_size_um,
            "y_px": pos[:, 1] / instrument.pixel_size_um,
            "psi_rad": orient[:, 0],
            "theta_rad": orient[:, 1],
            "phi_rad": orient[:, 2],
            "alpha": alpha,
        }
    )


def movie_holograms(
    model: ParticleModel, theory: ScatteringEngine, instrument: Instrument, pos: NDArray,
    orient: NDArray, grid: DetectorGrid, alpha: float,
) -> Iterator[NDArray[np.float64]]:
    """The normalised hologram of each frame (:func:`holofit.hologram.calc_hologram`, through
    the recorded field), solving the particle again only when its orientation changes."""
    wave = None
    last_orientation: tuple[float, ...] | None = None
    for k in range(pos.shape[0]):
        o = tuple(orient[k]) if model.anisotropic else (0.0, 0.0, 0.0)
        if wave is None or o != last_orientation:
            wave = theory.solve(model, instrument.optics, Orientation(*o))
            last_orientation = o
        yield calc_hologram(wave, pos[k], grid, alpha)


def default_camera(instrument: Instrument) -> Camera:
    """The simulated camera of an instrument: its bit depth and read noise, background at
    47 % of full scale."""
    return Camera(
        bit_depth=instrument.bit_depth,
        background_counts=0.47 * (2**instrument.bit_depth - 1),
        read_noise_counts=instrument.read_noise_counts or 0.8,
    )


def film(
    holograms: Iterable[NDArray[np.float64]],
    exposure: Exposure,
    rng: np.random.Generator,
    frame_shape: tuple[int, int],
    truth: GroundTruth,
    *,
    illumination: NDArray | None = None,
    out_dir: str | Path | None = None,
    keep_frames: bool = False,
    progress: Any = None,
) -> SimulatedMovie:
    """Expose normalised holograms on the camera and write the movie and its companions.

    Writes (with ``out_dir``) ``movie.tif`` frame by frame (removed again if anything fails),
    then ``background.tif`` (frames of the same camera without a particle) and ``truth.csv``
    (+ sidecar, ``units`` and ``meta``), in that order.

    Parameters
    ----------
    holograms : iterable of ndarray
        Normalised holograms (background 1), one per frame, of shape ``frame_shape``.
    exposure : Exposure
        Its camera (given) turns each into raw counts; noise and background frames.
    rng : numpy.random.Generator
        Source of the camera noise.
    frame_shape : tuple of int
        ``(rows, columns)``.
    truth : GroundTruth
        The ground truth to write, its units, sidecar entry and the movie's label.
    illumination : ndarray, optional
        Relative illumination pattern of movie and background.
    out_dir : str or Path, optional
        Output folder; nothing is written without it.
    keep_frames : bool
        Also return the raw frames.
    progress : callable, optional
        Called with 1 per frame done.
    """
    camera, noise = exposure.camera, exposure.noise
    assert camera is not None
    out = Path(out_dir) if out_dir is not None else None
    frames = _expose_movie(holograms, camera, rng, illumination, noise, out, truth.label,
                           keep_frames, progress)
    if out is None:
        return SimulatedMovie(None, None, None, truth.table, frames if keep_frames else None)
    with TiffStackWriter(out / "background.tif", {"holofit": "simulated background"}) as bw:
        for _ in range(max(exposure.n_background, 1)):
            bw.write(camera.expose(np.ones(frame_shape), rng, illumination, noise))
    table_path = write_table(
        out / "truth.csv", truth.table,
        sidecar(kind="simulation ground truth", units=truth.units, extra={"truth": truth.meta}),
    )
    return SimulatedMovie(out / "movie.tif", out / "background.tif", table_path, truth.table,
                          frames if keep_frames else None)


def _expose_movie(
    holograms: Iterable[NDArray[np.float64]], camera: Camera, rng: np.random.Generator,
    illumination: NDArray | None, noise: bool, out: Path | None, label: str,
    keep_frames: bool, progress: Any,
) -> list[NDArray]:
    """Raw frames of the holograms, written to ``out/movie.tif`` frame by frame (removed again
    if anything fails); the frames themselves are returned with ``keep_frames``."""
    frames: list[NDArray] = []
    writer = None if out is None else TiffStackWriter(out / "movie.tif", {"holofit": label})
    try:
        for holo in holograms:
            raw = camera.expose(holo, rng, illumination, noise)
            if writer is not None:
                writer.write(raw)
            if keep_frames:
                frames.append(raw)
            if progress is not None:
                progress(1)
        if writer is not None:
            writer.close()
            writer = None
    finally:
        if writer is not None:
            writer.abort()
    return frames
