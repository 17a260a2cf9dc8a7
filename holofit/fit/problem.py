"""One frame's fitting problem as one value: :class:`FrameProblem`.

Every fit of a frame (from the library's starts, from a known state, one evaluation, a probe,
an overlap refit) needs the same things: the crop and where it lies on the camera, the
instrument's optics and pixel size, the particle model and its engine, what is fitted and
how. They travel together, so they are one object; what differs between the fits (where they
start) is their own argument.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from holofit.conventions import euler_zyz
from holofit.fit.settings import FrameFitSettings
from holofit.holomodel.parameters import State, static_values
from holofit.optics import Optics
from holofit.particles import ParticleModel
from holofit.scattering.theory import ScatteringEngine

__all__ = ["FrameProblem", "state_of"]


@dataclass(frozen=True, eq=False)
class FrameProblem:
    """What defines one frame's fit.

    Attributes
    ----------
    crop : ndarray, shape (rows, cols)
        Normalised hologram; NaN marks pixels to leave out.
    corner : tuple of int
        Full-frame ``(row, column)`` of the crop's pixel ``[0, 0]``.
    pixel_size_um : float
        Pixel pitch in the sample plane, um.
    theory : ScatteringEngine
        The engine (kept across frames by the caller: its caches and warm starts pay).
    model : ParticleModel
        The particle; its static parameters are the start values (and the fixed values of
        the ones not in ``free``).
    optics : Optics
        Illumination and objective.
    free : tuple of str
        Fitted parameters: position and static names, ``alpha``, ``orientation``,
        ``numerical_aperture`` (starting from the optics' NA).
    settings : FrameFitSettings
        How the frame is fitted.
    seed : int
        Seed of the random pixel subsets (the frame number: batches are reproducible).
    extra_field : tuple of ndarray, optional
        A fixed field ``(Ex, Ey)`` of the crop's shape (complex, incident units, its own alpha
        applied) added to the model's before the intensity: an overlapping neighbour's
        recorded field (:mod:`holofit.fit.overlaps`).
    """

    crop: NDArray[Any]
    corner: tuple[int, int]
    pixel_size_um: float
    theory: ScatteringEngine
    model: ParticleModel
    optics: Optics
    free: tuple[str, ...]
    settings: FrameFitSettings = field(default_factory=FrameFitSettings)
    seed: int = 0
    extra_field: tuple[NDArray[np.complex128], NDArray[np.complex128]] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "free", tuple(self.free))

    def with_settings(self, settings: FrameFitSettings) -> FrameProblem:
        """The same problem fitted with other settings."""
        return replace(self, settings=settings)

    def with_(self, **changes: Any) -> FrameProblem:
        """The same problem with some fields changed (another engine, free set, model)."""
        return replace(self, **changes)


def state_of(values: dict[str, float], model: ParticleModel) -> State:
    """The :class:`~holofit.holomodel.parameters.State` of a fit's values (position, um;
    orientation ``psi_rad, theta_rad[, phi_rad]``; alpha; the model's static parameters where
    ``values`` has them, else the model's own)."""
    pos = (float(values["x_um"]), float(values["y_um"]), float(values["z_um"]))
    rot = None
    if model.anisotropic:
        rot = euler_zyz(float(values["psi_rad"]), float(values["theta_rad"]),
                        float(values.get("phi_rad", 0.0)))
    statics = tuple((name, float(values.get(name, v))) for name, v in static_values(model))
    return State(pos, rot, float(values["alpha"]), statics)
