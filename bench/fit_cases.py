"""One library/fit benchmark case per process (``python bench/fit_cases.py CASE``): prints JSON.

The paper's rod (a 0.501, b 1.079 um, n 1.495; 60x water, NA 1.2) and Janus particle (core
0.443 um, cap 0.047 um, n 1.581 / 2.74; 100x oil, NA 1.4), 140 x 140 crops, 12 um from focus,
8-bit camera noise, known truth. The "prefit" start is the truth moved by (30, -20, 250) nm and
alpha 0.85 (what a sphere fit of a rod gives, roughly); the library runs at that start.

Every case uses the paper's instrument with its objective lens (the default) and, as
``<particle>_ideal``, the ideal model without the lens. Reported per case: the library's
one-time tilt solves (``library_<p>_setup_s``), the
library per frame (``library_<p>_frame_s``), the final pass per frame (static parameters fixed:
``fit_<p>_frame_final_s``) and the initial pass (static parameters free from the config's
values: ``fit_<p>_frame_initial_s``), the final pass with direct solves
(``fit_<p>_frame_final_direct_s``) and from the particle's T-matrix (``fit_<p>_frame_final_s``,
the build timed apart), with their solves and hologram evaluations, and the
errors against the truth.

The frame, its truth and the library's candidates (:func:`make_case`, :class:`Case`,
:func:`make_library`, :func:`library_candidates`) are shared with the studies
``pixel_fraction.py`` and ``janus_mirror.py``.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from holofit.camera import Camera
from holofit.config import (
    Instrument,
    ParticleConfig,
    load_instrument,
    load_particle,
    resolve_config,
)
from holofit.conventions import DetectorGrid
from holofit.dda.tmatrix_io import TMatrixMismatch
from holofit.fit.frame import fit_frame
from holofit.fit.problem import FrameProblem
from holofit.fit.settings import FrameFitSettings
from holofit.fit.task import free_parameters
from holofit.hologram import calc_hologram
from holofit.holomodel.parameters import particle_with, static_values
from holofit.library.polar import polar_grid, sample_crop
from holofit.library.search import Candidate, OrientationLibrary, pick_candidates, tilt_grid
from holofit.particles import JanusSphere, ParticleModel, Spherocylinder
from holofit.scattering.theory import Orientation, ScatteringEngine

CASES_SETUP = {
    "rod": ("paper_60x_water", "rod_paper", Spherocylinder(0.501, 1.079, 1.495),
            Orientation(0.6, 1.0)),
    "janus": ("paper_100x_oil", "janus_paper", JanusSphere(0.443, 0.047, 1.581, 2.74),
              Orientation(0.6, 1.0)),
}
#: crop side, pixels
CROP = 140
#: the "prefit" start: the truth moved by this (um), and alpha
START_OFFSET_UM = (0.03, -0.02, 0.25)
START_ALPHA = 0.85


@dataclass
class Case:
    """One synthetic frame of a benchmark particle, with its truth.

    Attributes
    ----------
    name : str
        ``rod`` or ``janus`` (``_ideal`` appended without the objective lens).
    inst : Instrument
        The paper's instrument for the particle.
    config : ParticleConfig
        The particle config (its DDA settings; its static values are the initial pass's start).
    model : ParticleModel
        The truth (the paper's fitted static parameters).
    orientation : Orientation
        The truth's orientation.
    grid : DetectorGrid
        The crop's pixels.
    position_um : tuple of float
        The truth's ``(x, y, z)``, um.
    alpha : float
        The truth's alpha.
    hologram : ndarray
        The noise-free hologram (direct DDA solve of the truth, the instrument's optics).
    """

    name: str
    inst: Instrument
    config: ParticleConfig
    model: ParticleModel
    orientation: Orientation
    grid: DetectorGrid
    position_um: tuple[float, float, float]
    alpha: float
    hologram: NDArray[np.float64]

    def crop(self, seed: int | None = 0) -> NDArray[np.float64]:
        """The hologram through an 8-bit camera (background 120 counts: shot, read noise and
        quantisation) with noise seed ``seed``, normalised; ``None``: noise-free."""
        if seed is None:
            return self.hologram
        cam = Camera(background_counts=120.0)
        return cam.expose(self.hologram, np.random.default_rng(seed)) / 120.0

    @property
    def start(self) -> tuple[float, float, float]:
        """The prefit-like start: the truth moved by :data:`START_OFFSET_UM`."""
        return tuple(p + d for p, d in zip(self.position_um, START_OFFSET_UM, strict=True))

    def fit_model(self) -> tuple[ParticleModel, ScatteringEngine]:
        """The final pass's particle (the truth's static parameters, as after the initial
        pass) and its engine (the config's, on the lattice fixed for the instrument)."""
        fixed = particle_with(self.config.model, dict(static_values(self.model)))
        return fixed, self.config.with_fixed_lattice(self.inst.optics).theory()

    def axis_error_deg(self, values: dict[str, float]) -> float:
        """Angle between a fit's axis ``(ux, uy, uz)`` and the truth's, deg (a rod's u and -u
        are one orientation)."""
        o = self.orientation
        u = np.array([values["ux"], values["uy"], values["uz"]])
        ut = np.array([math.sin(o.theta) * math.cos(o.psi), math.sin(o.theta) * math.sin(o.psi),
                       math.cos(o.theta)])
        dot = float(u @ ut) / float(np.linalg.norm(u))
        if self.model.head_tail_symmetric:
            dot = abs(dot)
        return math.degrees(math.acos(max(-1.0, min(1.0, dot))))


def make_case(case: str, orientation: Orientation | None = None, z_um: float = 12.0,
              alpha: float = 0.9) -> Case:
    """The noise-free frame of ``case`` (a particle, ``_ideal`` for no lens in the model):
    crop at pixels (100, 200), the particle 0.3 px right of and 0.4 px above its centre column
    and row, ``z_um`` from focus, the truth's orientation ``orientation`` (default: the case's)."""
    ideal = case.endswith("_ideal")
    inst_name, part_name, truth_model, truth_o = CASES_SETUP[case.removesuffix("_ideal")]
    inst = load_instrument(resolve_config(inst_name, "instruments"))
    if ideal:
        inst = dataclasses.replace(inst, extra={k: v for k, v in inst.extra.items()
                                                if k != "numerical_aperture"})
    cfg = load_particle(resolve_config(part_name, "particles"))
    px = inst.pixel_size_um
    grid = DetectorGrid((CROP, CROP), px, (100, 200))
    pos = ((200 + 70.3) * px, (100 + 69.6) * px, z_um)
    o = orientation or truth_o
    wave = cfg.theory().solve(truth_model, inst.optics, o)
    return Case(case, inst, cfg, truth_model, o, grid, pos, alpha,
                calc_hologram(wave, pos, grid, alpha))


def make_library(theory: ScatteringEngine, model: ParticleModel, inst: Instrument
                 ) -> OrientationLibrary:
    """The library stage's tilts (10 deg) of ``model``, all solved."""
    lib = OrientationLibrary(theory, model, inst.optics, tilt_grid(model, math.radians(10)))
    lib.solve_all()
    return lib


def library_candidates(lib: OrientationLibrary, case: Case, crop: NDArray,
                       start: tuple[float, float, float] | None = None) -> list[Candidate]:
    """The library stage's candidates (4, at least 20 deg apart) for ``crop`` at ``start``
    (default: the case's start) and alpha :data:`START_ALPHA`."""
    px = case.inst.pixel_size_um
    start = start or case.start
    pg = polar_grid(start[:2], (CROP // 2 - 1) * px, px, 128)
    d, w = sample_crop(crop, case.grid.corner, px, pg)
    scores = lib.scores(pg, d, w, start, START_ALPHA)
    return pick_candidates(scores, lib.tilts, pg.phi, lib.model, 4, math.radians(20))


def use_tmatrix(theory: ScatteringEngine, model: ParticleModel, inst: Instrument,
                path: str | Path | None = None) -> float:
    """Serve ``theory``'s solves of ``model`` from its T-matrix, as the fit stage's final pass
    does: loaded from ``path`` if it holds this particle's, else built (and saved there).
    Returns the seconds it took."""
    t0 = time.perf_counter()
    if "path" not in inspect.signature(theory.tmatrix).parameters:
        theory.tmatrix(model, inst.optics)  # the exact engine builds in a second, no file
        return time.perf_counter() - t0
    try:
        theory.tmatrix(model, inst.optics, path=None if path is None else str(path))
    except TMatrixMismatch:  # made for another particle or settings: build anew
        Path(path).unlink()
        theory.tmatrix(model, inst.optics, path=str(path))
    return time.perf_counter() - t0


def run(case: str, with_tmatrix: bool = True) -> dict[str, float]:
    """``case`` is a particle (``rod``, ``janus``: the paper's instrument, objective lens
    included) or ``<particle>_ideal`` (no lens in the model: the focal-plane field itself)."""
    c = make_case(case)
    name, inst, cfg = case, c.inst, c.config
    px = inst.pixel_size_um
    grid, pos = c.grid, c.position_um
    crop = c.crop(0)
    start = c.start
    out: dict[str, float] = {}

    # the library at the truth's static parameters (as after the initial pass)
    fixed_model, theory = c.fit_model()
    t0 = time.perf_counter()
    lib = make_library(theory, fixed_model, inst)
    out[f"library_{name}_setup_s"] = time.perf_counter() - t0
    out[f"library_{name}_setup_solves"] = float(lib.n_solves)
    pg = polar_grid(start[:2], 69 * px, px, 128)
    d, w = sample_crop(crop, grid.corner, px, pg)
    t0 = time.perf_counter()  # the scores and the pick of library_candidates, timed alone
    scores = lib.scores(pg, d, w, start, START_ALPHA)
    cands = pick_candidates(scores, lib.tilts, pg.phi, fixed_model, 4, math.radians(20))
    out[f"library_{name}_first_frame_s"] = time.perf_counter() - t0
    # a movie: the particle sinks 9 nm per frame (the paper's rod, 0.9 um/s at 100 frames/s),
    # so neighbouring frames share the library's fields at nearly the same height
    t0 = time.perf_counter()
    n_movie = 40
    for k in range(1, n_movie + 1):
        here = (start[0], start[1], start[2] - 0.009 * k)
        sc = lib.scores(pg, d, w, here, START_ALPHA)
        pick_candidates(sc, lib.tilts, pg.phi, fixed_model, 4, math.radians(20))
    out[f"library_{name}_frame_s"] = (time.perf_counter() - t0) / n_movie

    def fit(pass_name, model, label):
        t0 = time.perf_counter()
        problem = FrameProblem(crop, grid.corner, px, theory, model, inst.optics,
                               free_parameters(model, pass_name), FrameFitSettings())
        res = fit_frame(problem, start, START_ALPHA, cands)
        out[f"fit_{name}_frame_{label}_s"] = time.perf_counter() - t0
        return res

    runs = [("final", fixed_model, "final_direct"), ("initial", cfg.model, "initial")]
    if with_tmatrix:
        runs.append(("final", fixed_model, "final"))
    for pass_name, model, label in runs:
        if label == "final":
            t0 = time.perf_counter()
            theory.tmatrix(fixed_model, inst.optics)
            out[f"tmatrix_build_{name}_in_fit_s"] = time.perf_counter() - t0
        res = fit(pass_name, model, label)
        pass_name = label
        out[f"fit_{name}_frame_{pass_name}_evaluations"] = float(res.n_eval)
        out[f"fit_{name}_frame_{pass_name}_solves"] = float(res.extra["n_solves"])
        out[f"fit_{name}_frame_{pass_name}_ok"] = float(res.status == "ok")
        err = math.sqrt(
            sum(
                (res.values[k] - v) ** 2 for k, v in zip(("x_um", "y_um", "z_um"), pos, strict=True)
            )
        )
        out[f"fit_{name}_frame_{pass_name}_position_error_nm"] = 1e3 * err
        out[f"fit_{name}_frame_{pass_name}_axis_error_deg"] = c.axis_error_deg(res.values)
    return out


if __name__ == "__main__":
    print(json.dumps(run(sys.argv[1])))
