"""The T-matrix policy of the final pass: when it is served from the particle's T-matrix.

``--tmatrix auto`` (the default) serves a final pass of at least :data:`TMATRIX_MIN_FRAMES`
frames of an anisotropic particle from its T-matrix, built once in the driver from DDA solves
(``OUT/tmatrix.npz``, loaded by every worker) when the engine can give one
(:func:`no_tmatrix_reason`); ``always`` refuses an engine that cannot; ``never`` fits every
frame with direct solves. An exact engine whose every solve is its T-matrix (``exact``) has it
built once in the driver and written to the same file whatever the number of frames (it costs
one solve); ``never`` then leaves each worker to build its own.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from holofit.config import Instrument, ParticleConfig
from holofit.dda.polarizability import INCIDENCE_INDEPENDENT
from holofit.dda.tmatrix_io import TMatrixMismatch, load_tmatrix, save_tmatrix
from holofit.fit.errors import FitStageError
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.theory import ScatteringEngine
from holofit.scattering.tmatrix import TMatrix

__all__ = ["TMATRIX_CHOICES", "TMATRIX_MIN_FRAMES", "FinalTMatrix", "check_policy",
           "final_tmatrix", "no_tmatrix_reason", "serve_tmatrix_file", "tmatrix_builder"]

TMATRIX_CHOICES = ("auto", "always", "never")
#: final passes at least this long are served from a T-matrix by default
TMATRIX_MIN_FRAMES = 8


@dataclass
class FinalTMatrix:
    """What the policy decided: the T-matrix file (None: direct solves), its build (or load)
    time, and notes for the user."""

    path: Path | None = None
    seconds: float = 0.0
    notes: list[str] = field(default_factory=list)


def check_policy(policy: str, particle: ParticleConfig, engine: str | None,
                 final_pass: bool) -> None:
    """Refuse an unknown policy, and ``always`` with an engine that has no T-matrix, before
    any frame is fitted (ValueError, :class:`~holofit.fit.errors.FitStageError`)."""
    if policy not in TMATRIX_CHOICES:
        raise ValueError(f"tmatrix must be one of {', '.join(TMATRIX_CHOICES)}, got {policy!r}")
    if policy == "always" and particle.model.anisotropic and final_pass:
        why_not = no_tmatrix_reason(particle.theory(engine))
        if why_not:
            raise FitStageError(f"--tmatrix always: {why_not} (or use --tmatrix never)")


def final_tmatrix(particle: ParticleConfig, inst: Instrument, engine: str | None,
                  policy: str, n_frames: int, out: Path, workers: int = 1,
                  name: str = "tmatrix.npz", purpose: str = "final pass",
                  build_options: dict[str, float] | None = None) -> FinalTMatrix:
    """Build (or reuse) the final pass's T-matrix ``OUT/tmatrix.npz`` when the policy asks
    for one; a build shares its solves by ``workers`` processes (the stage's workers, idle
    until the final pass starts). ``name`` and ``purpose``: another T-matrix of the stage
    under the same policy (the initial pass's seeds: :mod:`holofit.fit.seeded`), its file
    name and what the notes call it; ``build_options``: the build's ``tolerance`` and
    ``truncation`` where not :func:`holofit.dda.tmatrix_build.build_tmatrix`'s defaults."""
    model = particle.model
    if policy == "never" or not model.anisotropic:
        return FinalTMatrix()
    theory = particle.theory(engine, fixed_lattice_for=inst.optics)
    if getattr(theory, "own_tmatrix", False):
        if hasattr(theory, "adopt"):
            return _own_tmatrix(theory, model, inst, out / name, purpose)
        return FinalTMatrix(notes=[f"{purpose} served by the {theory.name} engine's own "
                                   "T-matrix (one solve per geometry, every orientation by "
                                   "rotation)"])
    if policy == "auto" and n_frames < TMATRIX_MIN_FRAMES:
        return FinalTMatrix()
    why_not = no_tmatrix_reason(theory)
    if why_not:
        if policy == "always":
            raise FitStageError(f"--tmatrix always: {why_not} (or use --tmatrix never)")
        return FinalTMatrix(notes=[f"{purpose} by direct DDA solves: {why_not}"])
    path = out / name
    t0 = time.perf_counter()
    reused = path.exists()
    build: dict[str, Any] = {**(build_options or {}), "workers": max(int(workers), 1)}
    try:
        tmatrix_builder(theory)(model, inst.optics, path=str(path), **build)
    except TMatrixMismatch:
        # made for other static parameters or settings (an earlier run): build anew
        path.unlink()
        tmatrix_builder(theory)(model, inst.optics, path=str(path), **build)
        reused = False
    seconds = time.perf_counter() - t0
    how = "loaded" if reused else f"built by {build['workers']} process(es)"
    return FinalTMatrix(path, seconds, [f"{purpose} served from the particle's T-matrix "
                                        f"{path} ({how} in {seconds:.1f} s)"])


def _own_tmatrix(theory: Any, model: Any, inst: Instrument, path: Path,
                 purpose: str) -> FinalTMatrix:
    """An exact engine's T-matrix, built once here (or read back from an earlier run's
    ``path`` where it is the same) and written to ``path`` for the workers
    (:func:`serve_tmatrix_file`); cheap for every number of frames, so the policy's minimum
    does not apply."""
    t0 = time.perf_counter()
    reused = False
    if path.exists():
        try:
            reused = theory.adopt(model, inst.optics, load_tmatrix(path))
        except TMatrixMismatch:
            reused = False
    tm = theory.tmatrix(model, inst.optics)
    if not reused:
        save_tmatrix(tm, path)
    seconds = time.perf_counter() - t0
    p = tm.provenance
    how = "loaded" if reused else f"built in {seconds:.1f} s"
    return FinalTMatrix(path, seconds, [
        f"{purpose} served from the {theory.name} engine's T-matrix {path} ({how}: "
        f"{p.get('method')}, order {tm.order}, truncation estimate "
        f"{float(p.get('truncation_estimate', float('nan'))):.1e}; every orientation by "
        "rotation)"])


def serve_tmatrix_file(theory: ScatteringEngine, model: ParticleModel, optics: Optics,
                       path: str) -> None:
    """Give ``theory`` the T-matrix file ``path`` of ``model`` (the driver's: the final pass's
    or the initial pass's seeds): the DDA engine loads it (its lattice's, or
    :class:`~holofit.dda.tmatrix_io.TMatrixMismatch`); an exact engine adopts it where it is
    that model's at its discretisation and otherwise builds its own (the same numbers)."""
    adopt = getattr(theory, "adopt", None)
    if adopt is not None:
        try:
            adopt(model, optics, load_tmatrix(path))
        except (TMatrixMismatch, FileNotFoundError):
            pass
        return
    tmatrix_builder(theory)(model, optics, path=path)


def tmatrix_builder(theory: ScatteringEngine) -> Callable[..., TMatrix]:
    """``theory``'s ``tmatrix(model, optics, **options)`` (the built-in DDA's and the exact
    engine's: :func:`no_tmatrix_reason` says whether it has one); an engine without one is a
    :class:`~holofit.fit.errors.FitStageError`."""
    build = getattr(theory, "tmatrix", None)
    if not callable(build):
        raise FitStageError(f"the {theory.name} engine has no T-matrix (use --engine builtin)")
    return build


def no_tmatrix_reason(theory: ScatteringEngine) -> str:
    """Why ``theory`` cannot serve a T-matrix ('' if it can)."""
    if getattr(theory, "own_tmatrix", False):
        return ""
    if not hasattr(theory, "tmatrix"):
        return f"the {theory.name} engine has no T-matrix (use --engine builtin)"
    settings = getattr(theory, "settings", None)
    kind = getattr(settings, "polarizability", None)
    if kind is not None and kind not in INCIDENCE_INDEPENDENT:
        return (f"polarizability {kind!r} depends on the incident wave, so the lattice has no "
                f"T-matrix (the particle config's [dda] polarizability: one of "
                f"{', '.join(INCIDENCE_INDEPENDENT)})")
    return ""
