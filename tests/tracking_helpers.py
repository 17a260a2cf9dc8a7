"""A short simulated rod track for the tracking tests: a small rod through a 1.2 NA objective,
holograms from its T-matrix (built once per session, ~3 s), filmed by
:func:`holofit.simulate.holograms.simulate_movie` on a 64 x 64 frame through an 8-bit camera,
with known truth."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from holofit.camera import Camera
from holofit.config import Instrument
from holofit.dda.engine import BuiltinDDA
from holofit.fit.follower import ChunkFrame
from holofit.library.search import Candidate
from holofit.particles import JanusSphere, ParticleModel, Spherocylinder
from holofit.simulate.holograms import Exposure, simulate_movie

INSTRUMENT = Instrument("test", 0.66, 1.33, 0.12, extra={"numerical_aperture": 1.2})
ROD = Spherocylinder(0.25, 0.6, 1.5)
#: a small Janus particle (its mirror theta -> pi - theta is a second minimum)
JANUS = JanusSphere(0.3, 0.06, 1.59, 2.7)
SHAPE = (64, 64)
FINAL = ("x_um", "y_um", "z_um", "orientation", "alpha")
BACKGROUND = 120.0


def engine(model: ParticleModel = ROD) -> BuiltinDDA:
    """The engine with the particle's T-matrix in use (rod ~3 s, Janus ~11 s to build)."""
    theory = BuiltinDDA(dipole_size_um=0.1 if model is ROD else 0.06, tolerance=1e-7)
    theory.tmatrix(model, INSTRUMENT.optics)
    return theory


@dataclass
class Track:
    """Frames (in time order, numbers possibly with gaps) and their truth."""

    frames: list[ChunkFrame]
    positions: np.ndarray
    angles: np.ndarray  # (psi, theta, phi) per frame
    head_tail: bool = True

    def axis_error_deg(self, row: dict, k: int) -> float:
        psi, theta = self.angles[k, 0], self.angles[k, 1]
        ut = np.array([math.sin(theta) * math.cos(psi), math.sin(theta) * math.sin(psi),
                       math.cos(theta)])
        dot = float(np.dot([row["ux"], row["uy"], row["uz"]], ut))
        dot = abs(dot) if self.head_tail else max(-1.0, dot)
        return math.degrees(math.acos(min(1.0, dot)))

    def position_error_um(self, row: dict, k: int) -> float:
        return math.dist([row["x_um"], row["y_um"], row["z_um"]], self.positions[k])


def make_track(theory, n: int = 6, seed: int = 0, jump_at: int | None = None,
               dropped: int = 0, model: ParticleModel = ROD) -> Track:
    """A rod wandering ~60 nm and ~3 deg per frame at z ~ 6 um (seed: its steps and noise);
    with ``jump_at``, from that frame on it sits 0.5 um and 25 deg away (``dropped`` frame
    numbers skipped there, as a camera that lost frames)."""
    rng = np.random.default_rng(seed)
    px = INSTRUMENT.pixel_size_um
    centre = np.array([32.3 * px, 31.6 * px, 6.0])
    pos = centre + np.cumsum(rng.normal(0, 0.035, (n, 3)), axis=0)
    angles = np.zeros((n, 3))
    angles[:, 0] = 0.5 + np.cumsum(rng.normal(0, 0.04, n))
    angles[:, 1] = 1.0 + np.cumsum(rng.normal(0, 0.04, n))
    numbers = np.arange(n)
    if jump_at is not None:
        pos[jump_at:] += (0.3, -0.3, 0.25)
        angles[jump_at:, 1] += math.radians(25)
        numbers[jump_at:] += dropped
    movie = simulate_movie(
        model,
        INSTRUMENT,
        pos,
        SHAPE,
        orientations=angles,
        alpha=0.9,
        theory=theory,
        seed=seed,
        keep_frames=True,
        exposure=Exposure(camera=Camera(background_counts=BACKGROUND)),
    )
    frames = []
    for k in range(n):
        crop = movie.frames[k] / BACKGROUND
        start = tuple(pos[k] + (0.03, -0.02, 0.25))  # a prefit-like start
        cands = (Candidate(angles[k, 0] + 0.08, angles[k, 1] - 0.1, 0.0, 0.95),)
        frames.append(
            ChunkFrame(int(numbers[k]), crop, (0, 0), start, 0.85, cands, float(numbers[k]) * 0.01)
        )
    return Track(frames, pos, angles, model.head_tail_symmetric)
