"""An initial-pass frame seeded from a T-matrix: the pose first, then every parameter free.

The initial pass measures the static parameters (sizes, indices) with direct DDA solves, one
per orientation and per static finite difference. From the library's coarse orientations such
a fit needs ~100 solves, and may settle in a wrong minimum; from a good pose it needs ~20-35.
A T-matrix of the particle at its start statics (the particle config's values) gives that pose
for the cost of a final-pass frame (no solve): :func:`fit_frame_seeded`

1. fits position, orientation and alpha from the library's starts with the statics held at
   their start values, served from that T-matrix (:func:`holofit.fit.frame.fit_frame`: the
   screened starts, the mirror, the runner-up); where that fit is far from the data (reduced
   chi^2 above :data:`SEED_RETRY_CHI2_RED`: a prefit height on the wrong side of the focal
   plane, or far off), again from the heights
   :data:`~holofit.fit.tracking.REOPEN_DZ_UM` off the prefit's, in turn, until one is not;
   the lowest is kept; then
2. fits every parameter from there by direct solves (:func:`holofit.fit.frame.fit_frame_warm`,
   whose mirror runner-up keeps ``delta_chi2`` and ``ambiguous`` meaning what they mean).

Cheap frames can be spread over the movie (:func:`holofit.fit.stage.initial_choice`), which
is what the static parameters need. A DDA model's cubic lattice breaks an axisymmetric
particle's symmetry about its axis; the Janus replicate's first frames (all cap-down, within
0.1 s) gave static parameters whose minima scatter along a valley shared with that lattice
anisotropy (radius 436-452 nm, truth 443), and their median was 3.6 nm off in radius; ten
seeded frames spread over the movie gave 442.4-443.8 nm but one near the pole (446.3), and a
median 0.1 nm off (bench/replicate.py, seed 11).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from holofit.config import ParticleConfig
from holofit.fit.frame import FrameFitSettings, fit_frame, fit_frame_warm
from holofit.fit.tracking import REOPEN_DZ_UM, state_of
from holofit.holomodel.result import FitResult
from holofit.library.search import Candidate
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.theory import ScatteringTheory

__all__ = ["SEED_BUILD", "SEED_RETRY_CHI2_RED", "SEED_TOLERANCE", "fit_frame_seeded",
           "seed_particle"]

#: a seed whose reduced chi^2 is above this is tried again from other heights (its statics
#: are the start values, so a right seed of a simulated frame is a little above 1; on the Janus
#: replicate two seeds from prefit heights 1.2 and 3.2 um off the truth ended at chi^2_red
#: 4.7 after 170 solves of the full fit). On real holograms, whose best fits stay above 1
#: (the lens, dust), this costs a few T-matrix fits a frame, against 15-35 direct solves
SEED_RETRY_CHI2_RED = 1.5

#: the DDA solver tolerance of the seeds' T-matrix build: a pose only has to land in the right
#: basin, and the full fit from it is by direct solves at the particle's own tolerance. The
#: paper's Janus particle: 53 s on one core against 88 s at the final T-matrix's 1e-6, its
#: far field within 4.7e-4 of a direct solve
SEED_TOLERANCE = 1e-3
#: the seeds' T-matrix build (:func:`holofit.dda.tmatrix_build.build_tmatrix`): that tolerance,
#: and its order chosen for a truncation error of 1e-3 instead of 3e-6. The paper's Janus
#: particle: order 11 and 36 solves, 28 s on one core (order 15 and 64 solves, 53 s, at
#: 3e-6), the far field within 4.8e-4 of a direct solve either way
SEED_BUILD = {"tolerance": SEED_TOLERANCE, "truncation": 1e-3}


def seed_particle(particle: ParticleConfig) -> ParticleConfig:
    """``particle`` with the DDA tolerance of the seeds' T-matrix (:data:`SEED_TOLERANCE`,
    unless the ``[dda]`` table asks for a looser one): the engine that serves the seeds
    accepts no T-matrix looser than its own tolerance. A particle without a ``[dda]`` table
    is returned as it is."""
    dda = particle.settings.get("dda")
    if not isinstance(dda, dict):
        return particle
    tol = max(float(dda.get("tolerance", 0.0)), SEED_TOLERANCE)
    return replace(particle, settings={**particle.settings, "dda": {**dda, "tolerance": tol}})


def fit_frame_seeded(
    crop: NDArray,
    corner_rc: tuple[int, int],
    pixel_size_um: float,
    seed_theory: ScatteringTheory,
    theory: ScatteringTheory,
    model: ParticleModel,
    optics: Optics,
    position_um: tuple[float, float, float],
    alpha: float,
    candidates: Sequence[Candidate],
    seed_free: Sequence[str],
    free: Sequence[str],
    options: FrameFitSettings | None = None,
    seed: int = 0,
    retry_chi2_red: float = SEED_RETRY_CHI2_RED,
) -> FitResult:
    """Fit one crop with the pose seeded from ``seed_theory`` (module docstring).

    Parameters
    ----------
    crop, corner_rc, pixel_size_um, model, optics, position_um, alpha, candidates, options, seed
        As for :func:`holofit.fit.frame.fit_frame`; ``model``'s static parameters are the
        seed's held values and the full fit's start.
    seed_theory : ScatteringTheory
        The engine with ``model``'s T-matrix in use (every orientation without a solve).
    theory : ScatteringTheory
        The engine of the full fit (direct solves: the statics move).
    seed_free, free : sequence of str
        The seed's parameters (no static ones) and the full fit's.
    retry_chi2_red : float
        A seed above this reduced chi^2 is tried from other heights (module docstring).

    Returns
    -------
    FitResult
        The full fit's, with the seed's holograms and time added to ``n_eval`` and
        ``time_s``, and its start columns (``start_theta_rad``, ``start_psi_rad``,
        ``library_r2``, ``n_starts``) those of the seed's library start. Where the seed
        fails (no finite residuals), the frame is fitted from the library's starts as
        :func:`~holofit.fit.frame.fit_frame` does.
    """
    t0 = time.perf_counter()
    placed = fit_frame(crop, corner_rc, pixel_size_um, seed_theory, model, optics, position_um,
                       alpha, candidates, seed_free, options, seed=seed)
    n_eval = placed.n_eval
    x, y, z = position_um
    for dz in REOPEN_DZ_UM if placed.chi2_red > retry_chi2_red else ():
        other = fit_frame(crop, corner_rc, pixel_size_um, seed_theory, model, optics,
                          (x, y, z + dz), alpha, candidates, seed_free, options, seed=seed)
        n_eval += other.n_eval
        if other.rss < placed.rss:
            placed = other
        if placed.chi2_red <= retry_chi2_red:
            break
    if not np.isfinite(placed.rss):
        result = fit_frame(crop, corner_rc, pixel_size_um, theory, model, optics, position_um,
                           alpha, candidates, free, options, seed=seed)
    else:
        result = fit_frame_warm(crop, corner_rc, pixel_size_um, theory, model, optics,
                                state_of(placed.values, model), free, options,
                                seed=seed).result
        result.extra.pop("runner_up_refit", None)
        result.extra.update({k: placed.extra[k] for k in
                             ("start_theta_rad", "start_psi_rad", "library_r2", "n_starts")
                             if k in placed.extra})
    result.n_eval += n_eval
    result.time_s = time.perf_counter() - t0
    return result
