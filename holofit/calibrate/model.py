"""The frames of a joint instrument fit as one model (:mod:`holofit.calibrate.joint`): every
frame's sphere hologram, their shared instrument parameters and their own spheres, stacked."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from holofit.aberration import Aberration
from holofit.cache import LRUCache
from holofit.calibrate.settings import (
    INSTRUMENT_PREFIX,
    POLARIZATION,
    POLARIZATION_STEP,
    JointFitSettings,
)
from holofit.holomodel.forward import HologramModel
from holofit.holomodel.parameters import APERTURE, ParameterSpace, State
from holofit.holomodel.pixels import PixelSelection
from holofit.optics import Optics
from holofit.particles import Sphere
from holofit.prefit.sphere import EXACT_STEPS
from holofit.scattering.mie import LorenzMie

__all__ = ["Frame", "JointModel", "Names"]


@dataclass
class Frame:
    """A frame's pixels, noise and current sphere."""

    pix: PixelSelection
    noise_sd: float
    sphere: dict[str, float]
    subset: NDArray[np.intp]


class Names:
    """The ``space`` a least-squares run asks a model for: its vector's names."""

    def __init__(self, names: tuple[str, ...]) -> None:
        self.names = names


class JointModel:
    """The frames' forward models stacked (module docstring), with the interface of
    :class:`~holofit.holomodel.forward.HologramModel` that
    :func:`~holofit.holomodel.leastsq.solve_least_squares` uses: ``space.names``,
    ``hologram``, ``jacobian`` and ``n_holograms``."""

    def __init__(self, frames: Sequence[Frame], optics: Optics, shared: Mapping[str, float],
                 free_shared: Sequence[str], frame_names: Sequence[str],
                 settings: JointFitSettings, subset: bool = False) -> None:
        self.frames = list(frames)
        self.optics = optics
        self.shared = dict(shared)
        self.free_shared = tuple(free_shared)
        self.frame_names = tuple(frame_names)
        self.settings = settings
        self.subset = subset
        names = [INSTRUMENT_PREFIX + n for n in self.free_shared]
        for j in range(len(self.frames)):
            names += [f"frame{j}.{n}" for n in self.frame_names]
        self.space = Names(tuple(names))
        self._models: dict[float, list[HologramModel]] = {}
        self._extra = 0
        rows = [f.subset.size if subset else f.pix.size for f in self.frames]
        self._rows = np.cumsum([0, *rows])
        self.weights = [1.0 / f.noise_sd for f in self.frames]
        model_free = [n for n in self.free_shared if n != POLARIZATION] + list(self.frame_names)
        self._frame_free = tuple(model_free)
        index = {n: i for i, n in enumerate(self.space.names)}
        self._index: list[NDArray[np.intp]] = []
        self._priors = self._prior_rows()
        for j in range(len(self.frames)):
            space = self._space(j)
            self._index.append(np.array(
                [index[INSTRUMENT_PREFIX + n] if n in self.free_shared else index[f"frame{j}.{n}"]
                 for n in space.names], dtype=np.intp))

    # -- the frames' models ------------------------------------------------------------
    def _space(self, j: int, shared: Mapping[str, float] | None = None) -> ParameterSpace:
        s = self.shared if shared is None else shared
        sphere = self.frames[j].sphere
        st = self.settings
        alpha = sphere["alpha"] if st.fix_alpha is None else st.fix_alpha
        model = Sphere(sphere["radius_um"], complex(sphere["n"], st.index_imag))
        aberration = Aberration.from_values(dict(s), self.optics.aberration)
        state = State((sphere["x_um"], sphere["y_um"], sphere["z_um"]), None, alpha,
                      (("radius_um", sphere["radius_um"]), ("n", sphere["n"])),
                      s.get(APERTURE.name), aberration)
        return ParameterSpace(model, self._frame_free, state, step_overrides=EXACT_STEPS)

    def _models_for(self, beta: float) -> list[HologramModel]:
        models = self._models.get(beta)
        if models is None:
            optics = replace(self.optics, polarization_rad=beta)
            models = []
            for j, f in enumerate(self.frames):
                xs, ys = ((f.pix.xs_um[f.subset], f.pix.ys_um[f.subset]) if self.subset
                          else (f.pix.xs_um, f.pix.ys_um))
                models.append(HologramModel(LorenzMie(), self._space(j), optics, xs, ys,
                                            waves=LRUCache(4)))
            while len(self._models) >= 3:
                self._extra += sum(m.n_holograms for m in self._models.pop(next(iter(
                    self._models))))
            self._models[beta] = models
        return models

    def _beta(self, v: NDArray) -> float:
        if POLARIZATION in self.free_shared:
            return float(v[self.space.names.index(INSTRUMENT_PREFIX + POLARIZATION)])
        return float(self.shared.get(POLARIZATION, self.optics.polarization_rad))

    @property
    def n_holograms(self) -> int:
        return self._extra + sum(m.n_holograms for ms in self._models.values() for m in ms)

    @n_holograms.setter
    def n_holograms(self, value: int) -> None:
        self._extra += int(value) - self.n_holograms

    # -- data, holograms, normal equations ----------------------------------------------
    def _prior_rows(self) -> list[tuple[int, float, float]]:
        """``(vector index, value, sd)`` of every prior row: each frame's free parameters
        that :attr:`JointFitSettings.priors` names, in frame order."""
        rows = []
        names = self.space.names
        for j in range(len(self.frames)):
            for name, (value, sd) in self.settings.priors:
                if name in self.frame_names:
                    rows.append((names.index(f"frame{j}.{name}"), float(value), float(sd)))
        return rows

    def data(self) -> NDArray[np.float64]:
        """Every frame's data, weighted, in the model's row order, then the priors' values
        over their sds."""
        pixels = [(f.pix.data[f.subset] if self.subset else f.pix.data) * w
                  for f, w in zip(self.frames, self.weights, strict=True)]
        prior = np.array([value / sd for _, value, sd in self._priors])
        return np.concatenate([*pixels, prior])

    def hologram(self, vector: NDArray) -> NDArray[np.float64]:
        """The frames' holograms, weighted, and the prior rows' parameters over their sds."""
        v = np.asarray(vector, dtype=float)
        models = self._models_for(self._beta(v))
        prior = np.array([v[i] / sd for i, _, sd in self._priors])
        return np.concatenate([*(m.hologram(v[idx]) * w for m, idx, w in
                                 zip(models, self._index, self.weights, strict=True)), prior])

    def normal(self, vector: NDArray, residuals: NDArray
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``J^T J`` and ``J^T r`` at ``vector`` for the weighted residuals ``r`` there,
        accumulated frame by frame (the stacked ``J`` is never formed:
        :mod:`holofit.calibrate.solver`)."""
        v = np.asarray(vector, dtype=float)
        r = np.asarray(residuals, dtype=float)
        models = self._models_for(self._beta(v))
        a = np.zeros((v.size, v.size))
        g = np.zeros(v.size)
        pol = None
        if POLARIZATION in self.free_shared:
            i_pol = self.space.names.index(INSTRUMENT_PREFIX + POLARIZATION)
            q = v.copy()
            q[i_pol] += POLARIZATION_STEP
            base = self.hologram(v)
            pol = (self.hologram(q) - base) / POLARIZATION_STEP
            models = self._models_for(self._beta(v))
        for j, (m, idx, w) in enumerate(zip(models, self._index, self.weights, strict=True)):
            rows = slice(int(self._rows[j]), int(self._rows[j + 1]))
            jac = m.jacobian(v[idx]) * w
            if pol is not None:
                jac = np.column_stack([jac, pol[rows]])
                cols = np.append(idx, i_pol)
            else:
                cols = idx
            a[np.ix_(cols, cols)] += jac.T @ jac
            g[cols] += jac.T @ r[rows]
        tail = int(self._rows[-1])
        for k, (i, _, sd) in enumerate(self._priors):
            a[i, i] += 1.0 / sd**2
            g[i] += r[tail + k] / sd
        return a, g

    # -- vectors <-> values -------------------------------------------------------------
    def vector(self) -> NDArray[np.float64]:
        """The model's vector at its shared values and the frames' spheres."""
        out = [self.shared[n] for n in self.free_shared]
        for f in self.frames:
            out += [f.sphere[n] for n in self.frame_names]
        return np.array(out, dtype=float)

    def values(self, vector: NDArray) -> tuple[dict[str, float], list[dict[str, float]]]:
        """The shared values and the frames' spheres at ``vector``."""
        v = np.asarray(vector, dtype=float)
        shared = dict(self.shared)
        for i, n in enumerate(self.free_shared):
            shared[n] = float(v[i])
        spheres = []
        k = len(self.free_shared)
        for f in self.frames:
            s = dict(f.sphere)
            for n in self.frame_names:
                s[n] = float(v[k])
                k += 1
            spheres.append(s)
        return shared, spheres


