"""The frame function of the fit passes and its settings (picklable: it runs in workers).

:class:`PassConfig` is everything a worker needs for one pass over every track; its
:meth:`~PassConfig.for_track` is the pass as one track sees it (that track's settled static
parameters and T-matrix in the final pass). :class:`FitPayload` is what the driver sends a
worker for one ``(particle, frame)`` item; :func:`fit_frame_task` fits it
(:func:`holofit.fit.frame.fit_frame`, or :func:`holofit.fit.seeded.fit_frame_seeded`) with the
engine this worker keeps for the track's particle. :func:`fit_columns` is the table's columns
for a particle and its free parameters (the fit-table schema: :mod:`holofit.tables.fit`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from holofit.batch.stage import fingerprint
from holofit.batch.worker import worker_resource
from holofit.config import Instrument, ParticleConfig
from holofit.fit.frame import RUNNER_UP_COLUMNS, fit_frame
from holofit.fit.problem import FrameProblem
from holofit.fit.seeded import fit_frame_seeded, seed_particle
from holofit.fit.settings import FrameFitSettings
from holofit.fit.tmatrix_policy import serve_tmatrix_file
from holofit.holomodel.parameters import APERTURE, particle_with, static_parameters
from holofit.holomodel.result import result_columns, result_row
from holofit.library.search import Candidate
from holofit.particles import ParticleModel
from holofit.scattering.theory import ScatteringEngine

__all__ = [
    "FitPayload",
    "PassConfig",
    "TrackSetup",
    "check_fixed",
    "fit_columns",
    "fit_frame_task",
    "fixable_names",
    "free_parameters",
    "item_theory",
    "pass_columns",
    "worker_theory",
]


def free_parameters(model: ParticleModel, pass_name: str, fixed: tuple[str, ...] = (),
                    fit_na: bool = False) -> tuple[str, ...]:
    """The parameters a pass fits: position, orientation and alpha; the static ones in the
    initial pass; the objective's NA with ``fit_na``; less those ``fixed``."""
    names = ["x_um", "y_um", "z_um", "orientation", "alpha"]
    if pass_name == "initial":
        names += [p.name for p in static_parameters(model)]
    if fit_na:
        names.append(APERTURE.name)
    return tuple(n for n in names if n not in fixed)


def fixable_names() -> dict[str, tuple[str, ...]]:
    """The static fit parameters of each particle model (``--fix`` can hold them), by kind;
    a voxel file's are ``n1, n2, ...`` (one per domain)."""
    from holofit.holomodel.parameters import index_column
    from holofit.particles import MODEL_TYPES

    return {kind: (*cls.size_fields, *cls.nonnegative_fields,
                   *(index_column(f) for f in cls.index_fields))
            for kind, cls in MODEL_TYPES.items() if kind != "voxels"}


def check_fixed(model: ParticleModel, fixed: tuple[str, ...]) -> None:
    """Refuse names in ``fixed`` that are not fit parameters of ``model`` (a typo)."""
    known = {"x_um", "y_um", "z_um", "orientation", "alpha"} | {
        p.name for p in static_parameters(model)}
    unknown = sorted(set(fixed) - known)
    if unknown:
        raise ValueError(f"cannot fix {', '.join(unknown)}: a {model.kind}'s fit parameters are "
                         f"{', '.join(sorted(known))}")


def pass_columns(config: PassConfig) -> tuple[str, ...]:
    """The columns of a pass's table: every track's model's (:func:`fit_columns`), in the
    order they first appear, then ``model``."""
    seen: dict[str, None] = {}
    models = [config.particle.model, *config.track_models().values()]
    for model in models:
        free = free_parameters(model, config.pass_name, config.fixed, config.fit_na)
        for c in fit_columns(model, free):
            seen.setdefault(c, None)
    cols = [c for c in seen if c not in ("status", "message")]
    return (*cols, "model", "status", "message")


