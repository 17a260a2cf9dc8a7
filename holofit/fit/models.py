"""Which particle model fits each track: a run's population and the test on chi^2 between them.

A run names its particle (the *primary* model, the one the library ranks orientations of) and
may name others, the *alternatives* (spheres, coated spheres: models without an orientation);
a run of a non-spherical particle also tries a sphere of the prefit's size unless told not to,
since real samples hold impurities and the other species of a mixture, and a sphere fitted by a
rod model is a rod with ``a ~ b`` that fits as well. Every model fits each track's initial
frames; :func:`choose_model` then picks, per track, the model of the lowest Bayesian
information criterion over the frames every model converged on,

    BIC = sum over frames of (chi^2 + k ln N),

``chi^2 = rss / noise_sd^2`` of the frame's ``N`` pixels and ``k`` the frame's fitted
parameters (the chi^2 a model with more parameters gains on data of a simpler one is of order
``k``, far below ``k ln N``; what a wrong model lacks is thousands). A model with more
parameters must beat a simpler one by :data:`DECISIVE_BIC` to be chosen.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from holofit.config import ParticleConfig
from holofit.holomodel.parameters import static_parameters
from holofit.particles import ParticleModel, Sphere
from holofit.quality import CONVERGED

__all__ = [
    "DECISIVE_BIC",
    "ModelChoice",
    "ModelFits",
    "Population",
    "choose_model",
    "parameter_count",
    "prefit_sphere",
]

#: a model with more parameters is chosen over a simpler one only when its BIC is lower by
#: more than this (Kass & Raftery 1995: "very strong" evidence)
DECISIVE_BIC = 10.0


@dataclass(frozen=True)
class Population:
    """The models of a run: the primary one and the alternatives, each under its label (the
    model's kind: ``spherocylinder``, ``sphere``); ``engines`` names an alternative's engine
    where it is not the run's."""

    primary: ParticleConfig
    alternatives: tuple[ParticleConfig, ...] = ()
    engines: Mapping[str, str | None] = field(default_factory=dict)

    @property
    def labels(self) -> tuple[str, ...]:
        return (self.primary.model.kind, *(a.model.kind for a in self.alternatives))

    def config(self, label: str) -> ParticleConfig:
        """The model of ``label``."""
        for p in (self.primary, *self.alternatives):
            if p.model.kind == label:
                return p
        raise KeyError(f"no model {label!r} in the run's population {self.labels}")


def parameter_count(model: ParticleModel, free: Sequence[str]) -> int:
    """Fitted parameters of a frame: one per name, the orientation as many angles as the model
    has (two for an axisymmetric particle, three otherwise, none for an isotropic one)."""
    n = 0
    for name in free:
        if name == "orientation":
            n += 0 if not model.anisotropic else (2 if model.axisymmetric else 3)
        else:
            n += 1
    return n


@dataclass(frozen=True)
class ModelFits:
    """One model's initial rows of every track (``particle``, ``frame``, ``status``,
    ``chi2``, ``noise_sd``, ``n_pixels``) and the parameters each frame fitted."""

    label: str
    table: pd.DataFrame
    n_params: int


@dataclass(frozen=True)
class ModelChoice:
    """The model a track is given: its label, each model's BIC and frame count, and why."""

    label: str
    bic: dict[str, float]
    n_frames: int
    reason: str


def _chi2(rows: pd.DataFrame) -> pd.Series:
    noise = rows["noise_sd"].astype(float)
    return rows["chi2"].astype(float) * rows["n_pixels"].astype(float) / noise**2


def choose_model(fits: Sequence[ModelFits], particle: int,
                 decisive: float = DECISIVE_BIC) -> ModelChoice:
    """The model of track ``particle`` (module docstring): the lowest BIC over the frames
    every model converged on; the first model (the primary) when no frame is common."""
    mine = {f.label: f.table[f.table["particle"] == particle].set_index("frame") for f in fits}
    common: set[int] | None = None
    for rows in mine.values():
        good = rows[rows["status"].isin(CONVERGED) & np.isfinite(rows["chi2"].astype(float))]
        frames = {int(f) for f in good.index}
        common = frames if common is None else common & frames
    shared = sorted(common or ())
    if not shared:
        return ModelChoice(fits[0].label, {}, 0, "no frame that every model converged on: "
                           "the primary model")
    bic = {}
    for f in fits:
        rows = mine[f.label].loc[shared]
        bic[f.label] = float((_chi2(rows) + f.n_params * np.log(rows["n_pixels"].astype(float)))
                             .sum())
    by_bic = sorted(fits, key=lambda f: bic[f.label])
    best = by_bic[0]
    for f in by_bic[1:]:  # a simpler model within the decisive margin is preferred
        if f.n_params < best.n_params and bic[f.label] - bic[best.label] <= decisive:
            best = f
    others = ", ".join(f"{label} {value - bic[best.label]:+.4g}" for label, value in bic.items()
                       if label != best.label)
    return ModelChoice(best.label, bic, len(shared),
                       f"lowest BIC over {len(shared)} frame(s) ({others} above it)")


def prefit_sphere(prefit: pd.DataFrame, particle: int) -> Sphere | None:
    """A sphere of a track's prefit size and index (the medians of its finite prefit rows),
    the start of the sphere alternative; None where the prefit has none."""
    rows = prefit[prefit["particle"] == particle] if "particle" in prefit else prefit
    if not {"radius_um", "n"} <= set(rows.columns):
        return None
    r = rows["radius_um"].astype(float).to_numpy()
    n = rows["n"].astype(float).to_numpy()
    r, n = r[np.isfinite(r)], n[np.isfinite(n)]
    if not r.size or not n.size:
        return None
    radius, index = float(np.median(r)), float(np.median(n))
    if not (radius > 0 and math.isfinite(index)):
        return None
    return Sphere(radius, index)


def static_names(model: ParticleModel) -> tuple[str, ...]:
    """The static parameters of ``model`` (the sizes and indices a track's statics hold)."""
    return tuple(p.name for p in static_parameters(model))
