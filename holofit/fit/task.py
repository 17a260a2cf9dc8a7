"""The frame function of both DDA fit passes and its settings (picklable: it runs in workers).

:class:`FitConfig` is everything a worker needs for one pass; :class:`FitPayload` what the
driver sends it for one frame; :func:`fit_frame_task` fits the frame
(:func:`holofit.fit.frame.fit_frame`) with the engine this worker keeps for the particle.
:func:`fit_columns` is the table's columns for a particle and its free parameters (the
fit-table schema: :mod:`holofit.tables.fit`).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from holofit.batch.stage import fingerprint
from holofit.cache import LRUCache
from holofit.config import Instrument, ParticleConfig
from holofit.fit.frame import RUNNER_UP_COLUMNS, FrameFitSettings, fit_frame
from holofit.fit.seeded import fit_frame_seeded, seed_particle
from holofit.holomodel.parameters import APERTURE, static_parameters
from holofit.holomodel.result import result_columns, result_row
from holofit.library.search import Candidate
from holofit.particles import ParticleModel
from holofit.scattering.theory import ScatteringTheory

__all__ = [
    "FitConfig",
    "FitPayload",
    "check_fixed",
    "fit_columns",
    "fit_frame_task",
    "fixable_names",
    "worker_theory",
]


def _free(model: ParticleModel, pass_name: str, fixed: tuple[str, ...] = (),
          fit_na: bool = False) -> tuple[str, ...]:
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


def fit_columns(model: ParticleModel, free: tuple[str, ...]) -> tuple[str, ...]:
    """Columns of a DDA fit table for ``model`` with parameters ``free``."""
    orient = ()
    if model.anisotropic:
        orient = ("theta_rad", "psi_rad", *(() if model.axisymmetric else ("phi_rad",)),
                  "ux", "uy", "uz")
    statics = tuple(p.name for p in static_parameters(model))
    optics = (APERTURE.name,) if APERTURE.name in free else ()
    values = ("x_um", "y_um", "z_um", *orient, "alpha", *statics, *optics)
    errors = ("x_um", "y_um", "z_um", *orient, "alpha", *(s for s in statics if s in free),
              *optics)
    return result_columns(values, errors, (*RUNNER_UP_COLUMNS, "n_masked"))


@dataclass(frozen=True)
class FitConfig:
    """Everything a worker needs for one pass (picklable).

    Attributes
    ----------
    particle : ParticleConfig
        The particle; its static parameters are the fit's start (initial pass) or fixed values
        (final pass).
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
        The particle's T-matrix file (final pass): every orientation is then served from it,
        with analytic orientation columns of the Jacobian, instead of a DDA solve.
    fit_na : bool
        Fit the objective's numerical aperture (from the instrument's) in every frame.
    seed_tmatrix : str, optional
        The T-matrix file of the particle at its start statics (initial pass): each frame's
        pose is first fitted from it, then every parameter by direct solves
        (:func:`holofit.fit.seeded.fit_frame_seeded`).
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

    @property
    def free(self) -> tuple[str, ...]:
        return _free(self.particle.model, self.pass_name, self.fixed, self.fit_na)

    def as_dict(self) -> dict[str, Any]:
        return {"particle": self.particle.as_dict(), "instrument": self.instrument.as_dict(),
                "pass": self.pass_name, "free": list(self.free),
                "options": asdict(self.options), "engine": self.engine,
                "tmatrix": self.tmatrix is not None,
                **({"seed_tmatrix": True} if self.seed_tmatrix is not None else {})}

    def key(self) -> str:
        return fingerprint({k: v for k, v in self.as_dict().items() if k != "pass"})


@dataclass(frozen=True)
class FitPayload:
    """What the driver sends a worker for one frame."""

    crop: NDArray[np.float32]
    corner: tuple[int, int]
    start: dict[str, float]
    candidates: tuple[Candidate, ...]


#: per worker process: one engine per particle configuration, with its caches
_THEORIES: LRUCache[str, ScatteringTheory] = LRUCache(2)


def worker_theory(config: FitConfig) -> ScatteringTheory:
    """The engine this worker keeps for ``config``'s particle (and T-matrix), with its
    caches: made on first use, then reused by every frame (or chunk) of the pass."""
    inst = config.instrument
    key = json.dumps({"particle": config.particle.as_dict(), "engine": config.engine},
                     sort_keys=True, default=str)

    def make_theory() -> ScatteringTheory:
        theory = config.particle.theory(config.engine, fixed_lattice_for=inst.optics)
        if config.tmatrix is not None:
            theory.tmatrix(config.particle.model, inst.optics, path=config.tmatrix)
        return theory

    return _THEORIES.get_or_create(key + str(config.tmatrix), make_theory)


def fit_frame_task(config: FitConfig, frame: int, payload: FitPayload) -> dict[str, Any]:
    """Fit one frame; the frame function of both passes (an initial pass with
    ``seed_tmatrix``: :func:`holofit.fit.seeded.fit_frame_seeded`)."""
    inst = config.instrument
    theory = worker_theory(config)
    start = payload.start
    position = (start["x_um"], start["y_um"], start["z_um"])
    if config.seed_tmatrix is not None:
        seeding = replace(config, particle=seed_particle(config.particle),
                          tmatrix=config.seed_tmatrix, seed_tmatrix=None)
        result = fit_frame_seeded(payload.crop, payload.corner, inst.pixel_size_um,
                                  worker_theory(seeding), theory, config.particle.model,
                                  inst.optics, position, start["alpha"], payload.candidates,
                                  _free(config.particle.model, "final", config.fixed,
                                        config.fit_na),
                                  config.free, config.options, seed=frame)
    else:
        result = fit_frame(payload.crop, payload.corner, inst.pixel_size_um, theory,
                           config.particle.model, inst.optics, position, start["alpha"],
                           payload.candidates, config.free, config.options, seed=frame)
    time_s = frame / inst.frame_rate_hz if inst.frame_rate_hz else math.nan
    return result_row(frame, time_s, result)