def fit_columns(model: ParticleModel, free: tuple[str, ...]) -> tuple[str, ...]:
    """Columns of a DDA fit table for ``model`` with parameters ``free`` (``particle``
    first: every fit table is keyed by ``(particle, frame)``)."""
    orient: tuple[str, ...] = ()
    if model.anisotropic:
        orient = ("theta_rad", "psi_rad", *(() if model.axisymmetric else ("phi_rad",)),
                  "ux", "uy", "uz")
    statics = tuple(p.name for p in static_parameters(model))
    optics = (APERTURE.name,) if APERTURE.name in free else ()
    values = ("x_um", "y_um", "z_um", *orient, "alpha", *statics, *optics)
    errors = ("x_um", "y_um", "z_um", *orient, "alpha", *(s for s in statics if s in free),
              *optics)
    return ("particle", *result_columns(values, errors, (*RUNNER_UP_COLUMNS, "n_masked")))


@dataclass(frozen=True)
class TrackSetup:
    """One track's part of a pass: the static parameters it starts from (initial pass) or
    fixes (final pass), the T-matrix file that serves it (None: direct solves), and, for a
    track given another model of the run's population than the pass's particle, that model's
    config and engine (:mod:`holofit.fit.models`)."""

    statics: tuple[tuple[str, float], ...] = ()
    tmatrix: str | None = None
    particle: ParticleConfig | None = None
    engine: str | None = None


@dataclass(frozen=True)
class PassConfig:
    """Everything a worker needs for one pass (picklable).

    Attributes
    ----------
    particle : ParticleConfig
        The particle; its static parameters are the fit's start (initial pass) or, for a
        track without a :class:`TrackSetup`, the fixed values (final pass).
    instrument : Instrument
        Optics and pixel size.
    pass_name : {"initial", "final"}
        Which pass.
    options : FrameFitSettings
        How each frame is fitted.
    engine : str, optional
        Scattering engine (default: the particle config's).
    fixed : tuple of str
        Parameters held at their start values in both passes (e.g. a dimer's ``gap_um``).
    tmatrix : str, optional
        The particle's T-matrix file (final pass; a track's :class:`TrackSetup` may name its
        own): every orientation is then served from it instead of a DDA solve.
    fit_na : bool
        Fit the objective's numerical aperture (from the instrument's) in every frame.
    seed_tmatrix : str, optional
        The T-matrix file of the particle at its start statics (initial pass): each frame's
        pose is first fitted from it, then every parameter by direct solves
        (:func:`holofit.fit.seeded.fit_frame_seeded`).
    tracks : tuple
        ``(particle, TrackSetup)`` per track of the final pass.
    """

    particle: ParticleConfig
    instrument: Instrument
    pass_name: str
    options: FrameFitSettings = field(default_factory=FrameFitSettings)
    engine: str | None = None
    fixed: tuple[str, ...] = ()
    tmatrix: str | None = None
    fit_na: bool = False
    seed_tmatrix: str | None = None
    tracks: tuple[tuple[int, TrackSetup], ...] = ()

    @property
    def free(self) -> tuple[str, ...]:
        return free_parameters(self.particle.model, self.pass_name, self.fixed, self.fit_na)

    def for_track(self, particle: int) -> PassConfig:
        """The pass as track ``particle`` sees it: its model, settled statics and T-matrix."""
        setup = dict(self.tracks).get(int(particle))
        if setup is None:
            return replace(self, tracks=())
        base = setup.particle or self.particle
        model = particle_with(base.model, dict(setup.statics))
        settled = ParticleConfig(model, base.settings, base.path)
        engine = setup.engine if setup.particle is not None else self.engine
        return replace(self, particle=settled, tmatrix=setup.tmatrix, engine=engine, tracks=(),
                       seed_tmatrix=self.seed_tmatrix if setup.particle is None else None)

    def track_models(self) -> dict[int, ParticleModel]:
        """Each track's model (the pass's particle where its setup names none)."""
        return {p: (s.particle or self.particle).model for p, s in self.tracks}

    def with_tracks(self, tracks: Mapping[int, TrackSetup]) -> PassConfig:
        """This pass with each track's setup (sorted by track)."""
        return replace(self, tracks=tuple(sorted((int(p), s) for p, s in tracks.items())))

    def as_dict(self) -> dict[str, Any]:
        doc = {"particle": self.particle.as_dict(), "instrument": self.instrument.as_dict(),
               "pass": self.pass_name, "free": list(self.free),
               "options": asdict(self.options), "engine": self.engine,
               "tmatrix": self.tmatrix is not None,
               **({"seed_tmatrix": True} if self.seed_tmatrix is not None else {})}
        if self.tracks:
            doc["tracks"] = {str(p): {"statics": dict(s.statics), "tmatrix": s.tmatrix is not None,
                                      **({"particle": s.particle.as_dict(), "engine": s.engine}
                                         if s.particle is not None else {})}
                             for p, s in self.tracks}
        return doc

    def key(self) -> str:
        return fingerprint({k: v for k, v in self.as_dict().items() if k != "pass"})


