"""An initial-pass frame seeded from a T-matrix: the pose first, then every parameter free.

The initial pass measures the static parameters (sizes, indices) with direct DDA solves, one
per orientation and per static finite difference. From the library's coarse orientations such
a fit needs several times the solves it needs from a good pose, and may settle in a wrong
minimum (docs: validation, "the initial pass").
A T-matrix of the particle at its start statics (the particle config's values) gives that pose
for the cost of a final-pass frame (no solve): :func:`fit_frame_seeded`

1. fits position, orientation and alpha from the library's starts with the statics held at
   their start values, served from that T-matrix (:func:`holofit.fit.frame.fit_frame`: the
   screened starts, the mirror, the runner-up); where that fit is far from the data (reduced
   chi^2 above :data:`SEED_RETRY_CHI2_RED`: a prefit height on the wrong side of the focal
   plane, or far off), again from the heights
   :data:`~holofit.fit.settings.REOPEN_DZ_UM` off the prefit's, in turn, until one is not;
   the lowest is kept; then
2. fits every parameter from there by direct solves (:func:`holofit.fit.warm.fit_frame_warm`,
   whose mirror runner-up keeps ``delta_chi2`` and ``ambiguous`` meaning what they mean).

Cheap frames can be spread over the movie (:func:`holofit.fit.passes.initial_choice`), which
is what the static parameters need: a DDA lattice's anisotropy makes the statics of frames
that share one orientation scatter along a common valley (docs: validation, "the initial
pass").
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from holofit.config import ParticleConfig
from holofit.fit.frame import fit_frame
from holofit.fit.problem import FrameProblem, state_of
from holofit.fit.settings import REOPEN_DZ_UM
from holofit.fit.warm import fit_frame_warm
from holofit.holomodel.parameters import static_parameters
from holofit.holomodel.result import FitResult
from holofit.library.search import Candidate
from holofit.scattering.theory import ScatteringEngine

__all__ = ["SEED_BUILD", "SEED_RETRY_CHI2_RED", "SEED_TOLERANCE", "fit_frame_seeded",
           "seed_particle"]

#: a seed whose reduced chi^2 is above this is tried again from other heights: a right seed,
#: its statics at their start values, fits a little above 1, while one from a prefit height on
#: the wrong side of focus ends several times higher
SEED_RETRY_CHI2_RED = 1.5

#: the DDA solver tolerance of the seeds' T-matrix build: a pose only has to land in the right
#: basin, and the full fit from it is by direct solves at the particle's own tolerance
SEED_TOLERANCE = 1e-3
#: the seeds' T-matrix build (:func:`holofit.dda.tmatrix_build.build_tmatrix`): that tolerance,
#: and its order chosen for a truncation error of 1e-3 (the final T-matrix's: 3e-6)
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


def fit_frame_seeded(problem: FrameProblem, seed_theory: ScatteringEngine,
                     position_um: tuple[float, float, float], alpha: float,
                     candidates: Sequence[Candidate],
                     retry_chi2_red: float = SEED_RETRY_CHI2_RED) -> FitResult:
    """Fit one crop with the pose seeded from ``seed_theory`` (module docstring).

    Parameters
    ----------
    problem : FrameProblem
        The full fit (its engine solves directly: the statics move); ``problem.model``'s
        static parameters are the seed's held values and the full fit's start.
    seed_theory : ScatteringEngine
        The engine with the model's T-matrix in use (every orientation without a solve); the
        seed fits ``problem.free`` without the static parameters.
    position_um, alpha, candidates
        As for :func:`holofit.fit.frame.fit_frame`.
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
    statics = {p.name for p in static_parameters(problem.model)}
    seeding = problem.with_(theory=seed_theory,
                            free=tuple(n for n in problem.free if n not in statics))
    placed = fit_frame(seeding, position_um, alpha, candidates)
    n_eval = placed.n_eval
    x, y, z = position_um
    for dz in REOPEN_DZ_UM if placed.chi2_red > retry_chi2_red else ():
        other = fit_frame(seeding, (x, y, z + dz), alpha, candidates)
        n_eval += other.n_eval
        if other.rss < placed.rss:
            placed = other
        if placed.chi2_red <= retry_chi2_red:
            break
    if not np.isfinite(placed.rss):
        result = fit_frame(problem, position_um, alpha, candidates)
    else:
        result = fit_frame_warm(problem, state_of(placed.values, problem.model)).result
        result.extra.pop("runner_up_refit", None)
        result.extra.update({k: placed.extra[k] for k in
                             ("start_theta_rad", "start_psi_rad", "library_r2", "n_starts")
                             if k in placed.extra})
    result.n_eval += n_eval
    result.time_s = time.perf_counter() - t0
    return result