@dataclass(frozen=True)
class FitPayload:
    """What the driver sends a worker for one frame."""

    crop: NDArray[np.float32]
    corner: tuple[int, int]
    start: dict[str, float]
    candidates: tuple[Candidate, ...]


def worker_theory(config: PassConfig) -> ScatteringEngine:
    """The engine this worker keeps for ``config``'s particle (and T-matrix), with its
    caches: made on first use, then reused by every frame (or chunk) of the pass."""
    inst = config.instrument
    key = json.dumps({"particle": config.particle.as_dict(), "engine": config.engine},
                     sort_keys=True, default=str)

    def make_theory() -> ScatteringEngine:
        theory = config.particle.theory(config.engine, fixed_lattice_for=inst.optics)
        if config.tmatrix is not None:
            serve_tmatrix_file(theory, config.particle.model, inst.optics, config.tmatrix)
        return theory

    return worker_resource("fit engine", key + str(config.tmatrix), make_theory, size=4)


def item_theory(config: PassConfig) -> ScatteringEngine:
    """:func:`worker_theory` with its solver history forgotten
    (:meth:`~holofit.scattering.theory.ScatteringEngine.forget_history`): what a batch item
    starts from, so that its rows do not depend on the items its worker ran before."""
    theory = worker_theory(config)
    theory.forget_history()
    return theory


def frame_problem(config: PassConfig, payload: FitPayload, frame: int,
                  theory: ScatteringEngine | None = None) -> FrameProblem:
    """The fitting problem of one frame of a pass (``config`` as its track sees it)."""
    inst = config.instrument
    return FrameProblem(payload.crop, payload.corner, inst.pixel_size_um,
                        theory or worker_theory(config), config.particle.model, inst.optics,
                        config.free, config.options, seed=frame)


def fit_frame_task(config: PassConfig, key: tuple[int, int], payload: FitPayload
                   ) -> dict[str, Any]:
    """Fit one ``(particle, frame)`` item; the frame function of the passes (an initial
    pass with ``seed_tmatrix``: :func:`holofit.fit.seeded.fit_frame_seeded`)."""
    particle, frame = int(key[0]), int(key[1])
    config = config.for_track(particle)
    inst = config.instrument
    start = payload.start
    position = (start["x_um"], start["y_um"], start["z_um"])
    problem = frame_problem(config, payload, frame, item_theory(config))
    if config.seed_tmatrix is not None:
        seeding = replace(config, particle=seed_particle(config.particle),
                          tmatrix=config.seed_tmatrix, seed_tmatrix=None)
        result = fit_frame_seeded(problem, worker_theory(seeding), position, start["alpha"],
                                  payload.candidates)
    else:
        result = fit_frame(problem, position, start["alpha"], payload.candidates)
    time_s = frame / inst.frame_rate_hz if inst.frame_rate_hz else math.nan
    return {"particle": particle, **result_row(frame, time_s, result),
            "model": config.particle.model.kind}
